"""The 3-axis linear-motor simulator: processes, NC trace, air moves."""

from __future__ import annotations

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.sim.linear_machine import LinearServoConfig
from drivesense.sim.machining import process_names, simulate_air_moves, simulate_process, table1_process_grid

NC = [f"{a}_{c}" for c in ("position", "velocity", "acceleration", "current") for a in "xyz"]


@pytest.fixture(scope="module")
def traces():
    return {p: simulate_process(p, 2e-3, 5e-3, 600 / 60e3, 4500, seed=3) for p in process_names()}


def test_every_process_gives_the_nc_trace_with_the_true_force(traces):
    assert len(traces) == 19
    for name, rec in traces.items():
        assert rec.fs == 250.0
        assert set(NC + ["spindle_speed", "spindle_current", "force_x", "force_y", "force_z"]) <= set(rec.channels)
        assert rec.units("x_acceleration") == "m/s^2" and rec.units("spindle_speed") == "rad/s"
        start, end = rec.meta["score_window"]
        assert rec.t0 < start < end <= rec.t0 + rec.duration
        assert "120 Hz" in rec.meta["reference_filter"] and rec.meta["nc_delay_s"] == pytest.approx(0.02)
        fx, fy = rec["force_x"], rec["force_y"]
        assert np.max(np.hypot(fx, fy)) > 30, name                   # it cuts
        assert abs(fx[0]) < 1e-6 and abs(fy[-1]) < 1e-6, name        # in air at start and end
        assert rec["spindle_speed"].mean() == pytest.approx(4500 * 2 * np.pi / 60, rel=1e-2)


def test_paths_move_the_right_axes_with_reversals_and_accelerations(traces):
    moves = {name: rec.meta["moving_axes"] for name, rec in traces.items()}
    assert moves["groove_+x"] == ["x"] and moves["side_-y"] == ["y"] and moves["groove_+x-y"] == ["x", "y"]
    assert moves["ramp_-y+z"] == ["y", "z"] and moves["pocket_ccw"] == moves["pocket_cw"] == ["x", "y", "z"]
    ramp = traces["ramp_-y+z"]
    assert ramp["y_position"][-1] < ramp["y_position"][0] and ramp["z_position"][-1] > ramp["z_position"][0]
    pocket = traces["pocket_ccw"]
    start, end = pocket.meta["score_window"]
    sel = (pocket.time > start) & (pocket.time < end)
    for ax in "xy":                                 # a full ccw lap reverses X and Y
        v = pocket[f"{ax}_velocity"][sel]
        assert v.max() > 5e-3 and v.min() < -5e-3
    groove = traces["groove_+x"]
    assert groove["x_acceleration"].max() > 0.05 and groove["x_acceleration"].min() < -0.05
    start, end = groove.meta["score_window"]
    cruise = groove["x_velocity"][(groove.time > start) & (groove.time < end)]
    assert np.median(cruise) == pytest.approx(0.01, rel=0.01)


def test_force_is_on_the_workpiece_in_machine_axes(traces):
    """Up-milling feed force resists the tool's motion: the workpiece is pushed along the feed."""
    for name, ax, sign in (("side_+x", "force_x", 1), ("side_-x", "force_x", -1), ("side_+y", "force_y", 1)):
        rec = traces[name]
        assert sign * np.mean(rec[ax][np.abs(rec[ax]) > 5]) > 0, name


def test_ideal_and_full_differ_and_runs_vary():
    ideal = simulate_process("groove_+y", 2e-3, 10e-3, 0.01, 5400, seed=1, ideal=True)
    full = simulate_process("groove_+y", 2e-3, 10e-3, 0.01, 5400, seed=1)
    again = simulate_process("groove_+y", 2e-3, 10e-3, 0.01, 5400, seed=1)
    other = simulate_process("groove_+y", 2e-3, 10e-3, 0.01, 5400, seed=2)
    assert ideal.meta["nc_delay_s"] == 0 and ideal.meta["physics"].startswith("ideal")
    assert full.equals(again) and not np.array_equal(full["y_current"], other["y_current"])
    # the ideal trace holds the unfiltered true force; the full one the 120 Hz low-passed force
    spec = lambda x: np.abs(np.fft.rfft(x - x.mean()))
    f = np.fft.rfftfreq(full.n_samples, 1 / 250)
    assert spec(full["force_y"])[f > 110].max() < 0.05 * spec(ideal["force_y"])[f > 110].max()


@pytest.mark.parametrize("args, text", [
    (("slot_+x", 2e-3, 5e-3, 0.01, 4500), "unknown process 'slot_+x'"),
    (("groove_+x", 0.0, 5e-3, 0.01, 4500), "'a_p'"),
    (("side_+x", 2e-3, 0.02, 0.01, 4500), "'a_e'"),
    (("side_+x", 2e-3, 5e-3, -0.01, 4500), "'v_f'"),
    (("side_+x", 2e-3, 5e-3, 0.01, float("nan")), "'n'"),
])
def test_bad_process_parameters(args, text):
    with pytest.raises(ConfigError, match=text.replace("+", r"\+")):
        simulate_process(*args)


def test_air_moves_and_config():
    moves = simulate_air_moves(axes=("z",), speeds=(1e-3, 5e-3), travel_speeds=(0.05,), accel_ramps=(0.1,))
    assert [m.name for m in moves] == ["air_z_travel", "air_z_speeds", "air_z_accel"]
    for m in moves:
        assert m.meta["kind"] == "air_move" and m.meta["moving_axes"] == ["z"]
        assert np.ptp(m["x_position"]) < 1e-4 and np.ptp(m["z_position"]) > 0.01
        assert np.max(np.abs(m["force_z"])) == 0.0
    assert np.max(np.abs(moves[2]["z_acceleration"])) > 2.0
    grid = table1_process_grid()
    assert len(grid["a_e"]) == 6 and grid["v_f"][0] == pytest.approx(0.005)
    with pytest.raises(ConfigError, match="whole number"):
        LinearServoConfig(fs=4000.0, nc_rate=300.0)
    with pytest.raises(ConfigError, match="unknown axis 'w'"):
        simulate_air_moves(axes=("w",))


@pytest.mark.parametrize("radius", [0.010, 0.022])
def test_pockets_turn_both_ways_at_their_radius_climb_and_up_milling(traces, radius):
    """The lap has the pocket's radius and its sense; the material is outside the lap: pushed outward, and
    along the feed by up milling (clockwise), against it by climb milling (counter-clockwise)."""
    from drivesense.sim.machining import ProcessSettings

    for name, turn in (("pocket_ccw", 1), ("pocket_cw", -1)):
        rec = simulate_process(name, 2e-3, 2e-3, 500 / 60e3, 3500, seed=3, settings=ProcessSettings(pocket_radius=radius))
        start, end = rec.meta["score_window"]
        sel = (rec.time > start + 1.0) & (rec.time < end - 0.5)
        x, y = rec["x_position"][sel], rec["y_position"][sel]
        cx, cy = 0.5 * (x.max() + x.min()), 0.5 * (y.max() + y.min())
        assert np.median(np.hypot(x - cx, y - cy)) == pytest.approx(radius, rel=0.01)
        th = np.unwrap(np.arctan2(y - cy, x - cx))
        assert turn * (th[-1] - th[0]) > 5.0                               # most of a lap, in its sense
        fx, fy = rec["force_x"][sel], rec["force_y"][sel]
        radial = np.mean(fx * np.cos(th) + fy * np.sin(th))
        along_feed = np.mean(turn * (-fx * np.sin(th) + fy * np.cos(th)))
        assert radial > 5.0, name
        assert (along_feed > 20.0) if turn < 0 else (along_feed < -5.0), name
        assert rec.meta["pocket_radius_m"] == radius and rec.meta["name"].endswith(f"_r{radius * 1e3:g}")
