"""Unit table and conversions (drivesense.units)."""

import math

import numpy as np
import pytest

from drivesense import units
from drivesense.errors import UnitError


@pytest.mark.parametrize(
    "value, unit, quantity, expected, si",
    [
        (1500.0, "mm", "length", 1.5, "m"),
        (250.0, "µm", "length", 250e-6, "m"),
        (2.0, "in", "length", 0.0508, "m"),
        (180.0, "deg", "angle", math.pi, "rad"),
        (1.0, "rev", "angle", 2 * math.pi, "rad"),
        (2500.0, "mA", "current", 2.5, "A"),
        (60.0, "rpm", "angular_speed", 2 * math.pi, "rad/s"),
        (60.0, "min^-1", "angular_speed", 2 * math.pi, "rad/s"),
        (60.0, "in/min", "velocity", 0.0254, "m/s"),
        (6000.0, "mm/min", "velocity", 0.1, "m/s"),
        (1.0, "lbf", "force", 4.4482216152605, "N"),
        (1.5, "kN", "force", 1500.0, "N"),
        (1.0, "hp", "power", 745.69987158227022, "W"),
        (3.0, "Nm", "torque", 3.0, "N*m"),
        (9.0, "m/s²", "acceleration", 9.0, "m/s^2"),
        (20.0, "ms", "time", 0.02, "s"),
        (5.0, "-", "dimensionless", 5.0, "1"),
    ],
)
def test_to_si_converts(value, unit, quantity, expected, si):
    out, out_unit = units.to_si([value, 2 * value], unit, quantity=quantity)
    assert out.dtype == np.float64
    assert out_unit == si
    np.testing.assert_allclose(out, [expected, 2 * expected], rtol=1e-15)


def test_from_si_inverts_to_si():
    x = np.array([0.0, 0.123, -4.5])
    for unit in ("mm", "um", "in"):
        np.testing.assert_allclose(units.to_si(units.from_si(x, unit), unit)[0], x, rtol=1e-15)
    np.testing.assert_allclose(units.from_si(np.pi, "deg"), 180.0)
    np.testing.assert_allclose(units.convert(6000.0, "mm/min", "m/s"), 0.1)


def test_si_values_are_copied_exactly():
    x = np.random.default_rng(0).normal(size=5)
    out, _ = units.to_si(x, "m")
    assert np.array_equal(out, x) and out is not x


def test_unknown_unit_names_channel_and_lists_known_units():
    with pytest.raises(UnitError) as err:
        units.to_si([1.0], "furlong", quantity="length", name="x_table_position")
    msg = str(err.value)
    assert "channel 'x_table_position'" in msg and "unknown unit 'furlong'" in msg
    assert "known length units: m, mm" in msg


def test_wrong_quantity_names_channel():
    expected = r"channel 'x_table_position' expects a length unit, got 'A'"
    with pytest.raises(UnitError, match=expected):
        units.to_si([1.0], "A", quantity="length", name="x_table_position")
    with pytest.raises(ValueError):  # UnitError is also a ValueError
        units.to_si([1.0], "rpm", quantity=units.quantity_of_channel("force_x"), name="force_x")


@pytest.mark.parametrize(
    "name, quantity",
    [
        ("x_current_ref", "current"), ("y_current", "current"), ("z_motor_angle", "angle"),
        ("x_table_position", "length"), ("y_position", "length"), ("x_velocity", "velocity"),
        ("z_acceleration", "acceleration"), ("spindle_speed", "angular_speed"),
        ("spindle_current", "current"), ("spindle_power", "power"), ("force_y", "force"),
        ("time", "time"), ("temperature", None), ("w_current", None), ("force_q", None),
    ],
)
def test_quantity_of_channel(name, quantity):
    assert units.quantity_of_channel(name) == quantity


def test_si_unit_of_every_quantity_is_in_table():
    for q in units.QUANTITIES:
        assert units.quantity_of_unit(units.si_unit(q)) == q
        assert units.known_units(q)[0] == units.si_unit(q)


def test_controller_spindle_units_deg_per_s_and_rev_per_min():
    """Edge recorders log the spindle in deg/s or rev/min; both convert to rad/s."""
    import math

    from drivesense.units import to_si

    assert to_si([360.0], "deg/s", quantity="angular_speed")[0] == pytest.approx(2 * math.pi)
    assert to_si([60.0], "rev/min", quantity="angular_speed")[0] == pytest.approx(2 * math.pi)
    assert to_si([1.0], "rev/s", quantity="angular_speed")[0] == pytest.approx(2 * math.pi)
