"""Four-step identification of the linear-motor axes (third paper, Sec. 2.2).

Each step is checked on synthetic data built directly from the model
equations (known answers, no simulator); the whole method on air moves from
the full-physics simulator against the issue's targets; then the CLI.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.bench.linear_axis import identification_table, score_process, session_truth
from drivesense.cli import app
from drivesense.errors import ConfigError, CoverageError, MissingChannelError
from drivesense.estimate.model_based import ModelBased
from drivesense.identify.linear_axis import (IdentificationWarning, constant_velocity_segments, direction_averaged,
                                             fit_cogging_table, fit_masses, fit_restoring, fit_stribeck,
                                             run_identification)
from drivesense.io.axes_file import read_axes_file, write_axes_file
from drivesense.machine.linear_motor import AXES, linear_machine_model
from drivesense.recording import Recording
from drivesense.io import write_recording
from drivesense.sim.machining import simulate_process

FS = 250.0
TRUE = linear_machine_model()
TRAVEL = {"x": (0.0, 0.32), "y": (0.0, 0.35), "z": (0.0, 0.30)}


# ------------------------------------------------------------------ synthetic air moves (Eq. 1 exactly)
def _velocity_profile(moves, fs=FS):
    """Velocity and acceleration of rest-to-rest moves ``(speed, cruise_time, ramp)`` with 0.2 s dwells."""
    v, a = [np.zeros(int(0.2 * fs))], [np.zeros(int(0.2 * fs))]
    for speed, cruise, ramp in moves:
        tr = np.arange(int(round(ramp * fs))) / fs
        up = speed * (0.5 - 0.5 * np.cos(np.pi * tr / ramp))
        dup = speed * np.pi / (2 * ramp) * np.sin(np.pi * tr / ramp)
        v += [up, np.full(int(round(cruise * fs)), speed), up[::-1], np.zeros(int(0.2 * fs))]
        a += [dup, np.zeros(int(round(cruise * fs))), -dup[::-1], np.zeros(int(0.2 * fs))]
    return np.concatenate(v), np.concatenate(a)


def synthetic_air_moves(model=TRUE, *, directions=(1, -1), accelerate=True, speeds_only=False):
    """One trace per axis; currents from Eq. 1 with F_ext = 0 (sgn(0) = 0 friction at rest)."""
    recs = []
    for ax in AXES:
        lo, hi = TRAVEL[ax][0] + 0.01, TRAVEL[ax][1] - 0.01
        moves = []
        if not speeds_only:
            for sp in (0.02, 0.05):
                moves += [(d * sp, (hi - lo) / sp - 0.1, 0.1) for d in directions]
        for sp in (0.5e-3, 1e-3, 2e-3, 3e-3, 5e-3, 8e-3, 0.012) + (() if speeds_only else (0.03,)):
            moves += [(d * sp, 2.0, 0.1) for d in directions]
        if accelerate:
            moves += [(d * 0.2, 0.5, 0.1) for d in directions]
        v, a = _velocity_profile(moves)
        s = lo + np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / FS)))
        chans = {}
        for other in AXES:
            axis = model.axis(other)
            pos = s if other == ax else np.full(s.size, 0.5 * sum(TRAVEL[other]))
            vel = v if other == ax else np.zeros(s.size)
            acc = a if other == ax else np.zeros(s.size)
            force = (axis.cogging_force(pos) + axis.restoring_force(pos) + axis.friction_force(vel)
                     + model.stacked_masses()[other] * acc)
            chans.update({f"{other}_position": pos, f"{other}_velocity": vel, f"{other}_acceleration": acc,
                          f"{other}_current": force / axis.K_m})
        recs.append(Recording.from_arrays(chans, fs=FS, meta={
            "name": f"synthetic_{ax}", "motor_constants_n_per_a": {k: model.axis(k).K_m for k in AXES}}))
    return recs


# ------------------------------------------------------------------ step by step, known answers
def test_segments_are_the_constant_velocity_stretches():
    v, _ = _velocity_profile([(0.01, 2.0, 0.1), (-0.002, 1.0, 0.1), (0.0001, 1.0, 0.1)])
    segs = constant_velocity_segments(v, FS)
    assert len(segs) == 2                                         # 0.1 mm/s is below min_speed
    assert np.allclose(v[segs[0]], 0.01) and np.allclose(v[segs[1]], -0.002)
    assert (segs[0].stop - segs[0].start) / FS == pytest.approx(2.0 - 0.3, abs=0.05)


def test_step1_direction_average_cancels_friction_and_gives_k_and_rest_point():
    ax = TRUE.x
    s_up = np.linspace(0.02, 0.30, 1500)
    s_dn = np.linspace(0.30, 0.02, 1400)
    f_up = ax.restoring_force(s_up) + ax.friction_force(np.full(s_up.size, 0.02))
    f_dn = ax.restoring_force(s_dn) + ax.friction_force(np.full(s_dn.size, -0.02))
    s, f = direction_averaged(s_up, f_up, s_dn, f_dn)
    np.testing.assert_allclose(f, ax.restoring_force(s), atol=1e-9)
    res = fit_restoring(s, f)
    assert res["k"] == pytest.approx(ax.k, rel=1e-9) and res["s_r"] == pytest.approx(ax.s_r, rel=1e-9)
    assert res["r2"] == pytest.approx(1.0)
    with pytest.raises(CoverageError, match="both directions"):
        fit_restoring(np.full(10, 0.1), np.ones(10))


def test_step2_cogging_table_from_the_binned_residual():
    ax = TRUE.y
    s = np.linspace(0.05, 0.05 + 5 * ax.pole_pitch, 20000)
    table = fit_cogging_table(s, ax.cogging_force(s) + 3.0, ax.pole_pitch, ax.cogging.size)
    np.testing.assert_allclose(table, ax.cogging - ax.cogging.mean(), atol=0.02 * np.abs(ax.cogging).max())
    np.testing.assert_allclose(ax.with_values(cogging=table).cogging_amplitudes(3), ax.cogging_amplitudes(3),
                               rtol=0.005, atol=0.05)
    with pytest.raises(CoverageError, match="pole pitch"):
        fit_cogging_table(np.linspace(0, 0.3 * ax.pole_pitch, 500), np.zeros(500), ax.pole_pitch)


def test_step3_stribeck_by_trust_region_reflective():
    ax = TRUE.z
    speeds = np.array([0.5e-3, 1e-3, 2e-3, 3e-3, 5e-3, 8e-3, 0.012, 0.03, 0.08, 0.15])
    v = np.concatenate([speeds, -speeds])
    fr = fit_stribeck(v, ax.friction_force(v))
    for name in ("F_C", "F_br", "v_s", "sigma"):
        assert fr[name] == pytest.approx(getattr(ax, name), rel=1e-5), name
    with pytest.raises(CoverageError, match="3 distinct speed"):
        fit_stribeck(v[:3], ax.friction_force(v[:3]))
    fast = np.array([0.05, 0.08, 0.1, 0.15, 0.2])           # all far above v_s: the hump is invisible
    with pytest.raises(CoverageError, match="do not determine"):
        fit_stribeck(fast, ax.friction_force(fast) + 0.01 * np.sin(np.arange(5)))
    fb = fit_stribeck(fast, ax.friction_force(fast) + 0.01 * np.sin(np.arange(5)), strict=False)
    assert fb["undetermined"] == ["F_br", "v_s"] and fb["F_br"] == fb["F_C"] and fb["v_s"] == pytest.approx(0.025)
    assert fb["F_C"] == pytest.approx(ax.F_C, rel=1e-3) and fb["sigma"] == pytest.approx(ax.sigma, rel=1e-3)


def test_step4_stacked_masses_solved_jointly():
    rng = np.random.default_rng(0)
    acc = {a: rng.uniform(-3, 3, 200) for a in AXES}
    stacked = TRUE.stacked_masses()
    frc = {a: stacked[a] * acc[a] for a in AXES}
    ms = fit_masses(acc, frc)
    for a in AXES:
        assert ms["m"][a] == pytest.approx(TRUE.axis(a).m, rel=1e-9)
        assert ms["stacked"][a] == pytest.approx(stacked[a], rel=1e-9)
    with pytest.raises(CoverageError, match="axis 'y'"):
        fit_masses({**acc, "y": np.zeros(200)}, frc)


def test_all_four_steps_on_synthetic_traces_recover_the_model():
    rep = run_identification(synthetic_air_moves())
    for ax in AXES:
        got, want = rep.model.axis(ax), TRUE.axis(ax)
        for name, tol in (("k", 0.003), ("s_r", 0.003), ("m", 0.003), ("F_C", 0.003), ("F_br", 0.003),
                          ("v_s", 0.01), ("sigma", 0.003)):
            assert getattr(got, name) == pytest.approx(getattr(want, name), rel=tol), (ax, name)
        assert got.cogging_amplitudes(1)[0] == pytest.approx(want.cogging_amplitudes(1)[0], rel=0.01)
        assert rep.steps[ax]["restoring"]["r2"] > 0.5 and rep.steps[ax]["mass"]["r2"] > 0.999
        assert rep.seconds[ax] < 10.0
    json.dumps(rep.to_dict())


@pytest.mark.parametrize("kwargs, error, text", [
    (dict(directions=(1,)), CoverageError, "both directions"),
    (dict(accelerate=False, speeds_only=True), CoverageError, "no accelerated moves of axis 'x'"),
])
def test_what_the_data_cannot_determine_is_named(kwargs, error, text):
    with pytest.raises(error, match=text):
        run_identification(synthetic_air_moves(**kwargs))


def test_given_motor_constants_that_disagree_with_the_traces_warn():
    recs = synthetic_air_moves()          # they carry K_m x 180, y 260, z 140 N/A
    with pytest.warns(IdentificationWarning) as caught:
        rep = run_identification(recs, motor_constants={"x": 130.0, "y": 260.0, "z": 140.0}, presliding=False)
    assert [str(w.message) for w in caught] == [
        "axis 'x': the given motor constant --km x=130 N/A disagrees with the 180 N/A the trace 'synthetic_x' "
        "carries in its metadata (and 2 more trace(s)); using the given 130 N/A (leave --km out to use the "
        "traces' constants)"]
    assert rep.model.x.K_m == 130.0 and rep.model.y.K_m == 260.0


def test_bad_inputs():
    recs = synthetic_air_moves()
    with pytest.raises(ConfigError, match=r"motor constants unknown: .*give --km x=\.\.\.,y=\.\.\.,z=\.\.\. \[N/A\]"):
        run_identification([r.with_meta(motor_constants_n_per_a=None) for r in recs])
    with pytest.raises(ConfigError, match=r"\(--km\): missing axis/axes z"):
        run_identification(recs, motor_constants={"x": 1.0, "y": 1.0})
    with pytest.raises(MissingChannelError, match="z_acceleration"):
        run_identification([r.select(*[c for c in r.channels if c != "z_acceleration"]) for r in recs])
    with pytest.raises(ConfigError, match="non-empty list"):
        run_identification([])


# ------------------------------------------------------------------ the full physics
@pytest.fixture(scope="module")
def air(linear_air_moves):
    """``simulate_air_moves(seed=7)``, shared for the session (conftest)."""
    return linear_air_moves


def test_identification_on_simulated_air_moves_meets_the_targets(air):
    rep = run_identification(air)
    table = identification_table(rep.model, session_truth(air, TRUE))    # the session's true values
    bad = {(ax, p): round(v["rel_error"], 4) for ax, t in table.items() for p, v in t.items() if not v["ok"]}
    assert not bad, f"outside the targets: {bad}"
    assert max(rep.seconds.values()) < 10.0
    nominal = identification_table(rep.model, TRUE)                     # the preset (2 % run variation apart)
    assert all(v["rel_error"] < 0.06 for t in nominal.values() for v in t.values())
    for ax in "xyz":       # step 5: a presliding distance of the simulator's order (LuGre F_C/sigma0 = 15 um)
        assert rep.steps[ax]["presliding"]["determined"] and 3e-6 < rep.model.axis(ax).x_pre < 30e-6
    assert run_identification(air, presliding=False).model.x.x_pre == 0.0
    est = ModelBased(TRUE).fit(air)                      # the estimator's fit() is the same method
    assert est.model.x.k == pytest.approx(rep.model.x.k) and est.report is not None


@pytest.fixture(scope="module")
def ordinary_air():
    """Air moves of the full-physics machine at ordinary speeds only (5-200 mm/s): no Stribeck hump in sight."""
    from drivesense.sim.machining import simulate_air_moves

    return simulate_air_moves(seed=7, speeds=(5e-3, 8e-3, 0.012, 0.03, 0.08, 0.15, 0.2))


def test_air_moves_at_ordinary_speeds_give_a_coulomb_viscous_model(ordinary_air, tmp_path):
    with pytest.raises(CoverageError, match=r"axis 'x': Stribeck friction: the speeds 5, 8, 12, .* do not "
                                            r"determine F_br, v_s"):
        run_identification(ordinary_air, strict=True)
    with pytest.warns(IdentificationWarning) as caught:
        rep = run_identification(ordinary_air)
    fallback = [ax for ax in AXES if rep.model.axis(ax).undetermined]
    assert "x" in fallback and len(caught) == len(fallback)
    assert str(caught[0].message).startswith("axis 'x': the air moves' speeds (5 mm/s and faster) do not determine "
                                             "the Stribeck curve's F_br and v_s; using Coulomb + viscous friction")
    assert "--strict" in str(caught[0].message)
    truth = session_truth(ordinary_air, TRUE)
    table = identification_table(rep.model, truth)
    for ax in AXES:
        got = rep.model.axis(ax)
        for name in ("k", "s_r", "m", "F_C", "sigma"):
            assert table[ax][name]["rel_error"] < 0.01, (ax, name, table[ax][name])
        if ax in fallback:
            assert got.undetermined == ("F_br", "v_s") and got.F_br == got.F_C and got.v_s == pytest.approx(2.5e-3)
            assert rep.steps[ax]["friction"]["undetermined"] == ["F_br", "v_s"]
    json.dumps(rep.to_dict(), allow_nan=False)
    held_out = simulate_process("side_-y", 2e-3, 10e-3, 0.01, 5400, seed=11)      # a cut it never saw
    est = ModelBased(rep.model).estimate(held_out)
    assert all(score_process(est, held_out, ax)["nrmse"] < 0.04 for ax in AXES)
    path = write_axes_file(tmp_path / "AXES.toml", rep.model)
    assert 'undetermined = ["F_br", "v_s"]' in path.read_text()
    back = read_axes_file(path)
    assert [back.axis(ax).undetermined for ax in AXES] == [rep.model.axis(ax).undetermined for ax in AXES]
    assert back.x.F_br == rep.model.x.F_br
    path.write_text(path.read_text().replace('undetermined = ["F_br", "v_s"]', 'undetermined = ["F_xx"]', 1))
    with pytest.raises(ConfigError, match=r"\[x\]: linear axis parameter 'undetermined' must list parameter names"):
        read_axes_file(path)


def test_cli_identify_linear_falls_back_and_strict_refuses(ordinary_air, tmp_path):
    runner = CliRunner()
    paths = []
    for rec in ordinary_air:
        paths.append(tmp_path / f"{rec.name}.nc")
        write_recording(rec, paths[-1])
    res = runner.invoke(app, ["identify", "linear", *map(str, paths), "--out", str(tmp_path / "AXES.toml"),
                              "--no-presliding"])
    assert res.exit_code == 0, res.output
    assert "warning: axis 'x': the air moves' speeds" in res.output and "* undetermined by the air moves" in res.output
    assert read_axes_file(tmp_path / "AXES.toml").x.undetermined == ("F_br", "v_s")
    res = runner.invoke(app, ["identify", "linear", *map(str, paths), "--out", str(tmp_path / "S.toml"), "--strict"])
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "do not determine F_br, v_s" in res.output
    assert not (tmp_path / "S.toml").exists()


def test_cli_identify_linear(air, tmp_path):
    runner = CliRunner()
    paths = []
    for rec in air:
        paths.append(tmp_path / f"{rec.name}.nc")
        write_recording(rec, paths[-1])
    res = runner.invoke(app, ["identify", "linear", *map(str, paths), "--out", str(tmp_path / "AXES.toml"),
                              "--json", str(tmp_path / "id.json"), "--plot", str(tmp_path / "id.png")])
    assert res.exit_code == 0, res.output
    model = read_axes_file(tmp_path / "AXES.toml")
    assert model.y.k == pytest.approx(TRUE.y.k, rel=0.05)
    info = json.loads((tmp_path / "id.json").read_text())
    assert set(info["steps"]["x"]) == {"restoring", "cogging", "friction", "mass", "presliding"}
    assert (tmp_path / "id.png").stat().st_size > 10_000
    # one trace of one axis cannot determine the machine: one line, exit 2
    res = runner.invoke(app, ["identify", "linear", str(paths[0]), "--out", str(tmp_path / "A2.toml")])
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "error:" in res.output
    res = runner.invoke(app, ["identify", "linear", *map(str, paths), "--out", str(tmp_path / "A3.toml"),
                              "--km", "x=180,y=260"])
    assert res.exit_code == 2 and "--km lacks axis/axes z" in res.output
    res = runner.invoke(app, ["identify", "linear", *map(str, paths), "--out", str(tmp_path / "A4.toml"),
                              "--km", "x=180,y=150,z=140", "--no-presliding"])   # the README's old y=150
    assert res.exit_code == 0, res.output
    assert res.output.count("warning:") == 1 and "axis 'y': the given motor constant --km y=150 N/A disagrees " \
        "with the 260 N/A the trace 'air_x_travel'" in res.output.replace("\n", " ")
    assert read_axes_file(tmp_path / "A4.toml").y.K_m == 150.0
    assert not (tmp_path / "A2.toml").exists() and not (tmp_path / "A3.toml").exists()
    assert math.isfinite(model.z.m)
