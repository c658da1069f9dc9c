"""Learned reconstruction, core pieces: scaling round trips and the compiled LSTM (= PyTorch, stream = batch)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.learn.features import INPUT_CHANNELS, Scaler, TargetScaler
from drivesense.learn.kernel import LSTMState, LSTMWeights, _tanh, run_lstm, skip_to_torch


def test_input_scaler_maps_training_range():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.uniform(-3, 5, 500), rng.uniform(2, 9, 500), np.full(500, 4.0)])
    sc = Scaler.fit([a[:250], a[250:]])
    u = sc.transform(a)
    assert u[:, 0].min() == pytest.approx(-1, abs=1e-6) and u[:, 0].max() == pytest.approx(1, abs=1e-6)
    # strictly positive column: [0, 1] from zero
    assert sc.positive.tolist() == [False, True, False]
    assert u[:, 1].max() == pytest.approx(1, abs=1e-6) and u[:, 1].min() > 0
    # a constant column carries nothing to learn from: zero, whatever its value later
    assert sc.constant.tolist() == [False, False, True]
    assert np.all(u[:, 2] == 0.0) and np.all(sc.transform(a + 1.0)[:, 2] == 0.0)
    again = Scaler.from_dict(sc.to_dict())
    np.testing.assert_array_equal(again.transform(a), u)


def test_target_scaler_is_eq17_and_inverts():
    ts = TargetScaler(200.0)
    f = np.array([-200.0, 0.0, 100.0, 200.0])
    np.testing.assert_allclose(ts.transform(f), [0.0, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(ts.inverse(ts.transform(f)), f, atol=1e-4)


def test_input_channels_are_the_papers_nc_data():
    assert len(INPUT_CHANNELS) == 14 and "spindle_current" in INPUT_CHANNELS and "z_acceleration" in INPUT_CHANNELS


def test_fast_tanh_accuracy():
    xs = np.linspace(-12, 12, 48001)
    assert max(abs(_tanh(v) - math.tanh(v)) for v in xs) < 3e-7


def _random_weights(seed=0, layers=3, hidden=20, inputs=14, dropout=0.1):
    rng = np.random.default_rng(seed)
    state = {}
    for k in range(layers):
        n_in = inputs if k == 0 else hidden
        state[f"lstm.weight_ih_l{k}"] = rng.normal(0, 0.4, (4 * hidden, n_in))
        state[f"lstm.weight_hh_l{k}"] = rng.normal(0, 0.4, (4 * hidden, hidden))
        state[f"lstm.bias_ih_l{k}"] = rng.normal(0, 0.1, 4 * hidden)
        state[f"lstm.bias_hh_l{k}"] = rng.normal(0, 0.1, 4 * hidden)
    state["head.weight"] = rng.normal(0, 0.5, (1, hidden))
    state["head.bias"] = rng.normal(0, 0.1, 1)
    return state


def test_kernel_streaming_equals_batch_and_state_is_constant():
    w = LSTMWeights.from_state_dict(_random_weights(), 3, 0.1)
    x = np.random.default_rng(1).uniform(-1, 1, (1000, 14))
    batch = run_lstm(w, LSTMState(w), x)
    st = LSTMState(w)
    sizes = np.random.default_rng(2).integers(0, 40, 200)
    parts, i = [], 0
    for s in sizes:
        parts.append(run_lstm(w, st, x[i:i + s]))
        i += s
    parts.append(run_lstm(w, st, x[i:]))
    assert np.array_equal(np.concatenate(parts), batch)
    assert st.h.shape == (3, 20) and st.c.shape == (3, 20)


def test_mc_dropout_samples_differ_and_evaluation_mode_is_deterministic():
    w = LSTMWeights.from_state_dict(_random_weights(), 3, 0.2)
    x = np.random.default_rng(1).uniform(-1, 1, (300, 14))
    a = run_lstm(w, LSTMState(w), x, seed=1)
    b = run_lstm(w, LSTMState(w), x, seed=2)
    assert not np.allclose(a, b)
    assert np.array_equal(run_lstm(w, LSTMState(w), x), run_lstm(w, LSTMState(w), x))


def test_kernel_matches_pytorch():
    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    lstm = torch.nn.LSTM(14, 20, 3, batch_first=True, dropout=0.1).double().eval()
    head = torch.nn.Linear(20, 1).double()
    x = np.random.default_rng(0).uniform(-2, 2, (800, 14))
    with torch.no_grad():
        ref = head(lstm(torch.from_numpy(x)[None])[0])[0, :, 0].numpy()
    state = {f"lstm.{k}": v for k, v in lstm.state_dict().items()}
    state.update({f"head.{k}": v for k, v in head.state_dict().items()})
    out = run_lstm(LSTMWeights.from_state_dict(state, 3), LSTMState(LSTMWeights.from_state_dict(state, 3)), x)
    np.testing.assert_allclose(out, ref, atol=2e-5)      # the kernel runs in single precision, like training


def test_kernel_with_a_linear_skip_matches_pytorch():
    torch = pytest.importorskip("torch")
    torch.manual_seed(1)
    lstm = torch.nn.LSTM(14, 20, 3, batch_first=True).double().eval()
    head, skip = torch.nn.Linear(20, 1).double(), torch.nn.Linear(14, 1, bias=False).double()
    x = np.random.default_rng(3).uniform(-1, 1, (500, 14))
    with torch.no_grad():
        xt = torch.from_numpy(x)[None]
        ref = (head(lstm(xt)[0]) + skip(xt))[0, :, 0].numpy()
    state = {f"lstm.{k}": v for k, v in lstm.state_dict().items()}
    state.update({f"head.{k}": v for k, v in head.state_dict().items()})
    state["skip.weight"] = skip.weight
    w = LSTMWeights.from_state_dict(state, 3)
    np.testing.assert_allclose(run_lstm(w, LSTMState(w), x), ref, atol=2e-5)
    no_skip = LSTMWeights.from_state_dict({k: v for k, v in state.items() if k != "skip.weight"}, 3)
    assert not np.allclose(run_lstm(no_skip, LSTMState(no_skip), x), ref, atol=1e-3)


def test_kernel_with_a_causal_fir_skip_matches_pytorch_and_streams():
    """A multi-tap skip is a causal Conv1d over the inputs (zeros before the start); chunks carry its last inputs."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(2)
    state = _random_weights(seed=4)
    conv = torch.nn.Conv1d(14, 1, 5, bias=False).double()
    state["skip.weight"] = conv.weight
    w = LSTMWeights.from_state_dict(state, 3)
    assert w.taps == 5 and w.skip_w.shape == (14, 5)
    np.testing.assert_array_equal(skip_to_torch(w.skip_w), conv.weight.detach().numpy())   # round trip
    x = np.random.default_rng(5).uniform(-1, 1, (400, 14))
    no_skip = LSTMWeights.from_state_dict({k: v for k, v in state.items() if k != "skip.weight"}, 3)
    with torch.no_grad():
        fir = conv(torch.nn.functional.pad(torch.from_numpy(x).T[None], (4, 0)))[0, 0].numpy()
    batch = run_lstm(w, LSTMState(w), x)
    np.testing.assert_allclose(batch - run_lstm(no_skip, LSTMState(no_skip), x), fir, atol=2e-5)
    st, parts, i = LSTMState(w), [], 0
    for size in (0, 1, 2, 3, 7, 1, 50, 0, 4):           # chunks shorter than the filter included
        parts.append(run_lstm(w, st, x[i:i + size]))
        i += size
    parts.append(run_lstm(w, st, x[i:]))
    assert np.array_equal(np.concatenate(parts), batch) and st.tail.shape == (4, 14)


def test_zero_epochs_are_refused_by_the_config_and_the_cli(tmp_path):
    """``train --epochs 0`` used to save an untrained model."""
    from typer.testing import CliRunner

    from drivesense.cli import app
    from drivesense.errors import ConfigError
    from drivesense.learn.model import TrainConfig

    with pytest.raises(ConfigError, match="'epochs' must be an integer >= 1"):
        TrainConfig(epochs=0)
    (tmp_path / "data").mkdir()
    res = CliRunner().invoke(app, ["train", "lstm", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "m"),
                                   "--epochs", "0"])
    assert res.exit_code == 2 and "--epochs must be >= 1" in res.output
    assert not (tmp_path / "m").exists()


def test_kernel_matches_pytorch_at_widths_off_its_four_input_sweep():
    """Input and hidden widths that are no multiple of four: the padding rows of the packed weights are inert."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(3)
    lstm = torch.nn.LSTM(5, 7, 2, batch_first=True).double().eval()
    head = torch.nn.Linear(7, 1).double()
    conv = torch.nn.Conv1d(5, 1, 3, bias=False).double()
    x = np.random.default_rng(6).uniform(-1, 1, (300, 5))
    with torch.no_grad():
        xt = torch.from_numpy(x)[None]
        fir = conv(torch.nn.functional.pad(xt.transpose(1, 2), (2, 0)))[0, 0]
        ref = (head(lstm(xt)[0])[0, :, 0] + fir).numpy()
    state = {f"lstm.{k}": v for k, v in lstm.state_dict().items()}
    state.update({f"head.{k}": v for k, v in head.state_dict().items()})
    state["skip.weight"] = conv.weight
    w = LSTMWeights.from_state_dict(state, 2)
    assert w.packed_ih.shape == (2, 8, 28)                      # 5 inputs, then 7 cells, padded to 8 rows
    assert w.packed_hh.shape == (2, 8, 28)
    np.testing.assert_allclose(run_lstm(w, LSTMState(w), x), ref, atol=2e-5)
    with pytest.raises(ValueError, match="5 inputs per row"):
        run_lstm(w, LSTMState(w), x[:, :4])


def test_inference_timing_is_the_best_pass_without_the_warm_up():
    """bench learn times the best of several passes, the first (compiling) call left out, CPU time beside."""
    import time

    from drivesense.bench.learn import INFER_REPEATS, time_inference

    class Slow:
        calls = 0

        def estimate(self, rec):
            self.calls += 1
            time.sleep(0.3 if self.calls == 1 else 0.002)         # the first call compiles

    class Run:
        duration = 8.0

    out = time_inference(Slow(), [Run(), Run()])
    assert out["repeats"] == INFER_REPEATS and out["signal_seconds"] == 16.0
    assert 0.004 <= out["wall_seconds"] <= out["wall_seconds_median"] < 0.3
    assert 0.0 <= out["cpu_seconds"] < 0.3 and "load_average" in out
