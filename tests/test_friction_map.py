"""Friction maps from idling runs (first paper, Sec. 4) and their coverage checks.

Three air-cut runs over the cut's trajectory (full physics, 1 mm/s) give the
friction versus table position in each estimator's space; the map must cover
the travel, be repeatable (run-to-run spread small against its variation), and
refuse traces that leave the mapped positions.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivesense.errors import CoverageError
from drivesense.estimate import MEDOB, CurrentOnly, RigidBody, SignalParams, VibrationMode
from drivesense.estimate.friction_map import FrictionMap, build_friction_map
from drivesense.machine.presets import table1_axis
from drivesense.recording import Recording
from drivesense.sim.scenarios import simulate_idle

AXIS = table1_axis()
METHODS = [CurrentOnly, RigidBody, MEDOB, VibrationMode]


@pytest.fixture(scope="module")
def cond(paper_scenario):
    return paper_scenario("feed_r1.5_S4000").cond


@pytest.fixture(scope="module")
def idle(paper_scenario) -> tuple[Recording, ...]:
    """``simulate_idle(cond, repeats=3)``, shared for the session (conftest)."""
    return paper_scenario("feed_r1.5_S4000").idle


@pytest.fixture(scope="module")
def cut(paper_scenario) -> Recording:
    """``simulate_cut(cond)`` (conftest)."""
    return paper_scenario("feed_r1.5_S4000").cut


@pytest.fixture(scope="module")
def maps(idle) -> dict:
    return {cls: cls(AXIS, SignalParams()).fit(idle).friction_map for cls in METHODS}


def shifted(rec: Recording, dx: float) -> Recording:
    return rec.with_channels({"x_table_position": rec["x_table_position"] + dx})


# ------------------------------------------------------------------ the map
@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.__name__)
def test_map_covers_the_travel(maps, idle, cls):
    m = maps[cls]
    assert isinstance(m, FrictionMap)
    assert m.method == cls.name and m.direction == 1
    x = np.concatenate([r["x_table_position"] for r in idle])
    w = m.bin_width
    assert w == pytest.approx(1e-6)  # default bins: 10 samples each at 1 mm/s and 10 kHz
    np.testing.assert_allclose(np.diff(m.position), w, rtol=1e-9)
    assert m.position[0] <= x.min() + w
    assert m.position[-1] >= x.max() - w
    assert m.position[-1] - m.position[0] == pytest.approx(np.ptp(x), abs=2 * w)
    assert m.force.shape == m.position.shape == m.spread.shape
    assert m.runs.shape == (3, m.position.size)
    assert np.isfinite(m.force).all()
    # every run reached (nearly) every bin
    assert np.isfinite(m.runs).mean() > 0.99
    np.testing.assert_allclose(m.force, np.nanmean(m.runs, axis=0), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.__name__)
def test_map_is_repeatable(maps, cls):
    m = maps[cls]
    rep = m.repeatability_rms
    assert np.isfinite(rep) and rep > 0
    cruise = m.position > 0.5e-3  # past the acceleration ramp
    variation = np.ptp(m.force[cruise])
    assert variation > 5.0  # position-dependent ripple of several N
    assert rep < 0.1 * variation
    if cls is VibrationMode:  # relative motion: friction level changes barely matter
        assert rep < 0.02 * variation
        assert rep < 0.05 * np.std(m.force[cruise])


def test_map_reads_the_kinetic_friction(maps):
    """Uncompensated thrust during cruise is the stage's ~120 N of kinetic friction (Fig. 19a)."""
    m = maps[CurrentOnly]
    cruise = m.position > 0.5e-3
    assert -130.0 < m.force[cruise].mean() < -110.0
    # rigid mode: thrust minus the viscous force (C_r + C_t) v of the linear model
    r = maps[RigidBody]
    viscous = (AXIS.C_r + AXIS.C_t) * 1e-3
    assert r.force[cruise].mean() == pytest.approx(m.force[cruise].mean() + viscous, abs=1.0)


def test_map_single_run_has_nan_spread(idle):
    m = VibrationMode(AXIS).fit(idle[:1]).friction_map
    assert np.isnan(m.spread).all() and np.isnan(m.repeatability_rms)
    assert np.isfinite(m.force).all()


def test_bins_widen_to_hold_enough_samples(idle):
    m = build_friction_map(VibrationMode(AXIS), idle, bin_width=1e-8, min_samples_per_bin=5)
    assert m.bin_width == pytest.approx(5 * 1e-3 / 1e4, rel=1e-3)  # 5 samples at 1 mm/s


def test_map_removes_friction_from_a_new_idle_run(cond, idle):
    """A fourth idle run (new seed) estimated with the map: what is left is small."""
    new = simulate_idle(cond, repeats=1, seed=4242)[0]
    t = new.time
    cruise = t > 0.6
    for cls in (RigidBody, VibrationMode):
        raw = cls(AXIS).estimate(new)["force_x"][cruise]
        comp = cls(AXIS).fit(idle).estimate(new)["force_x"][cruise]
        assert np.sqrt(np.mean(comp**2)) < 0.2 * np.sqrt(np.mean(raw**2)), cls.__name__
    vib = VibrationMode(AXIS).fit(idle).estimate(new)["force_x"][cruise]
    assert np.sqrt(np.mean(vib**2)) < 1.0


def test_fitted_estimate_accepts_the_cut(maps, idle, cut):
    est = VibrationMode(AXIS).fit(idle)
    out = est.estimate(cut)
    assert out.n_samples == cut.n_samples
    # a few um of extra deflection under the cutting load is tolerated
    est.estimate(shifted(cut, 5e-6))


# ----------------------------------------------------------------- coverage
@pytest.mark.parametrize("dx", [5e-3, -5e-3])
def test_cut_beyond_mapped_positions_raises(idle, cut, dx):
    est = RigidBody(AXIS).fit(idle)
    moved = shifted(cut, dx)
    with pytest.raises(CoverageError, match="idle runs cover table positions") as exc:
        est.estimate(moved)
    assert isinstance(exc.value, ValueError)
    assert cut.meta["name"] in str(exc.value)


def test_cut_beyond_map_built_from_arrays(idle, cut):
    est = VibrationMode(AXIS).fit(idle)
    moved = Recording.from_arrays({"x_current_ref": cut["x_current_ref"], "x_motor_angle": cut["x_motor_angle"],
                                   "x_table_position": cut["x_table_position"] + 5e-3},
                                  fs=cut.fs, meta={"name": "moved"})
    with pytest.raises(CoverageError, match="moved"):
        est.estimate(moved)


def test_check_coverage_directly(maps):
    m = maps[VibrationMode]
    m.check_coverage(m.position.copy())
    with pytest.raises(CoverageError, match="sample 2"):
        m.check_coverage(np.array([m.position[0], m.position[1], m.position[-1] + 1e-3]), "probe")


def test_fit_with_no_runs_raises():
    with pytest.raises(CoverageError, match="no idle runs"):
        VibrationMode(AXIS).fit([])
    with pytest.raises(ValueError):
        build_friction_map(RigidBody(AXIS), [])


def test_tare_outside_trace_raises(cut):
    est = VibrationMode(AXIS)
    with pytest.raises(CoverageError, match="outside the trace"):
        est.tare(cut, 20.0, 21.0)
    with pytest.raises(CoverageError, match="outside the trace"):
        est.tare(cut, -2.0, -1.0)


def test_tare_inside_start_up_raises(cut):
    with pytest.raises(CoverageError, match="start-up"):
        VibrationMode(AXIS).tare(cut, 0.0, 0.5)


def test_tare_removes_standing_offset(cut):
    est = VibrationMode(AXIS)
    start, end = cut.meta["tare_window"]
    raw = est.estimate(cut)["force_x"]
    value = est.tare(cut, start, end)
    t = cut.time
    sel = (t >= start) & (t < end)
    assert value == pytest.approx(raw[sel].mean(), rel=1e-12)
    after = est.estimate(cut)["force_x"]
    np.testing.assert_allclose(after, raw - value, rtol=0, atol=1e-9)
    assert "tare" in repr(est)


def test_fit_and_tare_replace_each_other(idle, cut):
    est = VibrationMode(AXIS)
    est.tare(cut, *cut.meta["tare_window"])
    est.fit(idle)
    assert est.friction_map is not None and "friction map" in repr(est)
    est.tare(cut, *cut.meta["tare_window"])
    assert est.friction_map is None and est.friction.values.size == 1


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.__name__)
def test_own_map_leaves_no_force_on_its_own_idle_runs(idle, cls):
    """The map is read through the method's own kernel: applied by that method, it cancels the idle runs
    it was built from, to the run-to-run spread (and to far less with one run)."""
    est = cls(AXIS).fit(idle)
    one = cls(AXIS).fit(idle[:1])
    for k, run in enumerate(idle):
        cruise = run.time > run.t0 + 0.6
        raw = cls(AXIS).estimate(run)["force_x"][cruise]
        left = est.estimate(run)["force_x"][cruise]
        rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
        assert rms(left) < 0.1 * rms(raw), (cls.__name__, k, rms(left), rms(raw))
        assert rms(left) < 2.0 * est.friction_map.repeatability_rms + 0.5, (cls.__name__, k)
    own = idle[0].time > idle[0].t0 + 0.6
    left_one = one.estimate(idle[0])["force_x"][own]
    raw_one = cls(AXIS).estimate(idle[0])["force_x"][own]
    assert np.sqrt(np.mean(left_one ** 2)) < 0.03 * np.sqrt(np.mean(raw_one ** 2)), cls.__name__
