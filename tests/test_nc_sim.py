"""The ball-screw machining centre: part programs traced by the controller at 50 and 500 Hz."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.machine.vmc import ball_screw_force_constant, screw_reflected_mass, vmc_physics
from drivesense.sim import nc_programs, simulate_nc_program
from drivesense.sim.catalog import describe_scenarios, simulate_scenario
from drivesense.sim.vmc import block_means

AXES = "xyz"
DRIVE = [f"{a}_{c}" for c in ("position", "velocity", "acceleration", "current") for a in AXES] + \
    ["spindle_speed", "spindle_current"]
FORCES = ["force_x", "force_y", "force_z"]
SESSION = dict(seed=1, machine_seed=3)


@pytest.fixture(scope="module")
def cuts():
    return {p: simulate_nc_program(p, **SESSION) for p in nc_programs()}


@pytest.fixture(scope="module")
def ideal():
    return simulate_nc_program("slots", rate=500.0, ideal=True)


def test_presets_follow_the_ball_screw_formulas():
    assert ball_screw_force_constant(1.2, 0.016) == pytest.approx(1.2 * 2 * np.pi / 0.016)
    assert screw_reflected_mass(0.002, 0.012) == pytest.approx(0.002 * (2 * np.pi / 0.012) ** 2)
    phys = vmc_physics()
    masses = phys.moved_masses()
    for ax in AXES:
        a = phys.axis(ax)
        assert a.model.k == 0.0 and a.model.pole_pitch in (0.012, 0.016) and 100 <= a.model.F_C <= 400
        assert masses[ax] == pytest.approx(a.model.m + a.reflected_mass + (phys.x.model.m if ax == "y" else 0.0))
    assert phys.carries == {"x": (), "y": ("x",), "z": ()}
    assert phys.x.weight == phys.y.weight == 0.0 and 1.0 < -phys.z.weight / phys.z.model.K_m < 8.0


def test_programs_are_production_like(cuts):
    assert set(cuts) == {"face_zigzag", "pocket", "slots", "contour", "drilling"}
    for name, rec in cuts.items():
        assert rec.fs == 50.0 and 15.0 <= rec.duration <= 40.0, name
        assert set(DRIVE + FORCES) <= set(rec.channels), name
        speed = np.sqrt(sum(rec[f"{a}_velocity"] ** 2 for a in AXES))
        assert 0.15 <= speed.max() <= 0.4, name                          # G0 rapids
        assert np.mean(speed < 1e-4) > 0.03, name                          # standstills
        assert rec.meta["moving_axes"] == ["x", "y", "z"], name
        assert sum(np.any(rec[f"{a}_velocity"] > 0.01) and np.any(rec[f"{a}_velocity"] < -0.01)
                   for a in AXES) >= 2, name                               # reversals
        force = np.sqrt(sum(rec[f] ** 2 for f in FORCES))
        assert force.max() > 150 and abs(force[0]) < 10 and abs(force[-1]) < 10, name   # cuts, in air at the ends
        assert rec["spindle_speed"].mean() == pytest.approx(4500 * 2 * np.pi / 60, rel=2e-3)
        assert rec.units("x_acceleration") == "m/s^2" and rec.units("spindle_speed") == "rad/s"
        assert rec.units("force_z") == "N" and rec.units("z_current") == "A"
        assert "nc_delay_s" not in rec.meta and rec.meta["trace_delay_s"] == pytest.approx(79 / 8000)
    drill = cuts["drilling"]
    assert drill["force_z"].min() < -500 and np.abs(drill["force_x"]).max() < 20     # thrust only
    both = (np.abs(cuts["slots"]["x_velocity"]) > 5e-3) & (np.abs(cuts["slots"]["y_velocity"]) > 5e-3)
    assert both.sum() > 20                                                 # the diagonal slot


def test_standstill_current_holds_the_weight(cuts, ideal):
    phys = vmc_physics()
    first = ideal.time < 0.9                                               # 1 s at rest before the first move
    for ax in AXES:
        md = phys.axis(ax).model
        sign = ideal.meta["current_signs"][ax]
        expected = sign * (md.cogging_force(ideal[f"{ax}_position"][first]) - phys.axis(ax).weight) / md.K_m
        np.testing.assert_allclose(ideal[f"{ax}_current"][first], expected, rtol=0, atol=1e-9)
    truth = ideal.meta["true_model"]["z"]
    assert truth["holding_current"] == pytest.approx(-truth["weight"] / truth["K_m"]) and truth["holding_current"] > 1
    for rec in cuts.values():                                              # full physics, noise and ripple
        tz = rec.meta["true_model"]["z"]
        z_rest = rec["z_current"][rec.time < 0.9]
        assert np.abs(z_rest - tz["holding_current"]).max() < 0.1
        assert np.abs(rec["x_current"][rec.time < 0.9]).max() < 0.15


def test_ideal_trace_obeys_the_force_balance_as_logged(ideal):
    """K_m I = M a + F_C sgn(v) + sigma v + ripple(s) - weight + F, block means, with K_m and I as logged."""
    phys = vmc_physics()
    truth = ideal.meta["true_model"]
    assert ideal.meta["trace_delay_s"] == 0.0 and truth["x"]["K_m"] < 0 and truth["y"]["K_m"] < 0 < truth["z"]["K_m"]
    for ax in AXES:
        t, md = truth[ax], phys.axis(ax).model
        v, a, s = ideal[f"{ax}_velocity"], ideal[f"{ax}_acceleration"], ideal[f"{ax}_position"]
        sel = np.abs(v) > 0.015                          # sliding: friction linear within each 2 ms block
        assert sel.sum() > 200 and np.abs(a[sel]).max() > 1.0
        rest = (np.sign(v) * t["F_C"] + t["sigma"] * v + md.cogging_force(s) - t["weight"] + ideal[f"force_{ax}"])[sel]
        motor = (t["K_m"] * ideal[f"{ax}_current"])[sel]
        np.testing.assert_allclose(motor, t["mass"] * a[sel] + rest, rtol=0, atol=0.5)
        fitted = np.sum(a[sel] * (motor - rest)) / np.sum(a[sel] ** 2)
        assert fitted == pytest.approx(t["mass"], rel=1e-3)
    # Y carries X: its motor moves the table too; X and Z carry nothing
    assert truth["y"]["mass"] == pytest.approx(truth["y"]["own_mass"] + truth["y"]["reflected_mass"]
                                               + truth["x"]["own_mass"])
    assert truth["x"]["mass"] == pytest.approx(truth["x"]["own_mass"] + truth["x"]["reflected_mass"])
    assert truth["carries"] == {"x": [], "y": ["x"], "z": []}


def test_logged_currents_of_x_and_y_oppose_the_accelerating_force(cuts):
    rec = cuts["slots"]
    for ax, sign in (("x", -1), ("y", -1), ("z", 1)):
        a = rec[f"{ax}_acceleration"]
        strong = np.abs(a) > 1.0
        i = rec[f"{ax}_current"] - rec.meta["true_model"][ax]["holding_current"]
        assert strong.sum() >= 5 and np.mean(np.sign(i[strong]) == sign * np.sign(a[strong])) > 0.95, ax


def test_50_hz_is_the_500_hz_trace_averaged_and_decimated(cuts):
    fast = simulate_nc_program("slots", rate=500.0, **SESSION)
    slow = cuts["slots"]
    assert fast.fs == 500.0 and fast.t0 == pytest.approx(7 / 4000) and slow.t0 == pytest.approx(79 / 4000)
    assert fast.meta["trace_delay_s"] == pytest.approx(7 / 8000) and slow.meta["averaging_window_s"] == 0.02
    for ch in DRIVE:
        np.testing.assert_allclose(slow[ch], block_means(fast[ch], 10), rtol=1e-12, atol=1e-12, err_msg=ch)
    for f in FORCES:    # each reference: filtered below its own Nyquist, sampled at its instants (the 10th)
        diff = slow[f] - fast[f][9::10][:slow.n_samples]          # the 500 Hz one keeps the runout (75 Hz)
        assert abs(diff.mean()) < 2.0 and np.median(np.abs(diff)) < 15.0, f
    with pytest.raises(ConfigError, match="whole number"):
        simulate_nc_program("slots", rate=300.0)


def test_air_cut_is_the_same_program_without_force(cuts):
    air = simulate_nc_program("slots", air=True, **SESSION)
    cut = cuts["slots"]
    assert not set(FORCES) & set(air.channels) and air.meta["kind"] == "air" and air.n_samples == cut.n_samples
    for ax in AXES:
        assert np.abs(air[f"{ax}_position"] - cut[f"{ax}_position"]).max() < 5e-5
    assert air.meta["true_model"] == cut.meta["true_model"]
    assert np.abs(air["spindle_current"] - 6.0).max() < 0.1 < np.abs(cut["spindle_current"] - 6.0).max()


def test_seeds_draw_the_run_and_the_machine(cuts):
    again = simulate_nc_program("drilling", **SESSION)
    for ch in cuts["drilling"].channels:
        np.testing.assert_array_equal(again[ch], cuts["drilling"][ch])
    other_run = simulate_nc_program("drilling", seed=2, machine_seed=3)
    other_machine = simulate_nc_program("drilling", seed=1, machine_seed=4)
    t1, t2, t3 = (r.meta["true_model"] for r in (cuts["drilling"], other_run, other_machine))
    assert t2["z"]["weight"] == t1["z"]["weight"] != t3["z"]["weight"]           # same machine, other run
    assert t2["z"]["F_C"] != t1["z"]["F_C"] and abs(t2["z"]["F_C"] / t1["z"]["F_C"] - 1) < 0.1
    assert not np.array_equal(other_run["z_current"], cuts["drilling"]["z_current"])


def test_cutting_parameters_and_speed():
    start = time.perf_counter()
    rec = simulate_nc_program("contour", a_p=1e-3, a_e=3e-3, v_f=1.5 / 60, n=6000, seed=5)
    elapsed = time.perf_counter() - start
    assert elapsed < 8.0                                 # ~1 s on a quiet core (36 s of machining at 4 kHz)
    assert rec.meta["n_rpm"] == 6000 and rec.meta["v_f_m_s"] == pytest.approx(0.025)
    assert rec["spindle_speed"].mean() == pytest.approx(6000 * 2 * np.pi / 60, rel=2e-3)
    with pytest.raises(ConfigError, match="a_e"):
        simulate_nc_program("contour", a_e=0.02)
    with pytest.raises(ConfigError, match="unknown NC program"):
        simulate_nc_program("engrave")


def test_catalog_lists_the_programs_and_their_dry_runs():
    names = describe_scenarios()
    for p in nc_programs():
        assert f"vmc_{p}" in names and f"vmc_air_{p}" in names
    rec, = simulate_scenario("vmc_air_drilling", seed=2)
    assert rec.fs == 50.0 and "force_z" not in rec.channels and rec.meta["program"] == "drilling"
