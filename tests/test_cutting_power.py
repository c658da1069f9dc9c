"""Cut geometry and the average-power force model (second paper, Eq. 1-5): closed forms and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.machine.cutting_power import (CutConditions, average_tangential_force, chip_thickness_from_angles,
                                              cutting_power, engagement_angle, force_per_depth)
from drivesense.machine.milling import (CuttingCoefficients, average_chip_thickness, engagement_angles,
                                        milling_forces)

D, A, OMEGA = 12.7e-3, 2.54e-3, 2 * math.pi * 1068 / 60
KTC, KTE = 2100e6, 35e3
IMMERSIONS = [(D, "down"), (0.75 * D, "down"), (0.5 * D, "up"), (0.25 * D, "down"), (0.1 * D, "up")]


def cut(ae=D, mode="down", ft=40e-6, flutes=1):
    return CutConditions.from_radial_depth(D, flutes, A, OMEGA, ft, radial_depth=ae, mode=mode)


@pytest.mark.parametrize("ft", [19e-6, 40e-6, 0.1e-3])
def test_slot_average_chip_thickness_is_two_ft_over_pi(ft):
    assert cut(ft=ft).average_chip_thickness == pytest.approx(2 * ft / math.pi, rel=1e-12)
    assert chip_thickness_from_angles(ft, 0.0, math.pi) == pytest.approx(2 * ft / math.pi, rel=1e-12)


@pytest.mark.parametrize("ae, mode", IMMERSIONS)
def test_chip_thickness_agrees_with_milling_and_with_eq4_integral(ae, mode):
    c = cut(ae, mode)
    st, ex = engagement_angles(D, ae, mode)
    phi = np.linspace(st, ex, 200001)
    integral = np.trapezoid(40e-6 * np.sin(phi), phi) / (ex - st)          # Eq. 4 numerically
    assert c.average_chip_thickness == pytest.approx(integral, rel=1e-9)
    assert c.average_chip_thickness == pytest.approx(average_chip_thickness(40e-6, D, ae, mode), rel=1e-12)
    assert c.engagement_angle == pytest.approx(engagement_angle(D, ae, mode))
    assert c.radial_depth == pytest.approx(ae, rel=1e-12)


def test_table1_entry_angles_are_down_milling_at_75_50_25_percent():
    for entry, share in ((60, 0.75), (90, 0.5), (120, 0.25)):
        c = CutConditions(D, 1, A, OMEGA, 40e-6, math.radians(entry), math.pi)
        assert c.mode == "down"
        assert c.radial_depth == pytest.approx(share * D, rel=1e-12)


@pytest.mark.parametrize("ae, mode", IMMERSIONS)
@pytest.mark.parametrize("flutes", [1, 4])
def test_rates_closed_forms_and_eq5(ae, mode, flutes):
    c = cut(ae, mode, flutes=flutes)
    vf = 40e-6 * flutes * OMEGA / (2 * math.pi)
    assert c.feed_speed == pytest.approx(vf)
    assert c.material_removal_rate == pytest.approx(ae * A * vf, rel=1e-12)
    assert c.contact_area_rate == pytest.approx(A * D / 2 * c.engagement_angle * flutes * OMEGA / (2 * math.pi))
    assert c.material_removal_rate / c.contact_area_rate == pytest.approx(c.average_chip_thickness, rel=1e-12)
    p = cutting_power(KTC, KTE, c)                                          # Eq. 2
    assert force_per_depth(p, c) == pytest.approx(KTC * c.average_chip_thickness + KTE, rel=1e-12)   # Eq. 5
    ft = average_tangential_force(p, c)                                     # Eq. 3 (per flute)
    assert ft == pytest.approx((KTC * c.average_chip_thickness + KTE) * A, rel=1e-12)               # Eq. 1


def test_eq3_single_flute_is_the_papers_formula():
    c = cut(0.5 * D, "down")
    p = 123.0
    assert average_tangential_force(p, c) == pytest.approx(p / (OMEGA * D / 2) * 2 * math.pi / c.engagement_angle)


@pytest.mark.parametrize("ae, mode", IMMERSIONS[:3])
def test_eq2_equals_mean_power_of_the_mechanistic_model(ae, mode):
    c = cut(ae, mode, flutes=3)
    angle = np.linspace(0, 2 * math.pi, 4000, endpoint=False)
    f = milling_forces(c.end_mill(35.0), CuttingCoefficients(KTC, 0.4 * KTC, 0.2 * KTC, KTE, 0.5 * KTE, 0.1 * KTE),
                       c.milling_cut(20), angle, c.feed_per_tooth)
    assert f.power(OMEGA).mean() == pytest.approx(cutting_power(KTC, KTE, c), rel=5e-3)


def test_sequences_give_arrays():
    cuts = [cut(ae, m) for ae, m in IMMERSIONS]
    p = cutting_power(KTC, KTE, cuts)
    assert p.shape == (len(cuts),)
    np.testing.assert_allclose(force_per_depth(p, cuts), [KTC * c.average_chip_thickness + KTE for c in cuts])


@pytest.mark.parametrize("make, name", [
    (lambda: cut(ft=-1e-6), "feed_per_tooth"),
    (lambda: cut(ae=1.01 * D), "radial_depth"),
    (lambda: cut(ae=0.0), "radial_depth"),
    (lambda: CutConditions(D, 1, A, 0.0, 40e-6), "spindle_speed"),
    (lambda: CutConditions(D, 1, -A, OMEGA, 40e-6), "axial_depth"),
    (lambda: CutConditions(D, 0, A, OMEGA, 40e-6), "flutes"),
    (lambda: CutConditions(D, 1, A, OMEGA, 40e-6, 1.0, 0.5), "exit_angle"),
    (lambda: CutConditions(D, 1, A, OMEGA, 40e-6, 0.5, 2.0), "entry_angle"),
    (lambda: CutConditions(D, 1, A, OMEGA, 40e-6, 0.0, 4.0), "exit_angle"),
    (lambda: cut(mode="climb"), "mode"),
    (lambda: chip_thickness_from_angles(-1e-6, 0.0, math.pi), "feed_per_tooth"),
    (lambda: cutting_power(math.nan, KTE, cut()), "Ktc"),
    (lambda: cutting_power(KTC, KTE, [cut(), "slot"]), "cut 1"),
])
def test_bad_input_raises_config_error_naming_the_field(make, name):
    with pytest.raises(ConfigError, match=name):
        make()


def test_bad_power_raises_invalid_signal_error():
    with pytest.raises(InvalidSignalError, match="power"):
        force_per_depth([1.0, 2.0], [cut()])
    with pytest.raises(InvalidSignalError, match="non-finite"):
        average_tangential_force(math.inf, cut())
