"""Conformance of all eight methods to the one estimator contract (drivesense.estimate.base).

Every registered method, built through ``ds.estimate.make``: batch = stream for
any chunking (to the bit), Recording in -> Recording out and mapping in -> dict
out, the chunk's rate checked, chunk validation, the latency declared the same
way by batch and stream, and save/load where it applies.  The learned methods
run small random networks here (their training is tested in test_learn.py).
"""

from __future__ import annotations

import numpy as np
import pytest

import drivesense as ds
from drivesense.errors import ConfigError, InvalidSignalError, MissingChannelError
from drivesense.estimate import ForceEstimator, ForceStream
from drivesense.learn.features import INPUT_CHANNELS, TARGET_CHANNELS, Scaler, TargetScaler, input_matrix
from drivesense.learn.kernel import LSTMWeights
from drivesense.learn.model import LearnedModel, TrainConfig
from drivesense.recording import Recording

ALL = ("current", "rigid", "medob", "vibration", "model", "regression", "lstm", "hybrid")


def test_registry_lists_the_eight_methods():
    assert ds.estimate.available() == ALL
    assert ds.estimate.available("ballscrew") == ALL[:4]
    assert ds.estimate.available("linear") == ALL[4:]
    with pytest.raises(ConfigError, match="unknown method 'nope'; choose one of current"):
        ds.estimate.make("nope")
    with pytest.raises(ConfigError, match="--axis AXIS.toml"):
        ds.estimate.make("vibration", axes=None)
    with pytest.raises(ConfigError, match="needs identified axes"):
        ds.estimate.make("model", axes=ds.table1_axis())
    with pytest.raises(ConfigError, match="needs the AXES.toml of 'identify nc'"):
        ds.estimate.make("regression", axes=ds.table1_axis())


def _random_model(kind: str, runs, axes) -> LearnedModel:
    rng = np.random.default_rng(3 if kind == "lstm" else 4)
    config = TrainConfig(hidden=4, layers=2, position_harmonics=1, presliding_length=10e-6, skip_taps=3)
    scaler = Scaler.fit([input_matrix(r) for r in runs])
    probe = LearnedModel(kind, config, scaler, {}, {}, model_based=axes)
    n_in = probe.scaled_inputs({c: runs[0][c] for c in INPUT_CHANNELS}).shape[1] + (kind == "hybrid")
    weights = {}
    for ch in TARGET_CHANNELS:
        h, g4 = config.hidden, 4 * config.hidden
        w_ih = np.zeros((config.layers, g4, max(n_in, h)))
        w_ih[0, :, :n_in] = rng.normal(0, 0.3, (g4, n_in))
        w_ih[1, :, :h] = rng.normal(0, 0.3, (g4, h))
        weights[ch] = LSTMWeights(w_ih, rng.normal(0, 0.3, (config.layers, g4, h)), rng.normal(0, 0.1, (config.layers, g4)),
                                  np.array([n_in, h]), rng.normal(0, 0.5, h), 0.1,
                                  skip_w=rng.normal(0, 0.1, (n_in, 3)))
    force_scale = {ch: 100.0 for ch in TARGET_CHANNELS}
    return LearnedModel(kind, config, scaler, {ch: TargetScaler(200.0) for ch in TARGET_CHANNELS}, weights,
                        force_scale, {ch: 1.0 for ch in TARGET_CHANNELS}, {}, axes if kind == "hybrid" else None)


@pytest.fixture(scope="module")
def cases(feed_scenario, linear_air_moves):
    """Per method: the fitted estimator and a trace to estimate."""
    from drivesense.sim.machining import simulate_process

    cut = feed_scenario.cut.slice_time(0.0, 0.6)
    out = {}
    for name in ALL[:4]:
        out[name] = (ds.estimate.make(name, axis=ds.table1_axis()).fit(feed_scenario.idle), cut)
    axes = ds.identify_axes(list(linear_air_moves))
    trace = simulate_process("pocket_ccw", 2e-3, 2e-3, 500 / 60e3, 3500, seed=3).slice_time(None, 3.0)
    out["model"] = (ds.estimate.make("model", axes=axes), trace)
    from drivesense.machine.regression_model import RegressionModel

    out["regression"] = (ds.estimate.make("regression", axes=RegressionModel.fit([trace], ("x", "y", "z"))), trace)
    for kind in ("lstm", "hybrid"):
        out[kind] = (ds.estimate.make(kind, model=_random_model(kind, [trace], axes)), trace)
    return out


@pytest.mark.parametrize("name", ALL)
def test_is_a_force_estimator(cases, name):
    est, trace = cases[name]
    assert isinstance(est, ForceEstimator) and est.name == name and est.drive in ("ballscrew", "linear")
    assert all(c in trace.channels for c in est.channel_names)
    assert est.output_channels and all(c.startswith("force_") for c in est.output_channels)


@pytest.mark.parametrize("name", ALL)
def test_stream_equals_batch_for_any_chunking(cases, name):
    est, trace = cases[name]
    batch = est.estimate(trace)
    assert batch.channels == list(est.output_channels) and batch.n_samples == trace.n_samples
    assert all(batch.units(c) == "N" for c in batch.channels)
    rng = np.random.default_rng(11)
    edges = [0, 0, 1, 2]      # an empty chunk and single samples too
    while edges[-1] < trace.n_samples:
        edges.append(min(edges[-1] + int(rng.integers(1, 400)), trace.n_samples))
    stream = est.stream(trace.fs)
    assert isinstance(stream, ForceStream)
    parts = {c: [] for c in est.output_channels}
    for a, b in zip(edges[:-1], edges[1:]):
        got = stream.push({c: trace[c][a:b] for c in est.channel_names})
        assert isinstance(got, dict) and list(got) == list(est.output_channels)
        for c, v in got.items():
            parts[c].append(v)
    for c in est.output_channels:
        np.testing.assert_array_equal(np.concatenate(parts[c]), batch[c], err_msg=f"{name} {c}")
    assert stream.samples_seen == trace.n_samples


@pytest.mark.parametrize("name", ALL)
def test_recording_chunks_give_recordings_with_the_declared_latency(cases, name):
    est, trace = cases[name]
    batch = est.estimate(trace)
    delay = trace.meta.get("nc_delay_s", 0.0)
    stream = est.stream(trace.fs, delay_s=delay)
    half = trace.t0 + round(trace.n_samples / 2) / trace.fs
    first, second = stream.push(trace.slice_time(None, half)), stream.push(trace.slice_time(half, None))
    assert isinstance(first, Recording) and first.t0 == trace.t0 and second.t0 == pytest.approx(half)
    for c in est.output_channels:
        np.testing.assert_array_equal(np.concatenate([first[c], second[c]]), batch[c])
    latency = est.latency_s(trace.fs) + delay
    assert batch.meta["latency_s"] == pytest.approx(latency) == first.meta["latency_s"] == stream.latency_s
    assert est.latency_s(trace.fs) >= 0
    assert batch.meta["method"] == name and batch.meta["provenance"][-1].startswith(f"estimate {name}")


@pytest.mark.parametrize("name", ALL)
def test_stream_refuses_another_rate(cases, name):
    est, trace = cases[name]
    stream = est.stream(trace.fs)
    other = Recording.from_arrays({c: trace[c][:50] for c in est.channel_names}, fs=trace.fs / 2)
    with pytest.raises(InvalidSignalError, match=f"{trace.fs / 2:g} Hz but the stream runs at {trace.fs:g} Hz"):
        stream.push(other)
    chunk = {c: trace[c][:10] for c in est.channel_names}
    with pytest.raises(InvalidSignalError, match="--resample"):
        stream.push(chunk, fs=2 * trace.fs)
    with pytest.raises(InvalidSignalError, match="stream runs at"):
        stream.push({**chunk, "time": np.arange(10) / (3 * trace.fs)})
    stream.push({**chunk, "time": trace.t0 + np.arange(10) / trace.fs}, fs=trace.fs)   # the right rate passes


@pytest.mark.parametrize("name", ALL)
def test_stream_validates_chunks(cases, name):
    est, trace = cases[name]
    stream = est.stream(trace.fs)
    chunk = {c: trace[c][:10] for c in est.channel_names}
    last = est.channel_names[-1]
    with pytest.raises(MissingChannelError, match=repr(last)):
        stream.push({k: v for k, v in chunk.items() if k != last})
    with pytest.raises(InvalidSignalError, match=f"'{last}' holds NaN"):
        stream.push({**chunk, last: np.full(10, np.nan)})
    with pytest.raises(InvalidSignalError, match=f"'{last}' has 9 samples"):
        stream.push({**chunk, last: chunk[last][:9]})
    with pytest.raises(InvalidSignalError, match="must be 1-D"):
        stream.push({**chunk, last: np.zeros((10, 2))})
    with pytest.raises(InvalidSignalError, match="mapping of channel arrays"):
        stream.push([1, 2, 3])
    assert stream.samples_seen == 0          # refused chunks leave the state as it was


@pytest.mark.parametrize("name", ALL)
def test_stream_state_has_constant_size(cases, name):
    est, trace = cases[name]
    stream = est.stream(trace.fs)

    def size(obj) -> int:
        if isinstance(obj, np.ndarray):
            return obj.nbytes
        if isinstance(obj, dict):
            return sum(size(v) for v in obj.values()) + len(obj)
        if isinstance(obj, (tuple, list)):
            return sum(size(v) for v in obj) + len(obj)
        if hasattr(obj, "__dict__"):
            return size(vars(obj))
        return 8

    stream.push({c: trace[c][:100] for c in est.channel_names})
    before = size(stream.state)
    for k in range(1, 6):
        stream.push({c: trace[c][100 * k:100 * (k + 1)] for c in est.channel_names})
    assert size(stream.state) == before


def test_learned_methods_save_and_load(cases, tmp_path):
    pytest.importorskip("torch")
    for name in ("lstm", "hybrid"):
        est, trace = cases[name]
        est.save(tmp_path / name)
        back = ds.estimate.make(name, model=tmp_path / name)
        for c in est.output_channels:
            np.testing.assert_allclose(back.estimate(trace)[c], est.estimate(trace)[c], rtol=1e-5, atol=1e-4)
    with pytest.raises(ConfigError, match="holds a 'lstm' model, not 'hybrid'"):
        ds.estimate.make("hybrid", model=tmp_path / "lstm")


def test_ballscrew_methods_read_their_axis_file(tmp_path, cases):
    from drivesense.io.axis_file import write_axis_file

    write_axis_file(tmp_path / "axis.toml", ds.table1_axis(), ds.SignalParams(lpf_hz=800.0))
    est = ds.estimate.make("rigid", axis=tmp_path / "axis.toml")
    assert est.signal.lpf_hz == 800.0 and est.axis == ds.table1_axis()
