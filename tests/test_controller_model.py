"""The controller-rate machine model and ``identify nc``: closed forms on traces generated from the model itself."""

from __future__ import annotations

import math

import numpy as np
import pytest

import drivesense as ds
from drivesense.errors import ConfigError, IdentificationError, MissingChannelError
from drivesense.identify.controller import identify_controller
from drivesense.machine.controller_model import (ControllerAxis, ControllerModel, ControllerTerm, feature_column,
                                                 friction_direction)
from drivesense.recording import Recording

FS = 50.0
G = 9.81
#: The truth: K_m as logged (X and Y oppose the motion), moved masses, a vertical Z with a net weight.
TRUE = {"x": {"K_m": -520.0, "offset": 0.0, "inertia_x": 600.0, "coulomb_pos": 180.0, "coulomb_neg": 170.0,
              "viscous": 900.0},
        "y": {"K_m": -610.0, "offset": 0.0, "inertia_y": 1100.0, "coulomb_pos": 260.0, "coulomb_neg": 240.0,
              "viscous": 1200.0},
        "z": {"K_m": 480.0, "offset": 330.0 * G * 0.15, "inertia_z": 330.0, "coulomb_pos": 150.0,
              "coulomb_neg": 210.0, "viscous": 700.0}}
V_EPS = 2e-5


def _motion(rng, n, amplitude, hold=True):
    """Smooth back-and-forth motion with holds [m], its velocity [m/s] and acceleration [m/s^2] (exact)."""
    t = np.arange(n) / FS
    s = np.zeros(n)
    v = np.zeros(n)
    a = np.zeros(n)
    for _ in range(3):
        f = rng.uniform(0.05, 0.4)
        ph = rng.uniform(0, 2 * math.pi)
        amp = amplitude * rng.uniform(0.3, 1.0)
        w = 2 * math.pi * f
        s += amp * np.sin(w * t + ph)
        v += amp * w * np.cos(w * t + ph)
        a -= amp * w * w * np.sin(w * t + ph)
    if hold:     # standstills: the axis holds every other 4 s
        gate = (np.floor(t / 4.0) % 2 == 0).astype(float)
        v, a = v * gate, a * gate
        s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / FS)])
    return s, v, a


def _trace(seed: int, *, force: bool, n: int = 3000, truth=TRUE, noise: float = 0.01, z_moves: bool = True):
    rng = np.random.default_rng(seed)
    arrays = {}
    for ax in ("x", "y", "z"):
        s, v, a = _motion(rng, n, 0.05 if (ax != "z" or z_moves) else 0.0)
        arrays.update({f"{ax}_position": s + 0.2, f"{ax}_velocity": v, f"{ax}_acceleration": a})
    forces = {}
    for ax, p in truth.items():
        d = friction_direction(arrays[f"{ax}_velocity"], arrays[f"{ax}_acceleration"], 0.0, V_EPS)
        resist = sum(val * feature_column(name, ax, arrays, window_s=0.0, v_eps=V_EPS, direction=d)
                     for name, val in p.items() if name != "K_m")
        f = 300.0 * np.sin(np.arange(n) / FS * 2 * math.pi * 0.7 + seed) * force
        forces[ax] = f
        arrays[f"{ax}_current"] = (f + resist) / p["K_m"] + noise * rng.standard_normal(n)
    arrays["spindle_current"] = np.full(n, 3.0)
    arrays["spindle_speed"] = np.full(n, 800.0)
    if force:
        arrays.update({f"force_{ax}": forces[ax] for ax in truth})
    return Recording.from_arrays(arrays, fs=FS, meta={"name": f"{'cut' if force else 'air'}_{seed}"})


@pytest.fixture(scope="module")
def identified():
    return identify_controller([_trace(1, force=False), _trace(2, force=True)], window_s=0.0, delay_s=0.0)


def test_sign_and_gravity_come_out_of_the_closed_form(identified):
    model = identified.model
    for ax, p in TRUE.items():
        m = model.axis(ax)
        assert m.K_m == pytest.approx(p["K_m"], rel=0.01), ax
        assert abs(m.K_m - p["K_m"]) <= max(m.K_m_ci95, 1e-9) * 2, ax     # the interval holds the truth
        assert m.value(f"inertia_{ax}") == pytest.approx(p[f"inertia_{ax}"], rel=0.02)
        assert m.value("coulomb_pos") == pytest.approx(p["coulomb_pos"], rel=0.05)
        assert m.value("coulomb_neg") == pytest.approx(p["coulomb_neg"], rel=0.05)
    # the vertical axis's net weight is its offset; the currents of X and Y oppose the motion (K_m < 0)
    assert model.axis("z").value("offset") == pytest.approx(TRUE["z"]["offset"], rel=0.03)
    assert model.axis("x").K_m < 0 and model.axis("y").K_m < 0 and model.axis("z").K_m > 0
    assert identified.seconds < 10.0


def test_every_term_carries_a_confidence_interval(identified):
    for ax, rep in identified.axes.items():
        assert rep["K_m_ci95"] > 0
        for name, term in rep["terms"].items():
            assert term["ci95"] > 0 and term["unit"], (ax, name)


def test_no_force_at_idle_and_the_truth_on_a_held_out_cut(identified):
    est = ds.estimate.make("model", axes=identified.model)
    air = _trace(5, force=False)
    out = est.estimate(air)
    for ax in "xyz":
        assert np.sqrt(np.mean(out[f"force_{ax}"] ** 2)) < 15.0      # N, on 300 N cuts: current noise x |K_m|
    cut = _trace(6, force=True)
    out = est.estimate(cut)
    for ax in "xyz":
        err = out[f"force_{ax}"] - cut[f"force_{ax}"]
        assert np.sqrt(np.mean(err ** 2)) < 15.0


def test_undetermined_terms_are_dropped_with_the_reason():
    """Z never moves: its friction, viscous and inertia are not excited; its weight (offset) still is."""
    air = _trace(1, force=False, z_moves=False)
    cut = _trace(2, force=True, z_moves=False)
    rep = identify_controller([air, cut], window_s=0.0, delay_s=0.0)
    z = rep.model.axis("z")
    for name in ("coulomb_pos", "coulomb_neg", "viscous"):
        assert name not in [t.name for t in z.terms]
        assert z.dropped[name].startswith("not excited"), z.dropped[name]
    assert z.value("offset") == pytest.approx(TRUE["z"]["offset"], rel=0.03)
    for ax in ("x", "y"):
        assert rep.model.axis(ax).dropped["inertia_z"].startswith("not excited")
    # a term the data excite but that is not there: position (no spring in the truth) is not determined
    x = rep.model.axis("x")
    assert "position" not in [t.name for t in x.terms]
    assert x.dropped["position"].startswith(("left out by held-out error", "indistinguishable"))


def test_a_given_force_constant_replaces_the_calibration():
    air = _trace(1, force=False)
    rep = identify_controller([air], km={"x": -520.0, "y": -610.0, "z": 480.0}, window_s=0.0)
    assert rep.model.axis("z").value("offset") == pytest.approx(TRUE["z"]["offset"], rel=0.03)
    assert rep.axes["x"]["K_m_source"].startswith("given")
    with pytest.raises(IdentificationError, match="--km"):
        identify_controller([air])


def test_bad_traces_are_refused_with_the_option_that_helps():
    air = _trace(1, force=False)
    slow = Recording.from_arrays({c: air[c][::4] for c in air.channels}, fs=12.5)
    with pytest.raises(ConfigError, match="25 Hz"):
        identify_controller([slow], km={"x": 1.0, "y": 1.0, "z": 1.0})
    other = Recording.from_arrays({c: air[c] for c in air.channels}, fs=100.0)
    with pytest.raises(ConfigError, match="--resample"):
        identify_controller([air, other], km={"x": 1.0, "y": 1.0, "z": 1.0})
    with pytest.raises(MissingChannelError):
        identify_controller([air.select("x_position", "spindle_current")])
    with pytest.raises(ConfigError):
        identify_controller([])


def test_window_mean_of_the_friction_direction():
    """A reversal inside the logging window averages sgn(v): v / (|a| T / 2), clipped."""
    T = 0.02
    a = np.array([1.0, 1.0, 1.0, 0.0])
    v = np.array([0.0, 0.005, 0.02, -0.001])
    d = friction_direction(v, a, T, 1e-5)
    assert d == pytest.approx([0.0, 0.5, 1.0, -1.0])
    # a position-periodic term travelling a whole period in the window averages out (sinc)
    arrays = {"x_position": np.array([0.0025]), "x_velocity": np.array([0.5]), "x_acceleration": np.zeros(1)}
    assert feature_column("ripple1_sin", "x", arrays, window_s=T, v_eps=1e-5, period=0.01)[0] == pytest.approx(0.0, abs=1e-12)
    arrays["x_velocity"] = np.array([0.0])
    assert feature_column("ripple1_sin", "x", arrays, window_s=T, v_eps=1e-5, period=0.01)[0] == pytest.approx(1.0)


def test_axes_file_round_trip_and_bad_tables(tmp_path, identified):
    from dataclasses import replace

    model = identified.model
    model = ControllerModel(axes={**model.axes, "x": replace(model.axis("x"), x_pre=5e-6, hold_time=3.0)},
                            window_s=model.window_s, delay_s=model.delay_s, rate_hz=model.rate_hz)
    path = ds.write_axes_file(tmp_path / "axes.toml", model)
    back = ds.read_axes_file(path)
    assert isinstance(back, ControllerModel)
    assert back.to_dict() == model.to_dict()
    text = path.read_text()
    assert 'model = "controller"' in text and "[x.terms]" in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("K_m = ", "K_mm = ", 1))
    with pytest.raises(ConfigError, match=r"\[x\].*unknown key\(s\) K_mm"):
        ds.read_axes_file(bad)
    bad.write_text(text.replace('model = "controller"', 'model = "spline"'))
    with pytest.raises(ConfigError, match="spline"):
        ds.read_axes_file(bad)


def test_model_values_are_checked():
    with pytest.raises(ConfigError, match="nonzero"):
        ControllerAxis(K_m=0.0, terms=(), v_eps=1e-5)
    with pytest.raises(ConfigError, match="unknown"):
        ControllerTerm("gravity_well", 1.0)
    with pytest.raises(ConfigError, match="period"):
        ControllerAxis(K_m=1.0, terms=(ControllerTerm("ripple1_sin", 1.0),), v_eps=1e-5)


def test_stream_equals_batch_and_latency_is_the_identified_delay(identified):
    est = ds.estimate.make("model", axes=identified.model)
    cut = _trace(7, force=True, n=600)
    batch = est.estimate(cut)
    stream = est.stream(FS)
    parts = [stream.push({c: cut[c][i:i + 37] for c in est.channel_names}) for i in range(0, 600, 37)]
    for ax in "xyz":
        assert np.array_equal(np.concatenate([p[f"force_{ax}"] for p in parts]), batch[f"force_{ax}"])
    assert batch.meta["latency_s"] == identified.model.delay_s


def test_confidence_intervals_cover_the_truth_with_autocorrelated_residuals():
    """AR(1) noise (rho 0.9) makes the textbook interval ~4x too narrow; the corrected one covers ~95 %."""
    from drivesense.identify.least_squares import residual_variance, solve_least_squares

    rng = np.random.default_rng(3)
    n, hits = 2000, 0
    t = np.arange(n) / 100.0
    X = np.column_stack([np.ones(n), np.sin(0.7 * t), np.sign(np.sin(0.23 * t))])
    for trial in range(200):
        e = np.zeros(n)
        w = rng.standard_normal(n)
        for k in range(1, n):
            e[k] = 0.9 * e[k - 1] + w[k]
        fit = solve_least_squares(X, X @ np.array([1.0, 2.0, 3.0]) + e, ["a", "b", "c"])
        hits += abs(fit.theta[1] - 2.0) <= 1.96 * np.sqrt(fit.cov[1, 1])
    assert 0.85 <= hits / 200 <= 1.0
    white = rng.standard_normal(100000)
    assert residual_variance(white, 0) == pytest.approx(1.0, rel=0.03)
