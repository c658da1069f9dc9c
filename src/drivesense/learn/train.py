"""Training the LSTM force reconstruction (third paper, Sec. 2.3) and its hybrid with the model.

One network per force component: 3 stacked LSTM layers of 20 cells, dropout
between them, a linear output (Eq. 11-16).  Plain PyTorch, deterministic seeds,
early stopping on validation runs that are evaluated like inference (whole
traces from a zero state).  Training uses random windows of the training runs;
the first ``burn_in`` samples of a window only warm the state up.

``kind="hybrid"`` trains the same networks on the residual of
:class:`~drivesense.estimate.model_based.ModelBased` (target = filtered force
minus the model's estimate), with the model's estimate as an extra input.

Prediction intervals: Monte-Carlo dropout gives a per-sample spread; its scale
is calibrated on the validation runs (normalised split-conformal), so a
nominal 90 % interval covers 90 % of validation samples.

The trained model, its settings and its folder format are
:mod:`drivesense.learn.model` (:class:`LearnedModel`, :class:`TrainConfig`,
re-exported here).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.learn.features import (INPUT_CHANNELS, TARGET_CHANNELS, Scaler, TargetScaler, filtered_target,
                                      input_matrix, resample_to)
from drivesense.learn.kernel import LSTMState, LSTMWeights, run_lstm, skip_to_torch
from drivesense.learn.model import LearnedModel, TrainConfig, require_torch
from drivesense.recording import Recording

__all__ = ["TrainConfig", "LearnedModel", "train_model", "require_torch"]


#: FIR taps of the linear skip when the config leaves them open (the better on the built dataset's validation runs)
_DEFAULT_TAPS = {"lstm": 4, "hybrid": 8}


def _prepare(runs: Sequence[Recording], fs: float) -> list[Recording]:
    out = []
    for rec in runs:
        rec = resample_to(rec, fs)
        rec.require(*INPUT_CHANNELS, *TARGET_CHANNELS)
        out.append(rec)
    return out


def train_model(kind: str, runs: Sequence[Recording], *, config: TrainConfig | None = None, model_based=None,
                progress: Callable[[str], None] | None = None) -> LearnedModel:
    """Train the three networks.

    Parameters
    ----------
    kind : {"lstm", "hybrid"}
        Plain LSTM, or LSTM on the residual of the model-based reconstruction.
    runs : sequence of Recording
        Traces with the NC inputs and reference forces; ``meta["split"]`` is
        ``"train"`` or ``"val"`` (others are ignored).
    config : TrainConfig, optional
        Settings.
    model_based : ThreeAxisModel, optional
        Identified axes, required for ``hybrid``.
    progress : callable, optional
        Called with a status line after each epoch.

    Returns
    -------
    LearnedModel
    """
    torch = require_torch()
    config = config or TrainConfig()
    if kind not in ("lstm", "hybrid"):
        raise ConfigError(f"unknown learned method {kind!r}; choose lstm or hybrid")
    if kind == "hybrid" and model_based is None:
        raise ConfigError("a hybrid needs the identified axes (model_based=...) for its model part")
    if config.skip_taps is None:
        config = replace(config, skip_taps=_DEFAULT_TAPS[kind])
    t_start = time.perf_counter()
    torch.manual_seed(config.seed)
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    train = _prepare([r for r in runs if r.meta.get("split") == "train"], config.fs)
    val = _prepare([r for r in runs if r.meta.get("split") == "val"], config.fs)
    if not train or not val:
        raise InvalidSignalError(f"training needs runs with meta split 'train' and 'val' "
                                 f"(got {len(train)} train, {len(val)} val)")
    scaler = Scaler.fit([input_matrix(r) for r in train])
    model = LearnedModel(kind, config, scaler, {}, {}, model_based=model_based)
    prepared = {name: [(rec, *model.inputs(rec)) for rec in group] for name, group in (("train", train), ("val", val))}
    history: dict = {"seconds": {}, "epochs": {}, "train_loss": {}, "val_loss": {}, "initial_val_loss": {}}
    for ch in TARGET_CHANNELS:
        data = {}
        for name, group in prepared.items():
            data[name] = [(model_input, filtered_target(rec, ch), bases[ch])
                          for rec, model_input, bases in group]
        model.force_scale[ch] = max(float(np.max(np.abs(t))) for _, t, _ in data["train"]) or 1.0
        model.target_scalers[ch] = TargetScaler(max(float(np.max(np.abs(t - b))) for _, t, b in data["train"]) or 1.0)
        t0 = time.perf_counter()
        weights, hist = _train_one(torch, model, ch, data["train"], data["val"], config, progress)
        model.weights[ch] = weights
        history["seconds"][ch] = time.perf_counter() - t0
        for key in ("epochs", "train_loss", "val_loss", "initial_val_loss"):
            history[key][ch] = hist[key]
        model.interval_scale[ch] = _calibrate(model, ch, data["val"])
    history["total_seconds"] = time.perf_counter() - t_start
    history["runs"] = {"train": len(train), "val": len(val)}
    model.history = history
    return model


def _train_one(torch, model: LearnedModel, ch: str, train, val, config: TrainConfig, progress):
    rng = np.random.default_rng(config.seed)
    ts = model.target_scalers[ch]
    xs = [model.network_input(x, b, ch).astype(np.float32) for x, _, b in train]
    ys = [ts.transform(t - b) for _, t, b in train]
    vx = [model.network_input(x, b, ch).astype(np.float32) for x, _, b in val]
    vy = [ts.transform(t - b) for _, t, b in val]
    n_in, taps = xs[0].shape[1], config.skip_taps

    class Net(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lstm = torch.nn.LSTM(n_in, config.hidden, config.layers, batch_first=True, dropout=config.dropout)
            self.head = torch.nn.Linear(config.hidden, 1)
            self.skip = torch.nn.Conv1d(n_in, 1, taps, bias=False) if config.linear_skip else None

        def forward(self, x):
            out, _ = self.lstm(x)
            y = self.head(out)[..., 0]
            if self.skip is None:
                return y
            causal = torch.nn.functional.pad(x.transpose(1, 2), (taps - 1, 0))   # zeros before the start
            return y + self.skip(causal)[:, 0, :]

    torch.manual_seed(config.seed + 101 * TARGET_CHANNELS.index(ch))
    net = Net()
    if net.skip is not None:
        # start from the least-squares FIR map of the inputs (the LSTM's head at zero): the network
        # then spends its training on what a linear filter cannot explain
        coef = _least_squares_fir(xs, ys, taps)
        with torch.no_grad():
            fir = skip_to_torch(coef[:-1].reshape(taps, n_in).T)
            net.skip.weight.copy_(torch.from_numpy(fir.astype(np.float32)))
            net.head.bias.fill_(float(coef[-1]))
            net.head.weight.zero_()
    groups = [{"params": [*net.lstm.parameters(), *net.head.parameters()]}]
    if net.skip is not None:
        groups.append({"params": net.skip.parameters(), "lr": config.lr * config.skip_lr_factor})
    opt = torch.optim.Adam(groups, lr=config.lr)
    schedule = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=config.lr_decay, patience=config.lr_patience,
                                                          threshold=0.0) if config.lr_decay < 1 else None
    lengths = np.array([x.shape[0] for x in xs])
    ok = np.flatnonzero(lengths > config.window)
    if ok.size == 0:
        raise InvalidSignalError(f"no training run is longer than the window ({config.window} samples)")
    weights_by_len = (lengths[ok] - config.window) / (lengths[ok] - config.window).sum()
    def val_loss() -> float:
        net.eval()
        with torch.no_grad():
            return float(np.mean([float(((net(torch.from_numpy(x[None]))[0] - torch.from_numpy(y)) ** 2).mean())
                                  for x, y in zip(vx, vy)]))

    best, best_loss, since = None, np.inf, 0
    if net.skip is not None:      # the linear start is a candidate too: training must beat it on validation
        best_loss, best = val_loss(), {k: t.detach().clone() for k, t in net.state_dict().items()}
    hist = {"epochs": 0, "train_loss": [], "val_loss": [], "initial_val_loss": None if best is None else best_loss}
    for epoch in range(config.epochs):
        net.train()
        losses = []
        for _ in range(max(1, config.windows_per_epoch // config.batch)):
            picks = rng.choice(ok, config.batch, p=weights_by_len)
            starts = [rng.integers(0, lengths[i] - config.window) for i in picks]
            xb = torch.from_numpy(np.stack([xs[i][s:s + config.window] for i, s in zip(picks, starts)]))
            yb = torch.from_numpy(np.stack([ys[i][s:s + config.window] for i, s in zip(picks, starts)]))
            pred = net(xb)
            loss = ((pred[:, config.burn_in:] - yb[:, config.burn_in:]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            if config.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(net.parameters(), config.grad_clip)
            opt.step()
            losses.append(loss.item())
        v = val_loss()
        if schedule is not None:
            schedule.step(v)
        hist["train_loss"].append(float(np.mean(losses)))
        hist["val_loss"].append(float(v))
        hist["epochs"] = epoch + 1
        if progress:
            progress(f"{model.kind} {ch}: epoch {epoch + 1}, train {np.mean(losses):.2e}, val {v:.2e}")
        if v < best_loss - 1e-7:
            best_loss, since = v, 0
            best = {k: t.detach().clone() for k, t in net.state_dict().items()}
        else:
            since += 1
            if since >= config.patience:
                break
    return LSTMWeights.from_state_dict(best, config.layers, config.dropout), hist


def _least_squares_fir(xs, ys, taps: int) -> np.ndarray:
    """Least-squares causal FIR map of the inputs onto the targets, from the normal equations run by run.

    Returns ``(taps * inputs + 1,)``: lag-major weights (lag 0 first), then the
    bias.  Samples before a run's start count as zero, as in the network's
    padded convolution; a tiny ridge keeps constant inputs harmless.
    """
    n_in = xs[0].shape[1]
    width = taps * n_in + 1
    gram, rhs = np.zeros((width, width)), np.zeros(width)
    for x, y in zip(xs, ys):
        a = np.zeros((x.shape[0], width))
        for lag in range(taps):
            a[lag:, lag * n_in:(lag + 1) * n_in] = x[:x.shape[0] - lag]
        a[:, -1] = 1.0
        gram += a.T @ a
        rhs += a.T @ np.asarray(y, dtype=np.float64)
    gram[np.diag_indices(width)] += 1e-9 * np.trace(gram) / width
    return np.linalg.solve(gram, rhs)


def _calibrate(model: LearnedModel, ch: str, val) -> float:
    """Scale of the MC spread so that the nominal coverage holds on the validation runs."""
    w = model.weights[ch]
    ts = model.target_scalers[ch]
    ratios = []
    for x_all, tgt, base in val:
        x = model.network_input(x_all, base, ch)
        pred = base + ts.inverse(run_lstm(w, LSTMState(w), x))
        spread = model.interval_spread(ch, x)
        ratios.append(np.abs(tgt - pred) / spread)
    return float(np.quantile(np.concatenate(ratios), model.config.coverage))
