"""The learned methods on small sets of slow real-machine traces (#14 item 3): one or two files at 50 Hz.

A controller traced at 50 Hz with dynamometer forces, two cuts and an air cut,
is what a user has.  Simulated here on the linear-motor machine at a 50 Hz NC
trace: training on one file and on two (a time split validates), scoring
against the reference at the trace's rate, no start transient, a model at
50 Hz applied to a 250 Hz trace, and a corrupt input sample that must not
wreck the scaling.
"""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.learn.features import (INPUT_CHANNELS, InputRangeWarning, Scaler, filtered_target, input_matrix,
                                      plausible_range, resample_to, target_cutoff_hz)
from drivesense.learn.train import time_split
from drivesense.recording import Recording
from drivesense.sim.linear_machine import LinearServoConfig
from drivesense.sim.machining import ProcessSettings, simulate_process

torch = pytest.importorskip("torch")

from drivesense.learn import LSTM, Hybrid  # noqa: E402
from drivesense.learn.model import TrainConfig  # noqa: E402

#: A 50 Hz NC trace: the logger's anti-alias filter and the reference filter at 20 Hz (below the 25 Hz Nyquist).
SLOW = ProcessSettings(servo=LinearServoConfig(nc_rate=50.0, logger_delay=0.1, reference_cutoff_hz=20.0))
TINY = TrainConfig(hidden=6, layers=2, epochs=2, windows_per_epoch=64, batch=16, mc_samples=2, seed=3)
CORRUPT_RAD_S = -3.3e6 * 2 * np.pi / 60        # a logger's corrupt spindle speed, -3.3e6 rpm


@pytest.fixture(scope="module")
def traces():
    """Two training files (a cut, the air cut of its path) and a held-out cut, all at 50 Hz."""
    cut = simulate_process("groove_+x", 2e-3, 10e-3, 500 / 60e3, 3500, seed=1, settings=SLOW)
    air = simulate_process("groove_+x", 2e-3, 10e-3, 500 / 60e3, 3500, seed=2, settings=SLOW, air=True)
    held = simulate_process("groove_+x", 1e-3, 10e-3, 400 / 60e3, 4500, seed=3, settings=SLOW)
    return cut, air, held


@pytest.fixture(scope="module")
def one_file(traces):
    return LSTM(config=TINY).fit([traces[0]])


def _corrupt(rec: Recording, index: int) -> Recording:
    speed = rec["spindle_speed"].copy()
    speed[index] = CORRUPT_RAD_S
    return rec.with_channels({"spindle_speed": speed})


def test_trace_is_at_50_hz_and_the_target_filter_stays_below_nyquist(traces):
    cut = traces[0]
    assert cut.fs == 50.0 and cut.meta["nc_delay_s"] == pytest.approx(0.1)
    assert target_cutoff_hz(250.0) == 120.0 and target_cutoff_hz(50.0) == 24.0 and target_cutoff_hz(25.0) == 12.0
    f = filtered_target(cut, "force_x")           # the default cut-off follows the rate: no ConfigError at 50 Hz
    assert f.shape == (cut.n_samples,) and np.all(np.isfinite(f))
    with pytest.raises(ConfigError, match="Nyquist"):
        filtered_target(cut, "force_x", cutoff_hz=120.0)


def test_time_split_blocks_and_guards():
    train, val = time_split(1000, 0.2, 50, 10)
    assert val.sum() == 200 and val[-1] and not val[0]
    starts = np.flatnonzero(np.diff(val.astype(int)) == 1) + 1
    assert len(starts) == 4                                   # at most four blocks, the last at the end
    assert not np.any(train & val)
    for s in starts:                                          # guards on either side of each block
        assert not train[s - 10:s].any()
    one_train, one_val = time_split(200, 0.2, 50, 5)          # 40 validation samples: one block, the tail
    assert one_val.sum() == 40 and one_val[-40:].all() and one_train[:155].all() and not one_train[155:].any()
    short_train, short_val = time_split(30, 0.2, 50, 5)       # too short to give a block: all training
    assert not short_val.any() and short_train.all()


def test_train_on_one_file_and_score_at_the_trace_rate(one_file, traces):
    from drivesense.score import score_estimate

    model = one_file.model
    hist = model.history
    assert model.config.fs == 50.0 and model.config.window == 50 and model.config.burn_in == 10
    assert model.config.skip_taps == 1 and model.config.warmup_steps(50.0) == 10
    assert hist["runs"] == {"train": 1, "val": 0} and hist["validation"].startswith("time split")
    assert all(len(v) == hist["epochs"][ch] for ch, v in hist["val_loss"].items())
    assert all(np.isfinite(s) and s > 0 for s in model.interval_scale.values())
    held = traces[2]
    out = one_file.estimate(held)
    assert out.fs == held.fs and out.n_samples == held.n_samples
    for ch in ("force_x", "force_y", "force_z"):
        s = score_estimate(out, held, channel=ch)               # used to raise IndexError (estimate at 250 Hz)
        assert np.isfinite(s.rmse_n)


def test_train_on_two_files_with_a_corrupt_sample(traces):
    cut, air, held = traces
    with pytest.warns(InputRangeWarning, match=r"'spindle_speed': 1 sample"):
        hyb = Hybrid(config=TINY).fit([_corrupt(air, 100), cut], model_based=_axes())
    model = hyb.model
    # two files: leave-one-file-out, the last one validates (early stopping, correction or the model alone)
    assert model.history["runs"] == {"train": 1, "val": 1}
    assert model.history["validation"].startswith("leave-one-file-out")
    assert model.config.skip_taps == 2                         # 32 ms at 50 Hz
    j = INPUT_CHANNELS.index("spindle_speed")
    sc = model.input_scaler
    clean = np.concatenate([cut["spindle_speed"], air["spindle_speed"]])
    assert sc.constant[j] and sc.low[j] == pytest.approx(clean.min())     # one spindle speed: constant, clean range
    assert -0.1 * clean.max() < sc.clip_low[j] < clean.min() and clean.max() < sc.clip_high[j] < 3 * clean.max()
    out = hyb.estimate(held)
    assert out.n_samples == held.n_samples and all(np.all(np.isfinite(out[c])) for c in out.channels)
    with pytest.warns(InputRangeWarning, match=r"'spindle_speed': 1\b"):  # clipped, and said so, at inference too
        bad = hyb.estimate(_corrupt(held, 50))
    assert np.max(np.abs(bad["force_x"] - out["force_x"])) < 10 * np.ptp(held["force_x"])


def test_scaler_ignores_a_corrupt_sample_and_keeps_legitimate_excursions(traces):
    x = input_matrix(traces[0])
    clean = Scaler.fit([x])
    bad = x.copy()
    j = INPUT_CHANNELS.index("spindle_speed")
    bad[77, j] = CORRUPT_RAD_S
    with pytest.warns(InputRangeWarning, match=r"'spindle_speed': 1 sample\(s\) \(e\.g\. -3\.456e\+05\)"):
        robust = Scaler.fit([bad])
    np.testing.assert_array_equal(robust.low, clean.low)
    np.testing.assert_array_equal(robust.high, clean.high)
    unclipped = Scaler(clean.low, clean.high, clean.positive)          # as a model of the first format scales
    assert -0.1 < robust.transform(bad)[77, j] < 1.1 and unclipped.transform(bad)[77, j] < -900   # clipped, not -941
    with warnings.catch_warnings():
        warnings.simplefilter("error")              # clean data: nothing flagged, every column's full range kept
        again = Scaler.fit([x])
    assert np.all(again.outside(x) == 0)
    lo, hi = plausible_range(np.r_[np.zeros(500), np.linspace(0, 0.1, 20)])     # a rare ramp stays plausible
    assert lo < 0 and hi > 0.1
    assert plausible_range(np.full(100, 3.0))[1] > 3.0 and plausible_range(np.zeros(100)) == (-np.inf, np.inf)


def test_a_column_constant_in_training_is_scaled_to_zero(traces):
    cut, _, held = traces                                   # trained at 3500 min^-1, held out at 4500 min^-1
    scaler = Scaler.fit([input_matrix(cut)])
    j = INPUT_CHANNELS.index("spindle_speed")
    assert scaler.constant[j] and np.ptp(cut["spindle_speed"]) < 0.01 * cut["spindle_speed"].max()
    assert not scaler.constant[INPUT_CHANNELS.index("x_current")]
    # no weight can be put on it: zero in training and on a trace at another speed (was 1.0 and 1.29)
    assert np.all(scaler.transform(input_matrix(cut))[:, j] == 0.0)
    assert np.all(scaler.transform(input_matrix(held))[:, j] == 0.0)
    again = Scaler.from_dict(json.loads(json.dumps(scaler.to_dict())))
    np.testing.assert_array_equal(again.constant, scaler.constant)
    old = scaler.to_dict()
    del old["constant"]                                     # a model saved before: no column is constant
    assert Scaler.from_dict(old).constant is None


def test_no_start_transient_and_stream_equals_batch(one_file, traces):
    held = traces[2]
    out = one_file.estimate(held)
    rest = int(0.25 * held.fs)                      # the trace starts with the machine at rest for 0.3 s
    for ch in ("force_x", "force_y", "force_z"):
        ref_range = np.ptp(filtered_target(held, ch)) or 1.0
        assert np.ptp(out[ch][:rest]) < 0.5 * ref_range, ch          # flat while the machine rests
        assert np.max(np.abs(out[ch][:rest] - out[ch][rest])) < ref_range, ch
    stream = one_file.stream(held.fs)
    edges = [0, 0, 1, 3, 40, 41, 200, held.n_samples]                # an empty first chunk does not prime
    parts = [stream.push({c: held[c][a:b] for c in INPUT_CHANNELS}) for a, b in zip(edges[:-1], edges[1:])]
    for ch in ("force_x", "force_y", "force_z"):
        assert np.array_equal(np.concatenate([p[ch] for p in parts]), out[ch])
    # the trained networks barely moved from their linear start; give their LSTMs a say to see the priming act
    model = one_file.model
    loud = dataclasses.replace(model, weights={ch: dataclasses.replace(w, head_w=np.full(w.hidden, 0.3))
                                               for ch, w in model.weights.items()})
    primed = LSTM(loud).estimate(held)                                    # 0.2 s of priming by default
    settled = LSTM(_with_config(loud, warmup_s=5.0)).estimate(held)        # a state long settled at rest
    unprimed = LSTM(_with_config(loud, warmup_s=0.0)).estimate(held)       # a zero state
    for ch in ("force_x", "force_y", "force_z"):
        ref_range = np.ptp(filtered_target(held, ch)) or 1.0
        transient = np.max(np.abs(unprimed[ch][:rest] - settled[ch][:rest]))
        left = np.max(np.abs(primed[ch][:rest] - settled[ch][:rest]))
        assert left < 0.1 * ref_range and left < 0.2 * transient, (ch, left, transient)
    stream = LSTM(loud).stream(held.fs)
    parts = [stream.push({c: held[c][a:b] for c in INPUT_CHANNELS}) for a, b in zip(edges[:-1], edges[1:])]
    assert np.array_equal(np.concatenate([p["force_z"] for p in parts]), primed["force_z"])   # primed alike


def _with_config(model, **changes):
    return dataclasses.replace(model, config=dataclasses.replace(model.config, **changes))


def _axes():
    from drivesense.machine.linear_motor import linear_machine_model

    return linear_machine_model()


def test_a_model_at_50_hz_on_a_250_hz_trace(one_file, traces):
    held = traces[2]
    fast = resample_to(held, 250.0)
    assert fast.n_samples == 5 * held.n_samples
    np.testing.assert_allclose(fast["x_position"][:3], held["x_position"][0], atol=1e-6)   # no edge transient
    out = one_file.estimate(fast)
    assert out.fs == 250.0 and out.n_samples == fast.n_samples and out.t0 == fast.t0
    assert any("250 Hz -> 50 Hz" in p for p in out.meta["provenance"])
    assert any("50 Hz -> 250 Hz" in p for p in out.meta["provenance"])
    slow_out = one_file.estimate(held)
    np.testing.assert_allclose(out["force_y"][::5], slow_out["force_y"], atol=0.1 * np.ptp(slow_out["force_y"]) + 1)
    with pytest.raises(ConfigError, match="the model works at 50 Hz; resample the 250 Hz signals"):
        one_file.stream(250.0)


def test_save_load_and_the_first_format(one_file, traces, tmp_path):
    held = traces[2]
    one_file.save(tmp_path / "m")
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["format"] == "drivesense-learned-2" and cfg["config"]["fs"] == 50.0
    back = LSTM.load(tmp_path / "m")
    ref = one_file.estimate(held)
    np.testing.assert_array_equal(back.estimate(held)["force_y"], ref["force_y"])
    # a folder of the first format: no limits, no settings in seconds; it loads, unclipped, primed on its burn-in
    cfg["format"] = "drivesense-learned-1"
    for key in ("window_s", "burn_in_s", "warmup_s", "val_fraction"):
        del cfg["config"][key]
    for key in ("clip_low", "clip_high"):
        del cfg["input_scaler"][key]
    (tmp_path / "m" / "config.json").write_text(json.dumps(cfg))
    old = LSTM.load(tmp_path / "m")
    assert old.model.input_scaler.clip_low is None and old.model.config.warmup_steps(50.0) == 10
    np.testing.assert_array_equal(old.estimate(held)["force_y"], ref["force_y"])
    cfg["format"] = "drivesense-learned-9"
    (tmp_path / "m" / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ConfigError, match="unknown model format 'drivesense-learned-9'"):
        LSTM.load(tmp_path / "m")


def test_refusals(traces):
    cut = traces[0]
    with pytest.raises(ConfigError, match="'warmup_s'"):
        TrainConfig(warmup_s=-1.0)
    with pytest.raises(ConfigError, match="'val_fraction'"):
        TrainConfig(val_fraction=0.9)
    with pytest.raises(ConfigError, match="'burn_in'"):
        TrainConfig(window=10, burn_in=10)
    slow = resample_to(cut, 20.0)
    with pytest.raises(InvalidSignalError, match="25 Hz or faster"):
        LSTM(config=TINY).fit([slow])
    with pytest.raises(InvalidSignalError, match="too short for a validation split"):
        LSTM(config=TINY).fit([cut.slice_time(None, cut.t0 + 0.8)])
    with pytest.raises(InvalidSignalError, match="split 'train'"):
        LSTM(config=TINY).fit([cut.with_meta(split="test")])


def test_cli_trains_on_one_file(traces, tmp_path):
    from typer.testing import CliRunner

    from drivesense.cli import app
    from drivesense.io import write_recording

    (tmp_path / "data").mkdir()
    write_recording(traces[0], tmp_path / "data" / "cut.nc")
    res = CliRunner().invoke(app, ["train", "lstm", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "m"),
                                   "--epochs", "1", "--json", str(tmp_path / "t.json")])
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "t.json").read_text())
    assert info["history"]["runs"] == {"train": 1, "val": 0} and info["history"]["fs"] == 50.0
    assert "time split" in res.output
