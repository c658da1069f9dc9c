"""Closed-loop simulator (``drivesense.sim``): physics against closed forms and known truth.

* Open loop, linear plant, perfect sensors: the steady-state spring deflection
  under a sinusoidal table force equals the analytic FRF of the dual-inertia model.
* Closed loop at 1 mm/s with the full physics needs the paper's ~120 N of thrust;
  with the ideal plant, exactly the viscous force ``(C_r + C_t) v``.
* Encoders: quantised to 2 pi / 2^23 rad and 244 pm, delayed by ``T_b``.
* Scenarios: the ten conditions of the paper, zero force before contact, seeds.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from drivesense.machine.presets import table1_axis, table1_stage
from drivesense.recording import Recording
from drivesense.sim.encoders import LinearScale, RotaryEncoder
from drivesense.sim.scenarios import (
    ScenarioSettings,
    condition_by_name,
    paper_conditions,
    simulate_cut,
    simulate_idle,
)
from drivesense.sim.servo import ServoConfig, run_servo
from drivesense.sim.toolpath import constant_feed

AXIS = table1_axis()
QUIET = ServoConfig(current_noise=0.0, current_sensor_noise=0.0)
FS = QUIET.fs


def phasor(x: np.ndarray, t: np.ndarray, f: float) -> complex:
    """Complex amplitude ``X`` of ``x ~ Re(X e^{j w t}) + c`` by least squares."""
    w = 2 * math.pi * f
    A = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(A, x, rcond=None)
    return complex(c[0], -c[1])


def ideal_sensors():
    return {"encoder": RotaryEncoder().ideal(), "scale": LinearScale().ideal()}


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def feed_cond():
    return condition_by_name("feed_r6_S1000")[0]


@pytest.fixture(scope="module")
def full_idle(feed_scenario) -> Recording:
    """``simulate_idle(feed_cond, repeats=1)[0]``: the first of the shared idling runs (conftest)."""
    assert feed_scenario.cond.name == "feed_r6_S1000"
    return feed_scenario.idle[0]


@pytest.fixture(scope="module")
def full_cut(feed_scenario) -> Recording:
    """``simulate_cut(feed_cond, seed=0)``, shared with the estimator tests (conftest)."""
    return feed_scenario.cut


@pytest.fixture(scope="module")
def full_cross(paper_scenario) -> Recording:
    """``simulate_cut(cross_cond, seed=0)`` (conftest)."""
    return paper_scenario("cross_r1.5_S4000").cut


@pytest.fixture(scope="module")
def ideal_feed_run():
    """Closed loop, ideal plant and sensors, 1 mm/s feed, no external force."""
    traj = constant_feed(1.0, FS, 1e-3)
    n = traj.position.size
    z = np.zeros(n)
    res = run_servo(table1_stage().ideal(), QUIET, traj.position, traj.velocity, traj.acceleration,
                    z, z, **ideal_sensors())
    return traj, res


# ------------------------------------------------------------ open-loop FRF
@pytest.mark.parametrize("freq", [150.0, 600.0])
def test_open_loop_deflection_matches_analytic_frf(freq):
    n = int(0.5 * FS)
    t = np.arange(n) / FS
    amp = 10.0
    force = amp * np.sin(2 * math.pi * freq * t)
    z = np.zeros(n)
    res = run_servo(table1_stage().ideal(), QUIET, z, z, z, force, z, enabled=False, **ideal_sensors())
    np.testing.assert_array_equal(res.current_ref, 0.0)  # loop open: no current
    defl = res.true_motor_position - res.true_table_position
    sel = t > 0.2  # the vibration mode decays in ~2 ms; keep only the steady state
    measured = phasor(defl[sel], t[sel], freq)
    G = AXIS.frf([freq])
    expected = (G["xm_per_force"] - G["xt_per_force"])[0] * (-1j * amp)  # F = Re(-j A e^{jwt})
    assert abs(measured) == pytest.approx(abs(expected), rel=0.01)
    assert abs(np.degrees(np.angle(measured / expected))) < 2.0
    # the fitted sinusoid is the whole story (steady state, no drift in the deflection)
    resid = defl[sel] - np.real(measured * np.exp(2j * math.pi * freq * t[sel]))
    assert np.sqrt(np.mean(resid**2)) < 0.01 * abs(measured)


def test_open_loop_free_mass_drifts_by_rigid_body_law():
    """A constant table force on the open-loop ideal stage: terminal velocity F / (C_r + C_t)."""
    n = int(0.3 * FS)
    force = np.full(n, 50.0)
    z = np.zeros(n)
    res = run_servo(table1_stage().ideal(), QUIET, z, z, z, force, z, enabled=False, **ideal_sensors())
    v_term = 50.0 / (AXIS.C_r + AXIS.C_t)
    assert res.true_table_velocity[-1] == pytest.approx(v_term, rel=1e-3)
    # at steady velocity the spring drags the motor side along against its viscous force C_r v
    # (the C_k term vanishes at equal velocities)
    defl = res.true_motor_position[-1] - res.true_table_position[-1]
    assert defl == pytest.approx(-AXIS.C_r * v_term / AXIS.K_r, rel=1e-3)


# ------------------------------------------------------------ closed loop
def test_full_physics_needs_about_120N_of_thrust_at_1mm_per_s(full_idle):
    t = full_idle.time
    sel = (t > full_idle.meta["score_window"][0]) & (t < full_idle.duration - 0.01)
    thrust_ref = AXIS.K_t / AXIS.R * full_idle["x_current_ref"][sel]
    thrust_res = AXIS.K_t / AXIS.R * full_idle["x_current"][sel]
    assert 110.0 <= thrust_ref.mean() <= 130.0
    assert 110.0 <= thrust_res.mean() <= 130.0
    # the table keeps moving at the commanded 1 mm/s
    x = full_idle["x_table_position"][sel]
    v = np.polyfit(t[sel], x, 1)[0]
    assert v == pytest.approx(1e-3, rel=1e-3)


def test_ideal_plant_cruise_thrust_is_viscous_force(ideal_feed_run):
    traj, res = ideal_feed_run
    t = traj.time
    sel = t > 0.6
    thrust = AXIS.K_t / AXIS.R * res.current_ref[sel]
    assert thrust.mean() == pytest.approx((AXIS.C_r + AXIS.C_t) * 1e-3, rel=2e-3)
    assert np.ptp(thrust) < 0.01 * thrust.mean()
    # in steady sliding the spring carries the table's viscous force: x_m - x_t = C_t v / K_r
    defl = res.true_motor_position[sel] - res.true_table_position[sel]
    np.testing.assert_allclose(defl, AXIS.C_t * 1e-3 / AXIS.K_r, rtol=2e-3)
    # the scale tracks the reference exactly (integral action), so the true table, seen T_b later
    # by the scale, runs ahead of the reference by v T_b
    assert np.abs(res.table_position[sel] - traj.position[sel]).max() < 1e-10
    np.testing.assert_allclose(res.true_table_position[sel] - traj.position[sel], 1e-3 * QUIET.T_b,
                               rtol=1e-3)


def test_closed_loop_rigid_body_balance_at_200Hz():
    """Sum of both rows of Eq. 2: M_r a_m + M_t a_t + C_r v_m + C_t v_t = K_t I / R + F (no spring)."""
    f = 200.0
    n = int(1.0 * FS)
    t = np.arange(n) / FS
    force = 20.0 * np.sin(2 * math.pi * f * t)
    z = np.zeros(n)
    res = run_servo(table1_stage().ideal(), QUIET, z, z, z, force, z, **ideal_sensors())
    xm, xt = res.true_motor_position, res.true_table_position

    def d1(x):
        return (x[2:] - x[:-2]) * FS / 2

    def d2(x):
        return (x[2:] - 2 * x[1:-1] + x[:-2]) * FS**2

    lhs = AXIS.M_r * d2(xm) + AXIS.M_t * d2(xt) + AXIS.C_r * d1(xm) + AXIS.C_t * d1(xt)
    rhs = AXIS.K_t / AXIS.R * res.current[1:-1] + force[1:-1]  # current response = actual current
    sel = t[1:-1] > 0.3
    resid = phasor((lhs - rhs)[sel], t[1:-1][sel], f)
    # central differences alone leave ~(wT)^2/12 of the inertia force: well below 1.5 %
    assert abs(resid) < 0.015 * 20.0


# ----------------------------------------------------------------- sensors
def test_encoder_quantisation(full_cut):
    xt = full_cut["x_table_position"]
    q = xt / 244e-12
    assert np.abs(q - np.round(q)).max() < 1e-6
    th = full_cut["x_motor_angle"]
    q = th / (2 * math.pi / 2**23)
    assert np.abs(q - np.round(q)).max() < 1e-6
    # and the signals really move over many counts
    assert np.unique(xt).size > 10_000 and np.unique(th).size > 10_000


def test_ideal_sensors_are_not_quantised(ideal_feed_run):
    _, res = ideal_feed_run
    q = res.table_position / 244e-12
    assert np.abs(q - np.round(q)).max() > 0.1


@pytest.mark.parametrize("T_b", [0.2e-3, 0.5e-3])
def test_encoder_signals_lag_truth_by_Tb(T_b):
    traj = constant_feed(0.5, FS, 2e-3, t_start=0.05, ramp=0.05)
    n = traj.position.size
    z = np.zeros(n)
    cfg = replace(QUIET, T_b=T_b)
    res = run_servo(table1_stage().ideal(), cfg, traj.position, traj.velocity, traj.acceleration,
                    z, z, **ideal_sensors())
    lag = int(round(T_b * FS))
    np.testing.assert_allclose(res.table_position[lag:], res.true_table_position[:-lag], rtol=0, atol=1e-15)
    np.testing.assert_allclose(res.motor_angle[lag:] * AXIS.R, res.true_motor_position[:-lag],
                               rtol=0, atol=1e-15)
    # not the unshifted truth (the table moves 0.2 um per sample at 2 mm/s)
    moving = slice(int(0.15 * FS), None)
    assert np.abs(res.table_position[moving] - res.true_table_position[moving]).min() > 0.5 * lag * 2e-3 / FS


def test_fractional_Tb_interpolates_linearly():
    traj = constant_feed(0.3, FS, 2e-3, t_start=0.05, ramp=0.05)
    z = np.zeros(traj.position.size)
    res = run_servo(table1_stage().ideal(), replace(QUIET, T_b=0.25e-3), traj.position, traj.velocity,
                    traj.acceleration, z, z, **ideal_sensors())
    x = res.true_table_position
    expected = 0.5 * (x[:-3] + x[1:-2])  # 2.5 samples back
    np.testing.assert_allclose(res.table_position[3:], expected, rtol=0, atol=1e-15)


def test_full_physics_encoder_lag_by_cross_correlation():
    """With noise, quantisation and all the physics the table scale still lags the truth by T_b."""
    settings = ScenarioSettings()
    traj = constant_feed(1.5, FS, 1e-3)
    z = np.zeros(traj.position.size)
    res = run_servo(settings.stage, settings.servo, traj.position, traj.velocity, traj.acceleration, z, z,
                    seed=5)
    sel = slice(int(0.6 * FS), int(1.4 * FS))
    rec, true = res.table_position[sel], res.true_table_position[sel]
    lags = np.arange(0, 6)
    err = [np.sqrt(np.mean((rec[5:] - true[5 - k: true.size - k]) ** 2)) for k in lags]
    assert int(lags[np.argmin(err)]) == round(settings.servo.T_b * FS)
    assert min(err) < 1e-9  # 0.5 nm noise + 244 pm quantisation
    assert max(err) > 1e-7  # 0.1 um per sample of lag at 1 mm/s


# --------------------------------------------------------------- scenarios
def test_ten_paper_conditions():
    conds = paper_conditions()
    assert len(conds) == 10
    got = {(c.direction, round(c.radial_depth * 1e3, 3), c.spindle_rpm) for c in conds}
    feed = {(1.5, 1000), (1.5, 4000), (6.0, 1000), (1.5, 10000), (6.0, 10000)}   # Fig. 15
    cross = {(1.5, 1000), (1.5, 4000), (6.0, 4000), (1.5, 10000), (6.0, 10000)}  # Fig. 21
    assert got == {("feed", r, float(s)) for r, s in feed} | {("cross", r, float(s)) for r, s in cross}
    assert len({c.name for c in conds}) == 10
    for c in conds:
        assert c.feed_speed == pytest.approx(1e-3)
        assert condition_by_name(c.name) == (c, False)
        assert c.name.startswith(c.direction)
    assert condition_by_name("idle_feed_r6_S1000")[1] is True
    with pytest.raises(KeyError, match="unknown scenario"):
        condition_by_name("feed_r3_S1000")


@pytest.mark.parametrize("which", ["full_cut", "full_cross"])
def test_true_force_zero_before_contact(which, request):
    rec = request.getfixturevalue(which)
    t = rec.time
    tc = rec.meta["t_contact"]
    for ch in ("force_x", "force_y", "force_z"):
        np.testing.assert_array_equal(rec[ch][t < tc], 0.0)
    # the tool is in the material soon after the contact time (0.4 s of feed for a 1.5 mm,
    # down-milling engagement that starts at 120 deg of immersion)
    after = (t >= tc) & (t < tc + 0.5)
    assert np.abs(rec["force_x"][after]).max() > 1.0
    assert np.abs(rec["force_x"][t > 5.0]).max() > 5.0
    assert rec.meta["tare_window"][1] <= tc and rec.meta["score_window"][0] < tc


def test_cross_condition_x_axis_stands_still(full_cross):
    t = full_cross.time
    x = full_cross["x_table_position"]
    assert np.ptp(x[t < full_cross.meta["t_contact"]]) < 1e-7
    y = full_cross["y_table_position"]
    assert y[-1] == pytest.approx(1e-3 * (t[-1] - 0.25), rel=1e-2)


def test_idle_runs_have_no_force(feed_cond):
    runs = simulate_idle(feed_cond, ScenarioSettings(duration=1.0), repeats=2)
    assert len(runs) == 2
    for r in runs:
        for ch in ("force_x", "force_y", "force_z"):
            np.testing.assert_array_equal(r[ch], 0.0)
        assert r.meta["kind"] == "idle"
    assert not np.array_equal(runs[0]["x_current_ref"], runs[1]["x_current_ref"])


def test_same_seed_identical_different_seed_differs(feed_cond, full_cut):
    again = simulate_cut(feed_cond, seed=0)
    assert again.equals(full_cut)
    other = simulate_cut(feed_cond, seed=1)
    for ch in ("x_current_ref", "x_current", "x_motor_angle", "x_table_position", "force_x"):
        assert not np.array_equal(other[ch], full_cut[ch]), ch
    assert other.meta["seed"] == 1 and full_cut.meta["seed"] == 0


def test_run_servo_is_deterministic_and_seeded():
    traj = constant_feed(0.2, FS, 1e-3, t_start=0.02, ramp=0.05)
    z = np.zeros(traj.position.size)
    args = (table1_stage(), ServoConfig(), traj.position, traj.velocity, traj.acceleration, z, z)
    a, b, c = run_servo(*args, seed=3), run_servo(*args, seed=3), run_servo(*args, seed=4)
    for name in ("current_ref", "current", "motor_angle", "table_position", "true_table_position"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.current, c.current)


def test_run_servo_rejects_unequal_lengths():
    with pytest.raises(ValueError, match="same length"):
        run_servo(table1_stage(), QUIET, np.zeros(10), np.zeros(10), np.zeros(10), np.zeros(9), np.zeros(10))
