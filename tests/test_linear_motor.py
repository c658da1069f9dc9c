"""Linear-motor axis model (Eq. 1-4, stacked masses of Eq. 2) and the AXES.toml file."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.io.axes_file import read_axes_file, write_axes_file
from drivesense.machine.linear_motor import (LinearMotorAxis, ThreeAxisModel, cogging_table_force,
                                             harmonic_cogging_table, linear_machine_model, linear_machine_physics)


def _axis(**kw) -> LinearMotorAxis:
    base = dict(K_m=150.0, k=200.0, s_r=0.1, m=120.0, F_C=30.0, F_br=45.0, v_s=4e-3, sigma=600.0,
                cogging=harmonic_cogging_table(((20.0, 0.3), (5.0, 1.0)), 64))
    base.update(kw)
    return LinearMotorAxis(**base)


def test_force_terms_follow_eq_1_and_4():
    ax = _axis()
    assert ax.motor_force(2.0) == pytest.approx(300.0)
    np.testing.assert_allclose(ax.restoring_force([0.1, 0.2]), [0.0, 20.0])
    v = np.array([-0.05, -4e-3, 4e-3, 0.05])
    want = np.sign(v) * (30.0 + 15.0 * np.exp(-np.abs(v / 4e-3) ** 2)) + 600.0 * v
    np.testing.assert_allclose(ax.friction_force(v), want)
    assert ax.friction_force(0.0) == 0.0
    # the sign ramp: linear through zero, the paper's curve outside it
    assert ax.friction_force(1e-4, v_eps=2e-4) == pytest.approx(0.5 * (30 + 15 * math.exp(-(0.025 ** 2))) + 0.06)
    assert ax.friction_force(0.01, v_eps=2e-4) == pytest.approx(ax.friction_force(0.01))


def test_cogging_table_is_periodic_and_interpolated():
    ax = _axis()
    p = ax.pole_pitch
    s = np.linspace(-0.1, 0.3, 997)
    np.testing.assert_allclose(ax.cogging_force(s), ax.cogging_force(s + 3 * p), atol=1e-9)
    # grid points return the table; the compiled helper agrees with the vectorised one
    grid = np.arange(64) * p / 64
    np.testing.assert_allclose(ax.cogging_force(grid), ax.cogging, atol=1e-9)
    assert all(cogging_table_force(ax.cogging, p, x) == pytest.approx(ax.cogging_force(x)) for x in s[::50])
    np.testing.assert_allclose(ax.cogging_amplitudes(3), [20.0, 5.0, 0.0], atol=1e-9)


def test_stacked_masses_and_process_force_of_eq_2():
    x, y, z = _axis(m=160.0), _axis(m=200.0), _axis(m=110.0)
    model = ThreeAxisModel(x, y, z)
    assert model.stacked_masses() == {"x": 270.0, "y": 470.0, "z": 110.0}
    i, s, v, a = np.array([1.0]), np.array([0.15]), np.array([0.01]), np.array([0.5])
    want = 150 * i - 200 * (s - 0.1) - 470.0 * a - y.cogging_force(s) - y.friction_force(v)
    np.testing.assert_allclose(model.process_force("y", i, s, v, a), want)


@pytest.mark.parametrize("field, value, text", [("m", 0.0, "'m' must be > 0"), ("F_C", -1.0, "'F_C' must be >= 0"),
                                                ("v_s", float("nan"), "'v_s' must be a finite"),
                                                ("cogging", [1.0, 2.0], "'cogging' must hold >= 4")])
def test_bad_parameters_name_the_field(field, value, text):
    with pytest.raises(ConfigError, match=text):
        _axis(**{field: value})


def test_preset_is_plausible_and_the_truth_is_richer():
    phys = linear_machine_physics()
    model = linear_machine_model()
    for name in "xyz":
        ax = model.axis(name)
        travel = phys.axis(name).travel
        assert 100 <= model.stacked_masses()[name] <= 500 and 100 <= ax.K_m <= 300
        assert 10 <= ax.k * (travel[1] - travel[0]) / 2 <= 60          # tens of N at the travel ends
        assert travel[0] < ax.s_r < travel[1]
        assert ax.cogging_amplitudes(1)[0] > 10 and ax.F_C > 10
    assert not phys.exact and phys.ideal().exact and phys.x.friction.sigma0 > 0


def test_axes_file_round_trip(tmp_path):
    model = linear_machine_model()
    path = write_axes_file(tmp_path / "sub" / "AXES.toml", model, header="test")
    back = read_axes_file(path)
    for name in "xyz":
        a, b = back.axis(name), model.axis(name)
        assert a.to_dict() == b.to_dict()
    assert not list(path.parent.glob(".*tmp"))


@pytest.mark.parametrize("edit, text", [
    (lambda t: t.replace("[z]", "[w]"), "unknown table"),
    (lambda t: t.replace("sigma =", "sigmaa =", 1), "unknown key(s) sigmaa"),
    (lambda t: t.replace("F_br =", "# F_br =", 1), "missing key(s) F_br"),
    (lambda t: t.replace("[y]", "[y"), "not valid TOML"),
    (lambda t: t.replace("\nm = ", "\nm = -", 1), "[x]: linear axis parameter 'm' must be > 0"),
])
def test_axes_file_bad_keys_are_named(tmp_path, edit, text):
    good = write_axes_file(tmp_path / "AXES.toml", linear_machine_model())
    bad = tmp_path / "bad.toml"
    bad.write_text(edit(good.read_text()))
    with pytest.raises(ConfigError, match=re.escape(text)):
        read_axes_file(bad)
    with pytest.raises(FileNotFoundError):
        read_axes_file(tmp_path / "missing.toml")
