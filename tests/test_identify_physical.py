"""identify nc yields physical models by construction, air cuts first, terms by held-out error, the regression check.

Synthetic controller traces with known parameters: per axis
``I = (m a + Fc_pos max(s, 0) + Fc_neg min(s, 0) + b v + offset + F) / K``
with ``s = clip(v / v_eps, -1, 1)``, plus noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.estimate import ModelBased, Regression
from drivesense.identify.controller import identify_controller
from drivesense.io.axes_file import read_axes_file, write_axes_file
from drivesense.recording import Recording

FS = 50.0
TRUE = {"x": {"K": -400.0, "m": 300.0, "fc": 150.0, "b": 800.0, "offset": 0.0},
        "y": {"K": 500.0, "m": 700.0, "fc": 200.0, "b": 600.0, "offset": 0.0}}


def _motion(seed: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Back-and-forth moves at several speeds: position [m], velocity [m/s], acceleration [m/s^2]."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    v = np.zeros(n)
    i = 0
    while i < n:
        length = int(rng.integers(60, 200))
        speed = rng.choice([-1, 1]) * rng.uniform(2e-3, 40e-3)
        ramp = np.minimum(1.0, np.minimum(np.arange(length), length - 1 - np.arange(length)) / 10.0)
        v[i:i + length] = (speed * ramp)[: n - i]
        i += length + int(rng.integers(5, 30))
    a = np.gradient(v, t)
    s = np.cumsum(v) / FS
    return s, v, a


def _trace(seed: int, n: int = 3000, axes=("x", "y"), force=None, truth=TRUE, noise=0.01, name="cut") -> Recording:
    """A trace of `axes`; `force(axis, v, a, rng)` gives the process force [N] (None: an air cut)."""
    rng = np.random.default_rng(seed + 100)
    ch, units = {}, {}
    for k, a in enumerate(axes):
        s, v, acc = _motion(seed * 10 + k, n)
        p = truth[a]
        sigma = np.clip(v / 2e-4, -1, 1)
        F = force(a, v, acc, rng) if force is not None else np.zeros(n)
        resisting = (p["m"] * acc + p["fc"] * sigma + p["b"] * v + p["offset"])
        ch.update({f"{a}_position": s, f"{a}_velocity": v, f"{a}_acceleration": acc,
                   f"{a}_current": (resisting + F) / p["K"] + noise * rng.standard_normal(n)})
        units.update({f"{a}_position": "m", f"{a}_velocity": "m/s", f"{a}_acceleration": "m/s^2", f"{a}_current": "A"})
        if force is not None:
            ch[f"force_{a}"] = F
            units[f"force_{a}"] = "N"
    return Recording.from_arrays(ch, fs=FS, units=units, meta={"name": name})


def _cutting(axis, v, a, rng):
    """A process force that moves with the feed: on while the axis moves, plus a slow variation."""
    on = np.abs(v) > 1e-3
    return on * (120.0 + 60.0 * np.sin(np.arange(v.size) / 37.0)) * np.sign(v + 1e-12)


def test_a_negative_mass_is_impossible_and_the_active_bound_says_why():
    # something the model does not hold pulls the current against the acceleration (a stiff servo, a lag): the
    # unconstrained fit reads it as a negative mass, as it did on a real tool axis
    truth = {"x": {**TRUE["x"], "m": -280.0}}
    air = _trace(0, axes=("x",), truth=truth, name="air")
    cal = _trace(1, axes=("x",), force=_cutting, truth=truth)
    rep = identify_controller([air, cal])
    mass = rep.model.axis("x").value("inertia_x")
    assert mass >= 0.0
    assert "inertia_x" in rep.axes["x"]["active_bounds"]
    assert rep.axes["x"]["active_bounds"]["inertia_x"].startswith("at its bound (a moved mass is >= 0)")
    for t in rep.model.axis("x").terms:
        if t.name.startswith("coulomb") or t.name == "viscous":
            assert t.value >= 0.0, t
    assert rep.warnings == []


def test_air_cut_first_keeps_machine_terms_a_process_force_cannot_explain():
    # in the calibration cut the process force is proportional to the speed, i.e. collinear with viscous friction:
    # only the air cut can tell friction from process; the force constant then comes out right
    def viscous_like(axis, v, a, rng):
        return 3000.0 * v

    air = _trace(2, axes=("x",), name="air")
    cal = _trace(3, axes=("x",), force=viscous_like)
    rep = identify_controller([air, cal])
    x = rep.model.axis("x")
    assert x.K_m == pytest.approx(TRUE["x"]["K"], rel=0.05)
    assert x.value("viscous") == pytest.approx(TRUE["x"]["b"], rel=0.15)
    assert x.value("inertia_x") == pytest.approx(TRUE["x"]["m"], rel=0.1)
    terms = rep.axes["x"]["terms"]
    assert terms["viscous"]["air_cut_value"] == pytest.approx(TRUE["x"]["b"], rel=0.15)
    held = rep.axes["x"]["held_out"]
    assert held["segments"] >= 4 and held["force_rms_n"] > 0 and rep.axes["x"]["shrink"] > 0


def test_terms_are_chosen_by_held_out_error():
    air = _trace(4, name="air")
    cal = _trace(5, force=_cutting)
    rep = identify_controller([air, cal])
    for a in ("x", "y"):
        model = rep.model.axis(a)
        kept = [t.name for t in model.terms]
        assert {"offset", f"inertia_{a}", "coulomb_pos", "coulomb_neg", "viscous"} <= set(kept)
        # no position spring, no cross-axis inertia in the truth: left out, by the held-out error
        for name in ("position", f"inertia_{'y' if a == 'x' else 'x'}"):
            if name not in kept:
                assert model.dropped[name].startswith(("left out by held-out error", "not excited",
                                                       "indistinguishable")), model.dropped[name]
        assert model.K_m == pytest.approx(TRUE[a]["K"], rel=0.05)
        assert rep.axes[a]["held_out"]["calibration_force_rms_n"] is not None
    assert rep.seconds < 10.0


def test_a_horizontal_axis_offset_is_a_sensor_offset_and_a_carrier_is_not_lighter():
    truth = {"x": {**TRUE["x"], "offset": 80.0}, "y": {**TRUE["y"], "m": 150.0}}
    air = _trace(6, truth=truth, name="air")
    cal = _trace(7, force=_cutting, truth=truth)
    free = identify_controller([air, cal])
    assert free.model.axis("x").value("offset") == pytest.approx(80.0, rel=0.2)
    assert free.model.axis("y").value("inertia_y") < free.model.axis("x").value("inertia_x")
    rep = identify_controller([air, cal], vertical="y", carries={"y": ["x"]})
    x, y = rep.model.axis("x"), rep.model.axis("y")
    limit = 0.02 * float(np.max(np.abs(np.concatenate([air["x_current"], cal["x_current"]])))) * abs(x.K_m)
    assert abs(x.value("offset")) <= limit * 1.001
    assert "horizontal" in rep.axes["x"]["active_bounds"]["offset"]
    assert y.value("inertia_y") >= x.value("inertia_x") * 0.999
    assert "carries x" in rep.axes["y"]["active_bounds"]["inertia_y"]
    assert rep.kinematics == {"vertical": "y", "carries": {"y": ["x"]}}


@pytest.mark.parametrize("kwargs, match", [
    ({"vertical": "q"}, "--vertical 'q': the traces have no such axis"),
    ({"carries": {"x": ["x"]}}, "an axis cannot carry itself"),
    ({"carries": {"x": ["w"]}}, "no axis w in the traces"),
    ({"carries": {"x": ["y"], "y": ["x"]}}, "the kinematics form a loop"),
])
def test_bad_kinematics_are_refused_in_one_line(kwargs, match):
    air, cal = _trace(8, n=800, name="air"), _trace(9, n=800, force=_cutting)
    with pytest.raises(ConfigError, match=match) as info:
        identify_controller([air, cal], **kwargs)
    assert "\n" not in str(info.value)


@pytest.fixture(scope="module")
def identified():
    air = _trace(10, name="air")
    cal = _trace(11, force=_cutting)
    return identify_controller([air, cal]), cal


def test_the_regression_check_compares_held_out_errors_and_sets_the_choice(identified):
    rep, cal = identified
    assert set(rep.regression_check) == {"x", "y"}
    for a, row in rep.regression_check.items():
        assert row["ratio"] == pytest.approx(row["nrmse"]["model"] / row["nrmse"]["regression"])
        assert row["choice"] == rep.model.choice[a] and row["choice"] in ("model", "sliding", "regression")
        assert row["samples"]["calibration"] > 0 and row["samples"]["air_inside_the_cuts_motion"] > 0
    # the truth is the model's own structure: the physics wins here
    assert all(row["ratio"] < 1 and row["choice"] != "regression" for row in rep.regression_check.values())
    assert rep.model.regression is not None and set(rep.model.regression.weights) == {"x", "y"}


def test_per_axis_auto_takes_the_regression_where_the_model_lost(identified, tmp_path):
    rep, cal = identified
    model = dataclasses.replace(rep.model, choice={"x": "model", "y": "regression"})
    path = write_axes_file(tmp_path / "AXES.toml", model)
    back = read_axes_file(path)
    assert back.choice == {"x": "model", "y": "regression"}
    assert back.regression.features == model.regression.features
    auto = ModelBased(back, per_axis="auto")
    assert auto.regression_axes == ("y",)
    got = auto.estimate(cal)
    np.testing.assert_allclose(got["force_x"], ModelBased(back).estimate(cal)["force_x"])
    np.testing.assert_allclose(got["force_y"], Regression(back).estimate(cal)["force_y"])
    assert "y: the regression (--per-axis auto)" in got.meta["provenance"][-1]


def test_per_axis_auto_needs_a_model_with_its_regression(identified):
    rep, _ = identified
    bare = dataclasses.replace(rep.model, regression=None, choice={})
    with pytest.raises(ConfigError, match="--per-axis auto needs a controller model identified with a calibration"):
        ModelBased(bare, per_axis="auto")
    with pytest.raises(ConfigError, match="--per-axis must be 'model' or 'auto'"):
        ModelBased(rep.model, per_axis="best")
    with pytest.raises(ConfigError, match="holds no regression"):
        Regression(bare)
    with pytest.raises(ConfigError, match="choice y = 'regression' but the model holds no regression"):
        dataclasses.replace(rep.model, regression=None, choice={"y": "regression"})


def test_a_dynamometer_turned_against_the_machine_axis_keeps_the_model_physical():
    # the reference of x reads the process load with the opposite sign (a dynamometer frame turned against the
    # machine's): an unconstrained fit gave a negative mass and friction here; now the signs are kept apart
    air = _trace(12, name="air")
    cal = _trace(13, force=_cutting)
    turned = cal.with_channels({"force_x": -cal["force_x"]})
    rep = identify_controller([air, turned])
    x = rep.model.axis("x")
    assert x.force_sign == -1 and rep.axes["x"]["force_sign"] == -1 and "turned" in rep.axes["x"]["force_sign_note"]
    assert rep.model.axis("y").force_sign == 1
    assert x.K_m == pytest.approx(TRUE["x"]["K"], rel=0.05)
    assert x.value("inertia_x") == pytest.approx(TRUE["x"]["m"], rel=0.1) and x.value("coulomb_pos") > 0
    est = ModelBased(rep.model).estimate(turned)
    err = est["force_x"] - turned["force_x"]
    assert np.sqrt(np.mean(err ** 2)) < 0.05 * np.ptp(turned["force_x"])


def test_an_axis_the_physics_cannot_identify_gets_the_regression_under_auto(tmp_path):
    # y stands still in every trace (no friction to fix the drive's sign, nothing to identify K_m from), yet the
    # calibration cut has its force, which the other axis's current predicts: only the regression can estimate it
    def standing_y(axis, v, a, rng):
        return _cutting("x", v, a, rng)

    air = _trace(14, axes=("x",), name="air")
    cal = _trace(15, axes=("x",), force=standing_y)
    n = cal.n_samples
    still = {"y_position": np.zeros(n), "y_velocity": np.zeros(n), "y_acceleration": np.zeros(n),
             "y_current": 0.001 * np.random.default_rng(1).standard_normal(n)}
    units = {"y_position": "m", "y_velocity": "m/s", "y_acceleration": "m/s^2", "y_current": "A"}
    cal = cal.with_channels({**still, "force_y": 0.5 * cal["force_x"]}, units={**units, "force_y": "N"})
    air = air.with_channels({k: v[: air.n_samples] for k, v in still.items()}, units=units)
    rep = identify_controller([air, cal])
    assert "y" not in rep.model.axes and any("axis y left out" in w for w in rep.warnings)
    assert rep.model.choice["y"] == "regression" and rep.regression_check["y"]["note"].startswith("no physical model")
    path = write_axes_file(tmp_path / "AXES.toml", rep.model)
    auto = ModelBased(read_axes_file(path), per_axis="auto")
    assert auto.axes == ("x", "y") and auto.regression_axes == ("y",)
    got = auto.estimate(cal)
    assert np.sqrt(np.mean((got["force_y"] - cal["force_y"]) ** 2)) < 0.1 * np.ptp(cal["force_y"])
    assert ModelBased(read_axes_file(path)).axes == ("x",)


def test_with_two_calibration_cuts_the_check_leaves_out_a_whole_cut():
    air = _trace(16, name="air")
    cuts = [_trace(17, force=_cutting, name="cut a"), _trace(18, force=_cutting, name="cut b")]
    rep = identify_controller([air, *cuts])
    for row in rep.regression_check.values():
        assert row["calibration_folds"] == "leave-one-cut-out"
        assert row["samples"]["calibration"] == sum(c.n_samples for c in cuts)
    one = identify_controller([air, cuts[0]])
    assert all(r["calibration_folds"] == "leave-one-segment-out" for r in one.regression_check.values())
