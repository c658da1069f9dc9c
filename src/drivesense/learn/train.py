"""Training the LSTM force reconstruction (third paper, Sec. 2.3) and its hybrid with the model.

One network per force component: 3 stacked LSTM layers of 20 cells, dropout
between them, a linear output (Eq. 11-16).  Plain PyTorch, deterministic seeds,
early stopping on validation runs that are evaluated like inference (whole
traces, the networks primed on the first input).  Training uses random windows
of the training runs; the first ``burn_in`` samples of a window only warm the
state up from zero.

Small sets: with no validation run (one or two files of a real machine), a
time split of every training run validates instead (:func:`time_split`: a
fifth of each run in blocks of at least one window, guarded).  It measures how
well the network generalises within the runs' own processes, not to new ones:
early stopping and the intervals are then optimistic for a process the runs do
not show, which the history notes (``history["validation"]``).

Rates: the model works at its training runs' own rate (or ``TrainConfig.fs``),
from 25 Hz up; window, burn-in, priming and the skip's length are set in
seconds and resolved to samples at that rate, and the target filter stays
below the Nyquist frequency (:func:`~drivesense.learn.features.target_cutoff_hz`).

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
from drivesense.estimate.model_based import ModelBased
from drivesense.learn.features import (INPUT_CHANNELS, TARGET_CHANNELS, Scaler, TargetScaler, filtered_target,
                                      input_matrix, resample_to)
from drivesense.learn.kernel import LSTMState, LSTMWeights, run_lstm, skip_to_torch
from drivesense.learn.model import LearnedModel, TrainConfig, require_torch
from drivesense.recording import Recording

__all__ = ["TrainConfig", "LearnedModel", "train_model", "time_split", "require_torch", "MIN_FS"]


def _prepare(runs: Sequence[Recording], fs: float) -> list[Recording]:
    out = []
    for rec in runs:
        rec.require(*INPUT_CHANNELS, *TARGET_CHANNELS)
        out.append(resample_to(rec, fs))
    return out


#: Slowest trace rate the learned methods take [Hz].
MIN_FS = 25.0
#: Most validation blocks per run in a time split.
_MAX_VAL_BLOCKS = 4
#: Fewest validation samples a run must give to take part in a time split.
_MIN_VAL_SAMPLES = 10


def time_split(n: int, fraction: float, window: int, guard: int) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation samples of one run when there are no validation runs.

    The validation share is cut into blocks of at least one training window
    (at most four), each at the end of an equal segment of the run, so the
    last one is the run's tail: validation covers the run's beginning, middle
    and end (approach, cut, exit) rather than its last phase only.  The
    training loss leaves out the blocks and ``guard`` samples on either side
    of each (the zero-phase target filter and the network's memory smear a
    sample into its neighbours), so no validation target, nor a target that
    carries it, is trained on.  The network still sees every input (inputs are
    known at inference): a validation block is scored after running the
    network over the whole run, as inference would.

    Parameters
    ----------
    n : int
        Samples in the run.
    fraction : float
        Share of the run for validation [-].
    window : int
        Training window [samples] (the shortest block).
    guard : int
        Samples left out of training on either side of a block.

    Returns
    -------
    train, val : ndarray of bool, shape (n,)
        Samples in the training loss and in validation; ``val`` is all False
        when the run is too short to give a block.
    """
    val = np.zeros(n, dtype=bool)
    n_val = int(round(fraction * n))
    if n_val < _MIN_VAL_SAMPLES:
        return np.ones(n, dtype=bool), val
    blocks = int(np.clip(round(n_val / max(window, 1)), 1, _MAX_VAL_BLOCKS))
    length = n_val // blocks
    for k in range(blocks):
        end = int(round((k + 1) * n / blocks))
        val[end - length:end] = True
    near = np.convolve(val.astype(float), np.ones(2 * guard + 1), mode="same") > 0 if guard else val
    return ~near, val


def train_model(kind: str, runs: Sequence[Recording], *, config: TrainConfig | None = None, model_based=None,
                progress: Callable[[str], None] | None = None) -> LearnedModel:
    """Train the three networks.

    Parameters
    ----------
    kind : {"lstm", "hybrid"}
        Plain LSTM, or LSTM on the residual of the model-based reconstruction.
    runs : sequence of Recording
        Traces with the NC inputs and reference forces.  ``meta["split"]``
        ``"train"`` (or no split) trains, ``"val"`` validates (early stopping
        and the interval calibration); other splits (``"test"``...) are
        ignored.  Without validation runs a hybrid given two or more runs
        holds the last one out (leave-one-file-out: early stopping, and the
        choice between its correction and the model alone, are made on a file
        it never trained on); otherwise -- one file, or a plain LSTM -- a time
        split of each training run (:func:`time_split`, ``config.val_fraction``)
        validates instead.  Any rate from 25 Hz up: the model works at the
        runs' own rate (``config.fs`` None) or at ``config.fs``, resampling
        explicitly.
    config : TrainConfig, optional
        Settings.
    model_based : ThreeAxisModel or ControllerModel or ModelBased, optional
        Identified axes, required for ``hybrid`` (a
        :class:`~drivesense.estimate.model_based.ModelBased` gives its model).
    progress : callable, optional
        Called with a status line after each epoch.

    Returns
    -------
    LearnedModel
        Its ``config`` resolved at the model's rate (:meth:`TrainConfig.at_rate`);
        ``history["validation"]`` says which validation was used.
    """
    torch = require_torch()
    config = config or TrainConfig()
    if kind not in ("lstm", "hybrid"):
        raise ConfigError(f"unknown learned method {kind!r}; choose lstm or hybrid")
    if isinstance(model_based, ModelBased):
        model_based = model_based.model
    if kind == "hybrid" and model_based is None:
        raise ConfigError("a hybrid needs the identified axes (model_based=...) for its model part")
    if kind == "hybrid":
        from drivesense.learn.model import hybrid_base

        missing = [a for a in ("x", "y", "z") if a not in hybrid_base(model_based).axes]
        if missing:
            raise ConfigError(f"a hybrid corrects an estimate of axes x, y and z; the identified model lacks "
                              f"{', '.join(missing)} (identify nc left it out: see its warnings, or give --km)")
    train = [r for r in runs if r.meta.get("split", "train") == "train"]
    val = [r for r in runs if r.meta.get("split") == "val"]
    if kind == "hybrid" and not val and len(train) >= 2 and not any("split" in r.meta for r in train):
        train, val = train[:-1], train[-1:]       # leave-one-file-out
    if not train:
        raise InvalidSignalError(f"training needs runs with meta split 'train' (or none); got {len(val)} 'val' "
                                 f"and {len(runs) - len(val)} other runs")
    fs = config.fs if config.fs is not None else max(r.fs for r in train + val)
    if fs < MIN_FS:
        raise InvalidSignalError(f"the learned methods need traces at {MIN_FS:g} Hz or faster; the model would "
                                 f"work at {fs:g} Hz (resample the traces, --resample HZ)")
    config = config.at_rate(fs, kind)
    if config.windows_per_epoch is None:
        samples = sum(r.n_samples * config.fs / r.fs for r in train)
        config = replace(config, windows_per_epoch=int(min(4096, max(256, 4 * samples / config.window))))
    t_start = time.perf_counter()
    torch.manual_seed(config.seed)
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    train, val = _prepare(train, config.fs), _prepare(val, config.fs)
    scaler = Scaler.fit([input_matrix(r) for r in train])
    model = LearnedModel(kind, config, scaler, {}, {}, model_based=model_based)
    prepared = {name: [(rec, *model.inputs(rec)) for rec in group] for name, group in (("train", train), ("val", val))}
    masks: dict = {"train": [None] * len(train), "val": [None] * len(val)}
    if val:
        validation = (f"{len(val)} validation run(s)" if any("split" in r.meta for r in val)
                      else f"leave-one-file-out: {val[0].name or 'the last run'} held out")
    else:
        split = [time_split(rec.n_samples, config.val_fraction, config.window, config.burn_in) for rec in train]
        if not any(v.any() for _, v in split):
            raise InvalidSignalError(f"the training runs are too short for a validation split (each needs "
                                     f"{int(np.ceil(_MIN_VAL_SAMPLES / config.val_fraction))} samples); give "
                                     "longer runs or runs with meta split 'val'")
        prepared["val"] = [item for item, (_, v) in zip(prepared["train"], split) if v.any()]
        masks = {"train": [t for t, _ in split], "val": [v for _, v in split if v.any()]}
        validation = (f"time split: {config.val_fraction:.0%} of each training run in blocks at the ends of equal "
                      f"segments (the last at its end), {config.burn_in} samples on either side left out of training")
    history: dict = {"seconds": {}, "epochs": {}, "train_loss": {}, "val_loss": {}, "initial_val_loss": {}}
    for ch in TARGET_CHANNELS:
        data = {}
        for name, group in prepared.items():
            data[name] = [(model_input, filtered_target(rec, ch), bases[ch], mask)
                          for (rec, model_input, bases), mask in zip(group, masks[name])]
        model.force_scale[ch] = max(_abs_max(t, m) for _, t, _, m in data["train"]) or 1.0
        model.target_scalers[ch] = TargetScaler(max(_abs_max(t - b, m) for _, t, b, m in data["train"]) or 1.0)
        t0 = time.perf_counter()
        weights, hist = _train_one(torch, model, ch, data["train"], data["val"], config, progress)
        model.weights[ch] = weights
        history["seconds"][ch] = time.perf_counter() - t0
        for key in ("epochs", "train_loss", "val_loss", "initial_val_loss", "skip_ridge", "model_alone_val_loss",
                    "correction"):
            history.setdefault(key, {})[ch] = hist.get(key)
        model.interval_scale[ch] = _calibrate(model, ch, data["val"])
    history["total_seconds"] = time.perf_counter() - t_start
    history["runs"] = {"train": len(train), "val": len(val)}
    history["validation"] = validation
    history["fs"] = config.fs
    model.history = history
    return model


def _abs_max(x: np.ndarray, mask: np.ndarray | None) -> float:
    return float(np.max(np.abs(x if mask is None else x[mask]), initial=0.0))


def _train_one(torch, model: LearnedModel, ch: str, train, val, config: TrainConfig, progress):
    rng = np.random.default_rng(config.seed)
    ts = model.target_scalers[ch]
    xs = [model.network_input(x, b, ch).astype(np.float32) for x, _, b, _ in train]
    ys = [ts.transform(t - b) for _, t, b, _ in train]
    ms = [None if m is None else m.astype(np.float32) for _, _, _, m in train]
    vx = [model.network_input(x, b, ch).astype(np.float32) for x, _, b, _ in val]
    vy = [ts.transform(t - b) for _, t, b, _ in val]
    vm = [m for _, _, _, m in val]
    masked = any(m is not None for m in ms)
    n_in, taps = xs[0].shape[1], config.skip_taps
    prime = config.warmup_steps(config.fs)

    class Net(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lstm = torch.nn.LSTM(n_in, config.hidden, config.layers, batch_first=True, dropout=config.dropout)
            self.head = torch.nn.Linear(config.hidden, 1)
            self.skip = torch.nn.Conv1d(n_in, 1, taps, bias=False) if config.linear_skip else None

        def forward(self, x, primed: int = 0):
            # primed: the state (and the skip's past) as inference starts it, after `primed` steps of the first row
            if primed:
                first = x[:, :1]
                _, state = self.lstm(first.expand(-1, primed, -1).contiguous())
                out, _ = self.lstm(x, state)
            else:
                out, _ = self.lstm(x)
            y = self.head(out)[..., 0]
            if self.skip is None:
                return y
            if primed:
                causal = torch.cat([first.expand(-1, taps - 1, -1), x], dim=1).transpose(1, 2)
            else:
                causal = torch.nn.functional.pad(x.transpose(1, 2), (taps - 1, 0))   # zeros before the start
            return y + self.skip(causal)[:, 0, :]

    torch.manual_seed(config.seed + 101 * TARGET_CHANNELS.index(ch))
    net = Net()
    if net.skip is not None:
        # start from the least-squares FIR map of the inputs (the LSTM's head at zero): the network
        # then spends its training on what a linear filter cannot explain
        coef, hist_ridge = _least_squares_fir(xs, ys, taps, ms, val=(vx, vy, vm))
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
        raise InvalidSignalError(f"no training run is longer than the window ({config.window} samples at "
                                 f"{config.fs:g} Hz = {config.window / config.fs:g} s)")
    weights_by_len = (lengths[ok] - config.window) / (lengths[ok] - config.window).sum()

    def val_loss() -> float:
        # evaluated like inference: whole runs from the primed state
        net.eval()
        with torch.no_grad():
            errs = [((net(torch.from_numpy(x[None]), prime)[0] - torch.from_numpy(y)) ** 2).numpy()
                    for x, y in zip(vx, vy)]
        if vm[0] is None:
            return float(np.mean([e.mean() for e in errs]))
        return float(np.concatenate([e[m] for e, m in zip(errs, vm)]).mean())

    best, best_loss, since = None, np.inf, 0
    if net.skip is not None:      # the linear start is a candidate too: training must beat it on validation
        best_loss, best = val_loss(), {k: t.detach().clone() for k, t in net.state_dict().items()}
    hist = {"epochs": 0, "train_loss": [], "val_loss": [], "initial_val_loss": None if best is None else best_loss,
            "skip_ridge": None if net.skip is None else hist_ridge}
    for epoch in range(config.epochs):
        net.train()
        losses = []
        for _ in range(max(1, config.windows_per_epoch // config.batch)):
            picks = rng.choice(ok, config.batch, p=weights_by_len)
            starts = [rng.integers(0, lengths[i] - config.window) for i in picks]
            xb = torch.from_numpy(np.stack([xs[i][s:s + config.window] for i, s in zip(picks, starts)]))
            yb = torch.from_numpy(np.stack([ys[i][s:s + config.window] for i, s in zip(picks, starts)]))
            pred = net(xb)
            if masked:      # a time split: validation samples (and their guards) never enter the loss
                wb = torch.from_numpy(np.stack([ms[i][s:s + config.window] for i, s in zip(picks, starts)]))
                wb = wb[:, config.burn_in:]
                loss = (wb * (pred[:, config.burn_in:] - yb[:, config.burn_in:]) ** 2).sum() / wb.sum().clamp_min(1.0)
            else:
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
    if model.kind == "hybrid":
        # the model alone (no correction: the network's output pinned at the scaled zero) is a candidate too: a
        # correction that does worse on held-out data than the model it corrects is switched off
        alone = _model_alone(best if best is not None else net.state_dict())
        net.load_state_dict(alone)
        hist["model_alone_val_loss"] = alone_loss = val_loss()
        hist["correction"] = "on"
        if alone_loss <= best_loss:
            best, best_loss = alone, alone_loss
            hist["correction"] = "off: the model alone did better on the validation data"
    return LSTMWeights.from_state_dict(best, config.layers, config.dropout), hist


def _model_alone(state: dict) -> dict:
    """A network state whose output is the scaled zero (0.5, :class:`TargetScaler`): the hybrid gives its model."""
    out = {k: t.detach().clone() for k, t in state.items()}
    out["head.weight"].zero_()
    out["head.bias"].fill_(0.5)
    if "skip.weight" in out:
        out["skip.weight"].zero_()
    return out


#: Ridges of the skip's least-squares start, relative to the mean diagonal of the normal equations, smallest first
#: (1e-9 only keeps constant inputs harmless).
_RIDGES = (1e-9, 1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: A larger ridge replaces a smaller one only if it cuts the validation error by this share [-].  On the built
#: dataset's 15 validation runs 1e-6 gains 0.1-0.9 % over 1e-9 (noise; the held-out hybrid median got 3 % worse
#: with it), on one 50 Hz file a ridge gains a factor of thousands.
_RIDGE_GAIN = 0.05


def _fir_design(x: np.ndarray, taps: int) -> np.ndarray:
    """Lagged copies of the inputs (lag-major, zeros before the start) and a constant column."""
    n_in = x.shape[1]
    a = np.zeros((x.shape[0], taps * n_in + 1))
    for lag in range(taps):
        a[lag:, lag * n_in:(lag + 1) * n_in] = x[:x.shape[0] - lag]
    a[:, -1] = 1.0
    return a


def _least_squares_fir(xs, ys, taps: int, masks=None, val=None) -> tuple[np.ndarray, float]:
    """Least-squares causal FIR map of the inputs onto the targets, from the normal equations run by run.

    Returns ``(taps * inputs + 1,)`` coefficients: lag-major weights (lag 0
    first), then the bias; and the relative ridge used.  Samples before a
    run's start count as zero, as in the network's padded convolution.  Where
    a run has a mask (time split), only its training samples count.  The
    ridge is chosen among :data:`_RIDGES`, the smallest unless a larger one
    cuts the error by more than :data:`_RIDGE_GAIN`, where the error is:

    * with two or more runs in a time split (a user's few files): each run's
      training samples predicted by the map fitted on the other runs (leave
      one run out).  That is the error on a process the map was not fitted
      on, which a time split cannot show: within its own runs a ridge smooths
      the map, but it also shrinks the current-to-force weights that carry a
      held-out cut's larger forces (on two 50 Hz cuts of the ball-screw
      centre the time split took ridges of 0.01-0.1 and the held-out z error
      grew 3x);
    * otherwise, with ``val`` (``(inputs, targets, masks)`` of the validation
      runs or blocks): the validation error of the map.  With one file the
      pole-pitch harmonics let an unregularised map follow the training path
      and swing wildly between its samples.
    """
    width = taps * xs[0].shape[1] + 1
    parts = []
    for x, y, m in zip(xs, ys, masks or [None] * len(xs)):
        a = _fir_design(x, taps)
        y = np.asarray(y, dtype=np.float64)
        if m is not None:
            keep = m > 0
            a, y = a[keep], y[keep]
        parts.append((a, y, a.T @ a, a.T @ y))
    gram = sum(p[2] for p in parts)
    rhs = sum(p[3] for p in parts)

    def solve(ridge: float, g: np.ndarray = gram, r: np.ndarray = rhs) -> np.ndarray:
        g = g.copy()
        g[np.diag_indices(width)] += ridge * np.trace(g) / width
        return np.linalg.solve(g, r)

    if masks is not None and any(m is not None for m in masks) and len(parts) >= 2:
        def error(ridge: float) -> float:
            sq = [(a @ solve(ridge, gram - g_k, rhs - r_k) - y) ** 2 for a, y, g_k, r_k in parts]
            return float(np.mean(np.concatenate(sq)))
    elif val is not None:
        designs = []
        for x, y, m in zip(*val):
            a, y = _fir_design(x, taps), np.asarray(y, dtype=np.float64)
            designs.append((a, y) if m is None else (a[m], y[m]))

        def error(ridge: float) -> float:
            coef = solve(ridge)
            return float(np.mean(np.concatenate([(a @ coef - y) ** 2 for a, y in designs])))
    else:
        return solve(_RIDGES[0]), _RIDGES[0]
    best = None
    for ridge in _RIDGES:
        err = error(ridge)
        if best is None or err < (1.0 - _RIDGE_GAIN) * best[0]:
            best = (err, ridge)
    return solve(best[1]), best[1]


def _calibrate(model: LearnedModel, ch: str, val) -> float:
    """Scale of the MC spread so that the nominal coverage holds on the validation runs (or blocks)."""
    w = model.weights[ch]
    ts = model.target_scalers[ch]
    steps = model.config.warmup_steps(model.config.fs)
    ratios = []
    for x_all, tgt, base, mask in val:
        x = model.network_input(x_all, base, ch)
        pred = base + ts.inverse(run_lstm(w, LSTMState(w, warmup=steps), x))
        spread = model.interval_spread(ch, x)
        ratio = np.abs(tgt - pred) / spread
        ratios.append(ratio if mask is None else ratio[mask])
    return float(np.quantile(np.concatenate(ratios), model.config.coverage))
