"""Force estimators of the first paper (CurrentOnly, RigidBody, MEDOB, VibrationMode).

Known truth:

* data generated from exactly the estimators' model (``ScenarioSettings().as_ideal()``)
  must give the true force back, to the discretisation error;
* idling on the ideal plant gives zero force;
* RigidBody (Eq. 5) and MEDOB (Appendix) are the same estimating equation and
  differ only in discretisation (one sample of latency);
* streaming and batch run the same kernel with the same state: identical numbers;
* the closed-loop response to a sinusoidal table force is the force through the
  estimator's low-pass, delayed by its declared latency.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal as sps

from drivesense.errors import MissingChannelError
from drivesense.estimate import MEDOB, CurrentOnly, RigidBody, SignalParams, VibrationMode
from drivesense.estimate.design import lowpass_sos
from drivesense.machine.presets import table1_axis, table1_stage
from drivesense.recording import Recording
from drivesense.score import score_estimate
from drivesense.sim.encoders import LinearScale, RotaryEncoder
from drivesense.sim.servo import ServoConfig, run_servo

AXIS = table1_axis()
FS = 10_000.0
SOS = lowpass_sos(SignalParams(), FS)
METHODS = [CurrentOnly, RigidBody, MEDOB, VibrationMode]
MODEL_BASED = [RigidBody, MEDOB, VibrationMode]
FEED = "feed_r6_S1000"
CROSS = "cross_r6_S4000"


def make(cls, rec: dict | None = None, name: str | None = None):
    """An estimator compensated as the paper does: idle-run map for feed, tare for cross-feed."""
    est = cls(AXIS, SignalParams())
    if rec is not None:
        if rec["idle"] is not None:
            est.fit(rec["idle"])
        else:
            est.tare(rec["cut"], *rec["cut"].meta["tare_window"])
    return est


def nrmse(est_rec: Recording, ref: Recording) -> float:
    return score_estimate(est_rec, ref, sos=SOS).nrmse


def phasor(x: np.ndarray, t: np.ndarray, f: float) -> complex:
    w = 2 * math.pi * f
    A = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(A, x, rcond=None)
    return complex(c[0], -c[1])


# ------------------------------------------------------------------ fixtures
def _scenario(paper_scenario, name: str, ideal: bool) -> dict:
    """The cut and (feed direction) its idling runs, shared for the session (conftest)."""
    s = paper_scenario(name, ideal=ideal)
    return {"cut": s.cut, "idle": s.idle}


@pytest.fixture(scope="module")
def ideal(paper_scenario):
    """``ScenarioSettings().as_ideal()``: data from exactly the estimators' model."""
    return {FEED: _scenario(paper_scenario, FEED, True), CROSS: _scenario(paper_scenario, CROSS, True)}


@pytest.fixture(scope="module")
def full(paper_scenario):
    """``ScenarioSettings()``: the full physics of the Table 1 stage."""
    return {FEED: _scenario(paper_scenario, FEED, False), CROSS: _scenario(paper_scenario, CROSS, False)}


# ------------------------------------------------------------ ideal physics
@pytest.mark.parametrize("scenario", [FEED, CROSS])
@pytest.mark.parametrize("cls", MODEL_BASED, ids=lambda c: c.__name__)
def test_ideal_physics_recovers_true_force(ideal, cls, scenario):
    data = ideal[scenario]
    assert "ideal" in data["cut"].meta["physics"]
    est = make(cls).estimate(data["cut"])  # no friction in the ideal plant: no compensation needed
    limit = 0.01 if cls is VibrationMode else 0.02
    assert nrmse(est, data["cut"]) < limit
    # with the paper's compensation as well (the map / tare of a frictionless plant is ~0)
    assert nrmse(make(cls, data).estimate(data["cut"]), data["cut"]) < limit


@pytest.mark.parametrize("scenario", [FEED, CROSS])
def test_ideal_physics_current_only_does_not(ideal, scenario):
    """Motor thrust alone misses the inertia and damping forces, even on the ideal plant."""
    data = ideal[scenario]
    assert nrmse(make(CurrentOnly, data).estimate(data["cut"]), data["cut"]) > 0.1


@pytest.mark.parametrize("cls", MODEL_BASED, ids=lambda c: c.__name__)
def test_ideal_idle_gives_zero_force(ideal, cls):
    idle = ideal[FEED]["idle"][0]
    e = make(cls)
    f = e.estimate(idle)["force_x"]
    t = idle.time
    after = t >= e.settle_time(idle.fs)
    assert np.abs(f[after]).max() < 0.5
    assert abs(f[after].mean()) < 0.05


def _sinusoid_response(cls, freq):
    """Ideal plant, closed loop at standstill, 20 N sinusoid on the table: phasor of the estimate."""
    cfg = ServoConfig(current_noise=0.0, current_sensor_noise=0.0)
    n = int(0.6 * FS)
    t = np.arange(n) / FS
    force = 20.0 * np.sin(2 * math.pi * freq * t)
    z = np.zeros(n)
    res = run_servo(table1_stage().ideal(), cfg, z, z, z, force, z,
                    encoder=RotaryEncoder().ideal(), scale=LinearScale().ideal())
    rec = Recording.from_arrays({"x_current_ref": res.current_ref, "x_motor_angle": res.motor_angle,
                                 "x_table_position": res.table_position, "force_x": force}, fs=FS)
    out = cls(AXIS, SignalParams()).estimate(rec)
    sel = t > 0.2
    _, h = sps.sosfreqz(SOS, worN=[freq], fs=FS)
    return phasor(out["force_x"][sel], t[sel], freq), h[0], out.meta["latency_s"]


@pytest.mark.parametrize("freq", [100.0, 200.0])
def test_vibration_mode_closed_loop_sinusoid_response(freq):
    """Estimate = LPF(force) delayed by the declared latency, in amplitude and phase."""
    got, h, latency = _sinusoid_response(VibrationMode, freq)
    assert abs(got) == pytest.approx(20.0 * abs(h), rel=0.01)
    expected = -20j * h * np.exp(-2j * math.pi * freq * latency)  # F = Re(-20j e^{jwt})
    assert abs(np.degrees(np.angle(got / expected))) < 1.0


@pytest.mark.parametrize("cls", [RigidBody, MEDOB], ids=lambda c: c.__name__)
def test_rigid_mode_closed_loop_sinusoid_response(cls):
    got, h, _ = _sinusoid_response(cls, 200.0)
    assert abs(got) == pytest.approx(20.0 * abs(h), rel=0.015)


# --------------------------------------------------------- RigidBody vs MEDOB
def test_latencies():
    sig = SignalParams()
    assert RigidBody(AXIS, sig).design(FS).latency_s == pytest.approx(sig.T_b + 1 / FS, abs=1e-15)
    assert MEDOB(AXIS, sig).design(FS).latency_s == pytest.approx(sig.T_b, abs=1e-15)
    assert VibrationMode(AXIS, sig).design(FS).latency_s == pytest.approx(sig.T_b + 1 / FS, abs=1e-15)
    assert RigidBody(AXIS, sig).stream(FS).latency_s == pytest.approx(sig.T_b + 1 / FS, abs=1e-15)


def test_rigid_body_and_medob_agree_on_full_physics(full):
    data = full[FEED]
    cut = data["cut"]
    r_rec = make(RigidBody, data).estimate(cut)
    m_rec = make(MEDOB, data).estimate(cut)
    assert r_rec.meta["latency_s"] == pytest.approx(cut.meta["true_signal"]["T_b"] + 1 / FS)
    assert m_rec.meta["latency_s"] == pytest.approx(cut.meta["true_signal"]["T_b"])
    shift = round((r_rec.meta["latency_s"] - m_rec.meta["latency_s"]) * FS)
    assert shift == 1
    r, m = r_rec["force_x"], m_rec["force_x"]
    t = cut.time
    keep = t[shift:] > 0.05
    p2p = np.ptp(cut["force_x"])
    aligned = np.abs(r[shift:] - m[:-shift])[keep].max()
    assert aligned < 0.02 * p2p
    # the alignment matters: unaligned they differ by several times more
    assert np.abs(r - m)[t > 0.05].max() > 3 * aligned


def test_rigid_body_uses_paper_appendix_coefficients():
    """Eq. 5 in (x_m, x_t): M_r a_m + M_t a_t, C_rigid split by (1, alpha)/(1 + alpha); no stiffness."""
    c = RigidBody(AXIS).combination()
    m = MEDOB(AXIS).combination()
    assert (c.c_I, c.m_m, c.m_t, c.k_m, c.k_t) == (1.0, AXIS.M_r, AXIS.M_t, 0.0, 0.0)
    assert c.c_m + c.c_t == pytest.approx(AXIS.modal_matrices().C[0, 0], rel=1e-12)
    # under proportional damping this is the MEDOB equation (C_r on the motor, C_t on the table)
    assert c.c_m == pytest.approx(m.c_m, rel=2e-3) and c.c_t == pytest.approx(m.c_t, rel=2e-3)
    v = VibrationMode(AXIS).combination()
    assert v.c_I == pytest.approx(-AXIS.alpha) and v.k_t == pytest.approx((1 + AXIS.alpha) * AXIS.K_r)


# ------------------------------------------------------------- full physics
def test_full_physics_feed_vibration_mode_accurate(full):
    data = full[FEED]
    assert nrmse(make(VibrationMode, data).estimate(data["cut"]), data["cut"]) <= 0.05


def test_full_physics_cross_vibration_beats_rigid(full):
    data = full[CROSS]
    vib = nrmse(make(VibrationMode, data).estimate(data["cut"]), data["cut"])
    rig = nrmse(make(RigidBody, data).estimate(data["cut"]), data["cut"])
    assert vib <= 0.05
    assert rig >= 3 * vib


def test_full_physics_friction_map_needed_in_rigid_mode(full):
    """Without the idle-run map the rigid-mode estimate carries the ~120 N of kinetic friction."""
    data = full[FEED]
    raw = make(RigidBody).estimate(data["cut"])
    fitted = make(RigidBody, data).estimate(data["cut"])
    t = data["cut"].time
    cruise = (t > 0.6) & (t < data["cut"].meta["t_contact"])
    assert -130 < raw["force_x"][cruise].mean() < -110
    assert abs(fitted["force_x"][cruise].mean()) < 5
    assert nrmse(fitted, data["cut"]) < 0.5 * nrmse(raw, data["cut"])


# ------------------------------------------------------------- streaming
@pytest.fixture(scope="module")
def fitted_full(full):
    return {cls: make(cls, full[FEED]) for cls in METHODS}


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.__name__)
def test_stream_equals_batch_fixed_chunks(full, fitted_full, cls):
    cut = full[FEED]["cut"]
    est = fitted_full[cls]
    batch = est.estimate(cut)["force_x"]
    cur, ang, tab = (cut[c] for c in est.channel_names)
    state = est.stream(cut.fs)
    out = np.concatenate([state.push_arrays(cur[i:i + 10], ang[i:i + 10], tab[i:i + 10])["force_x"]
                          for i in range(0, cut.n_samples, 10)])
    assert out.shape == batch.shape
    np.testing.assert_array_equal(out, batch)
    assert state.samples_seen == cut.n_samples


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.__name__)
def test_stream_equals_batch_random_chunks(full, fitted_full, cls):
    cut = full[FEED]["cut"]
    est = fitted_full[cls]
    batch = est.estimate(cut)["force_x"]
    cur, ang, tab = (cut[c] for c in est.channel_names)
    rng = np.random.default_rng(7)
    bounds = [0]
    while bounds[-1] < cut.n_samples:
        bounds.append(min(bounds[-1] + int(rng.integers(0, 700)), cut.n_samples))  # 0-length chunks too
    state = est.stream(cut.fs)
    parts = [state.push_arrays(cur[a:b], ang[a:b], tab[a:b])["force_x"] for a, b in zip(bounds[:-1], bounds[1:])]
    out = np.concatenate(parts)
    assert np.abs(out - batch).max() <= 1e-9
    np.testing.assert_array_equal(out, batch)


@pytest.mark.parametrize("cls", [RigidBody, VibrationMode], ids=lambda c: c.__name__)
def test_stream_recording_and_mapping_chunks(full, fitted_full, cls):
    cut = full[FEED]["cut"].slice_time(0.0, 1.0)
    est = fitted_full[cls]
    batch = est.estimate(cut)
    state = est.stream(cut.fs)
    got = []
    for k in range(20):
        chunk = cut.slice_time(k * 0.05, (k + 1) * 0.05)
        if k % 2 == 0:
            out = state.push(chunk)
            assert isinstance(out, Recording)
            assert out.channels == ["force_x"] and out.units("force_x") == "N"
            assert out.t0 == pytest.approx(chunk.t0) and out.n_samples == chunk.n_samples
            assert out.meta["latency_s"] == pytest.approx(batch.meta["latency_s"])
            got.append(out["force_x"])
        else:  # a plain mapping (bare channel names) gives a dict of arrays
            out = state.push({"current_ref": chunk["x_current_ref"], "motor_angle": chunk["x_motor_angle"],
                              "table_position": chunk["x_table_position"]})
            assert isinstance(out, dict) and list(out) == ["force_x"]
            got.append(out["force_x"])
    np.testing.assert_array_equal(np.concatenate(got), batch["force_x"])
    with pytest.raises(MissingChannelError, match="table_position"):
        state.push({"current_ref": np.zeros(3), "motor_angle": np.zeros(3)})


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.__name__)
def test_stream_state_does_not_grow(cls):
    est = cls(AXIS, SignalParams())
    state = est.stream(FS)
    rng = np.random.default_rng(0)
    chunk = [rng.normal(size=10), rng.normal(size=10) * 1e-3, rng.normal(size=10) * 1e-6]
    state.push_arrays(*chunk)
    shapes = (state.state.hist.shape, state.state.zi.shape, state.state.scalars.shape)
    for _ in range(10_000):
        state.push_arrays(*chunk)
    assert (state.state.hist.shape, state.state.zi.shape, state.state.scalars.shape) == shapes
    assert state.samples_seen == 10 * 10_001


def test_estimate_output_recording(full, fitted_full):
    cut = full[FEED]["cut"]
    out = fitted_full[VibrationMode].estimate(cut)
    assert out.channels == ["force_x"] and out.units("force_x") == "N"
    assert out.n_samples == cut.n_samples and out.fs == cut.fs and out.t0 == cut.t0
    assert out.meta["method"] == "vibration" and out.meta["latency_s"] > 0
