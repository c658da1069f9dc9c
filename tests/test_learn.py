"""Learned reconstruction end to end on a tiny grid: training reduces the loss, save/load, streaming = batch,
the hybrid, the CLI, and the clear message when PyTorch is missing."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.errors import ConfigError
from drivesense.learn.dataset import RunSpec, allowed, build_dataset, load_dataset, plan_runs
from drivesense.sim.machining import simulate_process

torch = pytest.importorskip("torch")

from drivesense.cli import app  # noqa: E402
from drivesense.learn import Hybrid  # noqa: E402
from drivesense.learn import LSTM  # noqa: E402
from drivesense.learn.model import TrainConfig  # noqa: E402
from drivesense.io import write_recording

TINY = TrainConfig(epochs=3, windows_per_epoch=128, batch=32, window=150, burn_in=30, mc_samples=4, seed=1,
                  lr_decay=0.5, lr_patience=0)   # the schedule runs (decays after every epoch without improvement)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ds")
    runs = plan_runs(n_train=4, n_val=2, n_test=1, n_held_out_process=1, n_air=1, seed=7, extra_pockets=())
    index = build_dataset(folder, runs)
    return folder, index, [rec for _, rec in load_dataset(folder)]


def test_plan_respects_the_rule_and_the_split():
    runs = plan_runs()
    assert len([r for r in runs if r.split in ("train", "val", "test")]) >= 180
    assert all(allowed(r.process, r.a_p, r.a_e) for r in runs)
    train = {(r.a_p, r.a_e, r.v_f, r.n) for r in runs if r.split == "train"}
    test = {(r.a_p, r.a_e, r.v_f, r.n) for r in runs if r.split == "test"}
    assert not train & test
    held = {r.process for r in runs if r.split == "test_process"}
    assert len(held) == 1 and held.isdisjoint({r.process for r in runs if r.split != "test_process"})
    assert plan_runs() == runs  # seeded
    air = [r for r in runs if r.air]
    assert len(air) == 34 and {r.split for r in air} == {"train"}
    assert {r.process for r in air}.isdisjoint(held) and len({r.name for r in runs}) == len(runs)


def test_plan_holds_clockwise_and_other_radius_pockets_out_of_training():
    runs = plan_runs()
    pockets = [r for r in runs if r.process.startswith("pocket") and r.split == "test"]
    assert {(r.process, r.pocket_radius) for r in pockets} == {("pocket_ccw", None), ("pocket_cw", 0.015),
                                                              ("pocket_ccw", 0.010), ("pocket_cw", 0.022)}
    fitted = {(r.a_p, r.a_e, r.v_f, r.n) for r in runs if r.split in ("train", "val")}
    assert all((r.a_p, r.a_e, r.v_f, r.n) not in fitted for r in pockets)
    assert len({(r.a_p, r.a_e, r.v_f, r.n) for r in pockets}) == len(pockets)
    assert {r.split for r in runs if r.process == "pocket_cw"} == {"test"}     # never trained on
    assert runs[:len(plan_runs(extra_pockets=()))] == plan_runs(extra_pockets=())   # the rest is unchanged
    assert "pocket_ccw_ap3_ae1_vf400_n6000_r10_s2250" in {r.name for r in runs}


def test_air_cuts_have_zero_force_and_the_cut_toolpath():
    cut = simulate_process("pocket_ccw", 2e-3, 2e-3, 500 / 60e3, 3500, seed=3)
    air = simulate_process("pocket_ccw", 2e-3, 2e-3, 500 / 60e3, 3500, seed=3, air=True)
    for ax in "xyz":
        assert np.all(air[f"force_{ax}"] == 0.0)
        assert np.max(np.abs(air[f"{ax}_position"] - cut[f"{ax}_position"])) < 5e-5   # same path, no cutting load
    assert air.meta["kind"] == "air" and air.meta["name"].startswith("air_")
    assert np.ptp(air["x_current"]) < np.ptp(cut["x_current"])


def test_dataset_is_cached_and_states_its_size(tiny):
    folder, index, runs = tiny
    assert index["bytes_on_disk"] > 0 and len(runs) == 9
    mtimes = {p: p.stat().st_mtime_ns for p in (folder / "runs").iterdir()}
    build_dataset(folder, [RunSpec(**e["spec"]) for e in index["runs"]])
    assert {p: p.stat().st_mtime_ns for p in (folder / "runs").iterdir()} == mtimes


@pytest.fixture(scope="module")
def trained(tiny):
    _, _, runs = tiny
    return LSTM(config=TINY).fit(runs)


def test_training_reduces_the_loss(trained):
    hist = trained.model.history
    for ch, losses in hist["train_loss"].items():
        assert losses[-1] < losses[0], ch


def test_streaming_equals_batch_and_save_load(trained, tiny, tmp_path):
    _, _, runs = tiny
    rec = next(r for r in runs if r.meta["split"] == "test")
    batch = trained.estimate(rec)
    stream = trained.stream(rec.fs)
    parts = [stream.push({c: rec[c][i:i + 25] for c in rec.channels}) for i in range(0, rec.n_samples, 25)]
    for ch in ("force_x", "force_y", "force_z"):
        assert np.array_equal(np.concatenate([p[ch] for p in parts]), batch[ch])
    trained.save(tmp_path / "m")
    again = LSTM.load(tmp_path / "m")
    assert np.array_equal(again.estimate(rec)["force_x"], batch["force_x"])
    with pytest.raises(ConfigError, match="lstm"):
        Hybrid.load(tmp_path / "m")


def test_intervals_are_ordered(trained, tiny):
    rec = tiny[2][0]
    out = trained.estimate(rec, intervals=True)
    assert np.all(out["force_x_lower"] <= out["force_x"]) and np.all(out["force_x"] <= out["force_x_upper"])


def test_hybrid_needs_the_model_and_runs(tiny):
    from drivesense.machine.linear_motor import linear_machine_model

    _, _, runs = tiny
    with pytest.raises(ConfigError, match="model_based"):
        Hybrid(config=TINY).fit(runs)
    hyb = Hybrid(config=TINY).fit(runs, model_based=linear_machine_model())
    out = hyb.estimate(runs[0])
    assert np.all(np.isfinite(out["force_y"]))
    assert hyb.model.config.skip_taps == 8 and hyb.model.weights["force_y"].taps == 8   # the hybrid's default


def test_cli_train_and_estimate(tiny, tmp_path):
    folder, _, runs = tiny
    res = CliRunner().invoke(app, ["train", "lstm", "--data", str(folder), "--out", str(tmp_path / "m"),
                                   "--epochs", "1", "--json", str(tmp_path / "t.json")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "t.json").read_text())["kind"] == "lstm"
    write_recording(runs[0], tmp_path / "trace.nc")
    res = CliRunner().invoke(app, ["estimate", str(tmp_path / "trace.nc"), "--method", "lstm", "--model",
                                   str(tmp_path / "m"), "--out", str(tmp_path / "f.csv"), "--json", str(tmp_path / "e.json")])
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "e.json").read_text())
    assert info["method"] == "lstm" and set(info["force_n"]) == {"force_x", "force_y", "force_z"}
    res = CliRunner().invoke(app, ["estimate", str(tmp_path / "trace.nc"), "--method", "hybrid",
                                   "--out", str(tmp_path / "f.csv")])
    assert res.exit_code == 2 and "--model" in res.output


def test_missing_torch_gives_a_clear_message(monkeypatch, tiny):
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ConfigError, match="pip install torch"):
        LSTM(config=TINY).fit(tiny[2])


def test_presliding_features_turn_over_at_reversals_and_stream():
    """The Dahl state of each position saturates at the direction of motion and turns over within ~3 x_pre."""
    from drivesense.learn.features import presliding_features

    s = np.concatenate([np.linspace(0, 1e-3, 101), np.linspace(1e-3, 0.5e-3, 101)[1:]])   # 10 um up, 5 um back
    f = presliding_features([s, -s, np.zeros_like(s)], 10e-6)
    assert f.shape == (s.size, 3) and f.dtype == np.float32
    assert f[99, 0] > 0.999 and f[99, 1] < -0.999 and np.all(f[:, 2] == 0)      # standing axis: no friction held
    assert f[100 + 8, 0] == pytest.approx(-1 + 2 * np.exp(-4.0), abs=1e-6)     # 40 um after the reversal
    state: dict = {}
    parts = [presliding_features([p, -p, 0 * p], 10e-6, state) for p in np.array_split(s, 7)]
    np.testing.assert_array_equal(np.vstack(parts), f)


def test_pole_pitch_features_and_models_without_them(trained, tiny, tmp_path):
    """sin/cos of the pole-pitch harmonics join the inputs; 0 harmonics (or an older saved model) is the paper's 14."""
    from drivesense.learn.features import position_features

    s = np.array([0.0, 0.023 / 4, 0.023 / 2, 0.0115 + 0.023])
    f = position_features([s, s, s], 0.023, 2)
    assert f.shape == (4, 12) and f.dtype == np.float32
    np.testing.assert_allclose(f[:, 0], [0, 1, 0, 0], atol=1e-6)       # sin(2 pi s / p)
    np.testing.assert_allclose(f[:, 3], [1, -1, 1, 1], atol=1e-6)      # cos(4 pi s / p)
    assert trained.model.weights["force_x"].in_dims[0] == 14 + 18 + 3          # + the presliding states
    assert trained.model.config.skip_taps == 4                                 # the LSTM's default FIR skip
    assert trained.model.weights["force_x"].skip_w.shape == (35, 4)           # saved and loaded
    _, _, runs = tiny
    import dataclasses

    paper = LSTM(config=dataclasses.replace(TINY, position_harmonics=0, linear_skip=False, presliding_length=0.0,
                                            epochs=1)).fit(runs)
    assert paper.model.weights["force_x"].in_dims[0] == 14 and paper.model.weights["force_x"].skip_w is None
    paper.save(tmp_path / "old")
    cfg = json.loads((tmp_path / "old" / "config.json").read_text())
    for key in ("position_harmonics", "pole_pitch", "linear_skip", "presliding_length", "skip_taps"):  # saved before
        del cfg["config"][key]
    (tmp_path / "old" / "config.json").write_text(json.dumps(cfg))
    rec = runs[0]
    assert np.array_equal(LSTM.load(tmp_path / "old").estimate(rec)["force_y"], paper.estimate(rec)["force_y"])
    with pytest.raises(ConfigError, match="position_harmonics"):
        TrainConfig(position_harmonics=-1)
    with pytest.raises(ConfigError, match="lr_decay"):
        TrainConfig(lr_decay=0.0)
    with pytest.raises(ConfigError, match="grad_clip"):
        TrainConfig(grad_clip=-1.0)
    with pytest.raises(ConfigError, match="skip_taps"):
        TrainConfig(skip_taps=0)
    with pytest.raises(ConfigError, match="skip_lr_factor"):
        TrainConfig(skip_lr_factor=2.0)


def test_learn_bench_scoring_on_held_out_runs(trained, tiny):
    """evaluate_methods scores per run and axis against the filtered reference; wins count per run."""
    from drivesense.bench.learn import _hybrid_wins, evaluate_methods

    _, _, runs = tiny
    held = [r for r in runs if r.meta["split"] in ("test", "test_process")]
    ev = evaluate_methods({"lstm": trained}, held)
    assert len(ev["rows"]) == 3 * len(held) and 0.5 < ev["coverage"] <= 1.0
    assert all(r["rmse_n"] > 0 and r["max_abs_force_n"] > 0 for r in ev["rows"] if r["axis"] != "z")
    rows = [{"split": "test", "axis": ax, "run": run, "method": m, "rmse_n": v}
            for run, vals in (("a", (1.0, 2.0, 3.0)), ("b", (3.0, 2.0, 1.0))) for ax in "xy"
            for m, v in zip(("hybrid", "lstm", "model"), vals)]
    assert _hybrid_wins(rows, "test") == [True, False] and _hybrid_wins(rows, "test_process") == []


def test_learn_bench_figures_per_seed_and_their_spread():
    """seed_figures reads the pockets (every pocket process of the test split) and the ratios; spread summarises seeds."""
    from drivesense.bench.learn import TARGETS, _targets, seed_figures, spread

    rmse = {"model": 4.0, "model_paper": 8.0, "lstm": 3.0, "hybrid": 2.0}
    rows = [{"split": split, "axis": ax, "run": f"{proc}_{split}", "process": proc, "method": m,
             "rmse_n": v * (1.5 if proc.startswith("pocket") else 1.0)}
            for split, proc in (("test", "groove_+x"), ("test", "pocket_ccw"), ("test", "pocket_cw"),
                                ("test_process", "side_-x+y"))
            for ax in "xyz" for m, v in rmse.items()]
    f = seed_figures(rows)
    assert f["median_rmse"]["hybrid"] == pytest.approx(2.0 * 1.5)           # 4 pocket values of 6: median 3
    assert f["pocket_rmse"]["model"] == pytest.approx(6.0) and f["hybrid_over_model_pocket"] == pytest.approx(0.5)
    assert f["lstm_over_paper_model_pocket"] == pytest.approx(3.0 / 8.0)
    assert f["hybrid_best_fraction"] == 1.0 and f["hybrid_best_fraction_held_out_process"] == 1.0
    s = spread([1.0, 2.0, None, 3.0])
    assert s["mean"] == 2.0 and s["std"] == pytest.approx(1.0) and (s["min"], s["max"]) == (1.0, 3.0)
    assert s["per_seed"] == [1.0, 2.0, None, 3.0] and spread([None]) is None and spread([5.0])["std"] == 0.0
    summary = {k: spread([f[k]] * 3) for k in f if not isinstance(f[k], dict)}
    summary.update({"coverage_90": spread([0.9] * 3), "train_minutes_lstm_plus_hybrid": spread([20.0] * 3),
                    "infer_realtime_factor": spread([2000.0] * 3), "train_peak_mb": spread([300.0] * 3)})
    t = _targets(summary)
    assert set(t) == set(TARGETS)
    assert t["hybrid_over_model_pocket"]["met"] and not t["train_minutes_lstm_plus_hybrid"]["met"]
    assert t["coverage_90"]["met"] and t["hybrid_over_model_pocket"]["spread"]["std"] == 0.0


def test_a_hybrid_never_does_worse_than_its_model_on_the_validation_data(tiny):
    """Where the validation runs are the model's own estimate, any learned correction is worse: it is switched off
    and the hybrid gives its model (the model-alone candidate)."""
    from drivesense.estimate import ModelBased
    from drivesense.machine.linear_motor import linear_machine_model

    _, _, runs = tiny
    axes = linear_machine_model()
    train = [r for r in runs if r.meta.get("split") == "train"]
    val = []
    for r in [r for r in runs if r.meta.get("split") == "val"]:
        own = ModelBased(axes).estimate(r)
        val.append(r.with_channels({c: own[c] for c in own.channels}))
    hyb = Hybrid(config=TINY).fit(train + val, model_based=axes)
    history = hyb.model.history
    assert all(history["correction"][ch].startswith("off") for ch in ("force_x", "force_y", "force_z")), history
    assert all(history["model_alone_val_loss"][ch] <= min(history["val_loss"][ch]) for ch in history["correction"])
    rec = runs[0]
    got, model = hyb.estimate(rec), ModelBased(axes).estimate(rec)
    for ch in ("force_x", "force_y", "force_z"):
        np.testing.assert_allclose(got[ch], model[ch], rtol=1e-5, atol=1e-3 * float(np.ptp(model[ch])))
