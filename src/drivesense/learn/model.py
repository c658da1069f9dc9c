"""A trained LSTM force reconstruction (third paper, Sec. 2.3): its settings, inference and model folder.

:class:`TrainConfig` holds the architecture and training settings;
:class:`LearnedModel` the trained networks (one per force component), their
scalers and calibrated Monte-Carlo dropout intervals, with batch and streaming
inference in numba.  :func:`drivesense.learn.train.train_model` builds one.

A trained model is a folder: ``config.json`` (architecture, scalers, interval
calibration, training history) and one ``weights_{x,y,z}.pt`` per network
(``state_dict``, loaded with ``weights_only=True``); the format is
:data:`MODEL_FORMAT`, and folders of the first format still load.

A model works at one sample rate (its training runs' own, unless set): every
length in its settings is resolved to samples at that rate when it is trained
(:meth:`TrainConfig.at_rate`).  Its networks are primed on a trace's first
input (``TrainConfig.warmup_s``), so an estimate has no start transient.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from drivesense.errors import ConfigError
from drivesense.estimate.model_based import ModelBased
from drivesense.learn.features import (INPUT_CHANNELS, TARGET_CHANNELS, Scaler, TargetScaler, position_features,
                                      presliding_features)
from drivesense.learn.kernel import LSTMState, LSTMWeights, run_lstm, skip_to_torch
from drivesense.recording import Recording

__all__ = ["TrainConfig", "LearnedModel", "require_torch", "MODEL_FORMAT", "hybrid_base"]


def require_torch():
    """Import torch or raise a clear error saying how to install it."""
    try:
        import torch
    except ImportError:
        raise ConfigError("the learned methods need PyTorch: pip install torch==2.13.0 (CPU build), "
                          "then pip install 'drivesense[learn]'") from None
    return torch


@dataclass(frozen=True)
class TrainConfig:
    """Architecture and training settings.

    Parameters
    ----------
    hidden : int
        Cells per LSTM layer.
    layers : int
        Stacked layers.
    dropout : float
        Dropout probability between layers [-] (training and Monte-Carlo sampling).
    fs : float, optional
        Sample rate the model works at [Hz] (traces at another rate are
        resampled explicitly).  None (default): the training runs' own rate
        (the highest, if they differ); :func:`~drivesense.learn.train.train_model`
        saves the resolved value.
    window : int, optional
        Training window [samples]; None (default): ``window_s`` at the model's rate.
    burn_in : int, optional
        Leading samples of a window excluded from the loss (the network warms
        up over them from a zero state); None (default): ``burn_in_s`` at the
        model's rate.
    batch : int
        Windows per batch.
    windows_per_epoch : int, optional
        Training windows drawn per epoch; None (default): about four passes
        over the training samples, between 256 and 4096 windows (one or two
        50 Hz cuts: 256; the built dataset: 4096).
    epochs : int
        Maximum epochs.
    patience : int
        Epochs without validation improvement before stopping.
    lr : float
        Adam learning rate [-] (the loss is on scaled forces).
    seed : int
        Seed of everything random.
    mc_samples : int
        Monte-Carlo dropout samples for intervals.
    coverage : float
        Nominal coverage of the intervals [-] (e.g. 0.95).
    position_harmonics : int
        Beyond the paper: sine and cosine of this many harmonics of the pole
        pitch of each axis position are added to the inputs (cogging is
        periodic in the position); 0 gives the paper's 14 inputs.
    pole_pitch : float
        Pole pitch of the linear motors [m] (catalogue value).
    linear_skip : bool
        Beyond the paper: a linear path from the inputs straight to the output
        beside the LSTM (the network learns what a linear map of the inputs
        cannot: friction, reversals, history); False gives the paper's network.
    skip_taps : int, optional
        Samples the linear skip looks back over: a causal FIR filter of the
        inputs (and, in a hybrid, of the model's estimate), which can undo
        the small lags and roll-offs a sample-by-sample map leaves; 1 is an
        instantaneous map.  None (default): 16 ms for an LSTM, 32 ms for a
        hybrid at the model's rate, at least one tap (4 and 8 taps at 250 Hz,
        each the better on the validation runs of the built dataset).
    skip_lr_factor : float
        Learning rate of the skip (already at its least-squares optimum) relative
        to ``lr`` [-]: small values keep the LSTM from trading the linear fit away early.
    presliding_length : float
        Beyond the paper: the Dahl presliding state of each axis, computed
        from its position over this distance [m] (a nominal guide value, not an
        identified one), is added to the inputs: it turns over within a few
        micrometres at a reversal, faster than 250 Hz velocity can show;
        0 leaves it out.
    lr_decay : float
        Factor [-] on the learning rate after ``lr_patience`` epochs without a
        validation improvement (1 keeps it constant).
    lr_patience : int
        Epochs without improvement before the learning rate is decayed.
    grad_clip : float
        Largest gradient norm per step [-] (0: no clipping).
    window_s : float
        Training window [s] where ``window`` is None (1 s: 250 samples at 250 Hz).
    burn_in_s : float
        Burn-in [s] where ``burn_in`` is None (0.2 s: 50 samples at 250 Hz).
    warmup_s : float, optional
        Priming of the networks' states [s]: before the first sample of a trace
        (or of a stream) each network runs this long on the first input held
        constant, so that it starts as if the machine had rested in that state
        instead of from a zero state (which gave start transients many times the
        force's range).  None (default): the burn-in's length, over which training
        teaches the networks to settle from a zero state; 0: no priming.
    val_fraction : float
        Share of each training run held out for validation [-] when no run has
        ``meta["split"] == "val"`` (one or two files): the time split of
        :func:`~drivesense.learn.train.train_model`.
    """

    hidden: int = 20
    layers: int = 3
    dropout: float = 0.1
    fs: float | None = None
    window: int | None = None
    burn_in: int | None = None
    batch: int = 128
    windows_per_epoch: int | None = None
    epochs: int = 100
    patience: int = 12
    lr: float = 1e-3
    seed: int = 0
    mc_samples: int = 16
    coverage: float = 0.9
    position_harmonics: int = 3
    pole_pitch: float = 0.023
    linear_skip: bool = True
    skip_taps: int | None = None
    skip_lr_factor: float = 0.1
    presliding_length: float = 10e-6
    lr_decay: float = 0.5
    lr_patience: int = 3
    grad_clip: float = 1.0
    window_s: float = 1.0
    burn_in_s: float = 0.2
    warmup_s: float | None = None
    val_fraction: float = 0.2

    def __post_init__(self) -> None:
        if self.fs is not None and not (_is_number(self.fs) and self.fs > 0):
            raise ConfigError(f"'fs' must be a sample rate > 0 [Hz] or None (the training runs' rate), "
                              f"got {self.fs!r}")
        for name in ("window", "burn_in"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < (2 if name == "window" else 0)):
                raise ConfigError(f"'{name}' must be an integer number of samples (or None: '{name}_s' at the "
                                  f"model's rate), got {v!r}")
        if self.window is not None and self.burn_in is not None and self.burn_in >= self.window:
            raise ConfigError(f"'burn_in' ({self.burn_in}) must be shorter than 'window' ({self.window}) [samples]")
        if not (_is_number(self.window_s) and self.window_s > 0):
            raise ConfigError(f"'window_s' must be a duration > 0 [s], got {self.window_s!r}")
        if not (_is_number(self.burn_in_s) and 0 <= self.burn_in_s < self.window_s):
            raise ConfigError(f"'burn_in_s' must be a duration >= 0 [s] shorter than 'window_s', got {self.burn_in_s!r}")
        if self.warmup_s is not None and not (_is_number(self.warmup_s) and self.warmup_s >= 0):
            raise ConfigError(f"'warmup_s' must be a duration >= 0 [s] or None (the burn-in), got {self.warmup_s!r}")
        if not (_is_number(self.val_fraction) and 0 < self.val_fraction <= 0.5):
            raise ConfigError(f"'val_fraction' must be in (0, 0.5], got {self.val_fraction!r}")
        if isinstance(self.epochs, bool) or not isinstance(self.epochs, int) or self.epochs < 1:
            raise ConfigError(f"'epochs' must be an integer >= 1 (0 saves an untrained model), got {self.epochs!r}")
        if isinstance(self.position_harmonics, bool) or not isinstance(self.position_harmonics, int) \
                or not 0 <= self.position_harmonics <= 8:
            raise ConfigError(f"'position_harmonics' must be an integer in 0..8, got {self.position_harmonics!r}")
        if self.skip_taps is not None and (isinstance(self.skip_taps, bool) or not isinstance(self.skip_taps, int)
                                           or not 1 <= self.skip_taps <= 64):
            raise ConfigError(f"'skip_taps' must be an integer in 1..64, got {self.skip_taps!r}")
        if not (isinstance(self.pole_pitch, (int, float)) and self.pole_pitch > 0):
            raise ConfigError(f"'pole_pitch' must be a length > 0 [m], got {self.pole_pitch!r}")
        if not (isinstance(self.presliding_length, (int, float)) and self.presliding_length >= 0):
            raise ConfigError(f"'presliding_length' must be a length >= 0 [m], got {self.presliding_length!r}")
        if not 0 <= self.skip_lr_factor <= 1:
            raise ConfigError(f"'skip_lr_factor' must be in [0, 1], got {self.skip_lr_factor!r}")
        if not 0 < self.lr_decay <= 1:
            raise ConfigError(f"'lr_decay' must be in (0, 1], got {self.lr_decay!r}")
        if self.grad_clip < 0:
            raise ConfigError(f"'grad_clip' must be >= 0 (0: no clipping), got {self.grad_clip!r}")

    def at_rate(self, fs: float, kind: str = "lstm") -> "TrainConfig":
        """The settings with everything given in seconds resolved to samples at ``fs`` [Hz].

        ``fs`` (if open), ``window``, ``burn_in`` and ``skip_taps`` are filled
        in: 1 s and 0.2 s of samples, and a skip over 16 ms (LSTM) or 32 ms
        (hybrid), at least one tap; at 250 Hz 250, 50, 4 and 8 samples.

        Parameters
        ----------
        fs : float
            The model's sample rate [Hz] (ignored when ``fs`` is already set).
        kind : {"lstm", "hybrid"}
            Which default skip length applies.

        Returns
        -------
        TrainConfig
        """
        fs = float(self.fs if self.fs is not None else fs)
        window = self.window if self.window is not None else max(2, int(round(self.window_s * fs)))
        burn_in = self.burn_in if self.burn_in is not None else int(round(self.burn_in_s * fs))
        if burn_in >= window:
            raise ConfigError(f"the burn-in ({burn_in} samples) must be shorter than the window ({window} samples) "
                              f"at {fs:g} Hz")
        taps = self.skip_taps if self.skip_taps is not None else max(1, int(round(_DEFAULT_SKIP_S[kind] * fs)))
        return replace(self, fs=fs, window=window, burn_in=burn_in, skip_taps=min(taps, 64))

    def warmup_steps(self, fs: float) -> int:
        """Steps the networks are primed over at ``fs`` [Hz] (see ``warmup_s``).

        Parameters
        ----------
        fs : float
            Sample rate [Hz] (the model's; used when the settings leave it open).

        Returns
        -------
        int
        """
        fs = float(self.fs if self.fs is not None else fs)
        if self.warmup_s is not None:
            return int(round(self.warmup_s * fs))
        return self.burn_in if self.burn_in is not None else int(round(self.burn_in_s * fs))


def _is_number(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and np.isfinite(v)


#: Span of the linear skip where the settings leave ``skip_taps`` open [s] (4 and 8 taps at 250 Hz, each the
#: better on the built dataset's validation runs)
_DEFAULT_SKIP_S = {"lstm": 0.016, "hybrid": 0.032}

#: Format of a saved model folder: 2 added the settings in seconds (``window_s``, ``burn_in_s``, ``warmup_s``,
#: ``val_fraction``) and the input scaler's plausible limits; folders of format 1 load as they were (no
#: clipping), primed on their burn-in.
MODEL_FORMAT = "drivesense-learned-2"
_READABLE_FORMATS = ("drivesense-learned-1", MODEL_FORMAT)

_POOL = None
#: Shortest input for which the three networks run side by side on the thread pool; shorter ones (stream
#: chunks) run one after the other: below ~250 samples the pool costs more than it saves (measured).  A count of
#: kernel steps, not a duration: a step costs the same at any trace rate.
_PARALLEL_MIN_SAMPLES = 256


def _pool():
    """The thread pool the networks run on (created once: starting threads per trace costs more than a short trace)."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=len(TARGET_CHANNELS), thread_name_prefix="drivesense-lstm")
    return _POOL


@dataclass
class LearnedModel:
    """A trained reconstruction (see module docstring for the folder format).

    Attributes
    ----------
    kind : str
        ``"lstm"`` or ``"hybrid"``.
    config : TrainConfig
        Settings it was trained with.
    input_scaler : Scaler
        Input scaling.
    target_scalers : dict of str to TargetScaler
        Eq. 17 per force channel.
    weights : dict of str to LSTMWeights
        Network per force channel.
    force_scale : dict of str to float
        Largest absolute training force per channel [N] (scales a hybrid's model input).
    interval_scale : dict of str to float
        Calibrated multiplier of the Monte-Carlo spread per channel [-].
    history : dict
        Training record (losses, epochs, seconds).
    model_based : object, optional
        The :class:`~drivesense.machine.linear_motor.ThreeAxisModel` of a hybrid.
    """

    kind: str
    config: TrainConfig
    input_scaler: Scaler
    target_scalers: dict
    weights: dict
    force_scale: dict = field(default_factory=dict)
    interval_scale: dict = field(default_factory=dict)
    history: dict = field(default_factory=dict)
    model_based: object = None

    # ------------------------------------------------------------- features
    def scaled_inputs(self, arrays, state: dict | None = None) -> np.ndarray:
        """Network inputs shared by the three networks from ``{channel: samples}`` (SI): scaled NC
        inputs, the pole-pitch harmonics of the positions, then their presliding states (float32).

        ``state`` carries the presliding states between stream chunks (updated
        in place; None: a fresh start).

        Parameters
        ----------
        arrays : mapping of str to array_like
            ``{channel: samples}`` [SI unit of each channel], at least
            :data:`~drivesense.learn.features.INPUT_CHANNELS`.
        state : dict, optional
            ``{axis index: (last position [m], state [-])}``, updated in place.

        Returns
        -------
        ndarray, shape (n_samples, n_inputs)
        """
        x = self.input_scaler.transform(np.column_stack([np.asarray(arrays[c], float) for c in INPUT_CHANNELS]))
        pos = [arrays[f"{ax}_position"] for ax in ("x", "y", "z")]
        k = self.config.position_harmonics
        if k:
            x = np.hstack([x, position_features(pos, self.config.pole_pitch, k)])
        if self.config.presliding_length > 0:
            x = np.hstack([x, presliding_features(pos, self.config.presliding_length, state)])
        return x

    def inputs(self, recording: Recording) -> tuple[np.ndarray, dict]:
        """Scaled network inputs of a whole trace and the model part of each output [N] (zeros for a plain LSTM).

        Parameters
        ----------
        recording : Recording
            A trace holding the NC input channels.

        Returns
        -------
        x : ndarray
            Scaled inputs [-].
        base : dict of str to ndarray
            Model part of each force channel [N].
        """
        recording.require(*INPUT_CHANNELS)
        return self.features({c: recording[c] for c in recording.channels}, {}, {})

    def features(self, arrays, input_state: dict, model_state: dict) -> tuple[np.ndarray, dict]:
        """Scaled inputs and the model part of each output [N] for the next samples, carrying both states.

        Parameters
        ----------
        arrays : mapping of str to array_like
            ``{channel: samples}`` [SI unit of each channel].
        input_state : dict
            Presliding states of the inputs (:meth:`scaled_inputs`), updated in place.
        model_state : dict
            The hybrid's model state (:meth:`ModelBased.process`), updated in place.

        Returns
        -------
        x : ndarray
            Scaled inputs [-].
        base : dict of str to ndarray
            Model part of each force channel [N] (zeros for a plain LSTM).
        """
        x = self.scaled_inputs(arrays, input_state)
        if self.kind == "hybrid":
            return x, hybrid_base(self.model_based).process(model_state, arrays)
        return x, {ch: np.zeros(len(x)) for ch in TARGET_CHANNELS}

    def network_input(self, x: np.ndarray, base: np.ndarray, channel: str) -> np.ndarray:
        """Inputs of ``channel``'s network: the NC inputs, plus the scaled model estimate for a hybrid.

        Parameters
        ----------
        x : ndarray, shape (n_samples, n_inputs)
            Scaled NC inputs [-] (:meth:`scaled_inputs`).
        base : ndarray
            Model estimate of the force [N] (ignored for a plain LSTM).
        channel : str
            Force channel (``force_x``...).

        Returns
        -------
        ndarray
        """
        if self.kind != "hybrid":
            return x
        return np.column_stack([x, base / self.force_scale[channel]]).astype(np.float32)

    @property
    def fs(self) -> float | None:
        """Sample rate the model works at [Hz] (None: not fixed, for a model built by hand)."""
        return self.config.fs

    def new_state(self, fs: float | None = None) -> dict:
        """A fresh carried state: each network's hidden/cell state, the presliding states of the inputs
        and (hybrid) of the model part; constant size.

        Each network is primed on its first input (``TrainConfig.warmup_s``)
        when the first samples arrive, in batch and stream alike.

        Parameters
        ----------
        fs : float, optional
            Rate of the signals [Hz] (default: the model's); sets the priming's
            length in steps when the model's rate is not fixed.
        """
        fs = self.config.fs if fs is None else fs
        steps = self.config.warmup_steps(fs) if fs is not None else 0
        return {"networks": {ch: LSTMState(w, warmup=steps) for ch, w in self.weights.items()}, "inputs": {},
                "model": {}}

    def forward(self, state: dict, arrays, *, network_inputs: dict | None = None) -> dict[str, np.ndarray]:
        """Force per channel [N] for the next samples of ``{channel: samples}`` (SI), carrying ``state``.

        Batch prediction is one call from :meth:`new_state`; streaming is one
        call per chunk: the same numbers.  ``network_inputs``, if given, is
        filled with each network's input matrix (for the intervals).

        Parameters
        ----------
        state : dict
            From :meth:`new_state`; updated in place.
        arrays : mapping of str to array_like
            ``{channel: samples}`` [SI unit of each channel].
        network_inputs : dict, optional
            Filled with ``{force channel: input matrix}``.

        Returns
        -------
        dict of str to ndarray
            Force per channel [N].
        """
        x_all, bases = self.features(arrays, state["inputs"], state["model"])
        n = len(x_all)
        inputs = {ch: self.network_input(x_all, bases[ch], ch) for ch in TARGET_CHANNELS}
        if network_inputs is not None:
            network_inputs.update(inputs)
        nets = state["networks"]
        if n >= _PARALLEL_MIN_SAMPLES:
            # the compiled kernel releases the GIL: the three networks run side by side on a kept pool
            raw = dict(zip(TARGET_CHANNELS, _pool().map(
                lambda ch: run_lstm(self.weights[ch], nets[ch], inputs[ch]), TARGET_CHANNELS)))
        else:
            raw = {ch: run_lstm(self.weights[ch], nets[ch], inputs[ch]) for ch in TARGET_CHANNELS}
        return {ch: bases[ch] + self.target_scalers[ch].inverse(raw[ch]) for ch in TARGET_CHANNELS}

    def predict(self, recording: Recording, *, intervals: bool = False) -> dict[str, np.ndarray]:
        """Force per channel [N] over a whole trace; with ``intervals``, also ``{ch}_lower`` / ``{ch}_upper``.

        Parameters
        ----------
        recording : Recording
            A trace holding the NC input channels.
        intervals : bool, optional
            Add Monte-Carlo dropout intervals.

        Returns
        -------
        dict of str to ndarray
        """
        recording.require(*INPUT_CHANNELS)
        inputs: dict = {}
        out = self.forward(self.new_state(recording.fs), {c: recording[c] for c in recording.channels},
                           network_inputs=inputs if intervals else None)
        if intervals:
            for ch in TARGET_CHANNELS:
                half = self.interval_scale[ch] * self.interval_spread(ch, inputs[ch], fs=recording.fs)
                out[f"{ch}_lower"], out[f"{ch}_upper"] = out[ch] - half, out[ch] + half
        return out

    def interval_spread(self, channel: str, x: np.ndarray, *, fs: float | None = None) -> np.ndarray:
        """Uncalibrated half-width of ``channel``'s prediction interval [N]: twice the Monte-Carlo
        dropout spread plus a floor of 0.1 % of the force scale (:attr:`interval_scale` calibrates it).

        Parameters
        ----------
        channel : str
            Force channel (``force_x``...).
        x : ndarray, shape (n_samples, n_inputs)
            The network's input matrix [-] (:meth:`network_input`).
        fs : float, optional
            Rate of the samples [Hz] (default: the model's), for the priming.

        Returns
        -------
        ndarray
            Half-width per sample [N].
        """
        ts = self.target_scalers[channel]
        fs = self.config.fs if fs is None else fs
        steps = self.config.warmup_steps(fs) if fs is not None else 0
        spread = _mc_spread(self.weights[channel], x, self.config.mc_samples, self.config.seed, steps)
        return spread * 2.0 * ts.f_max + 1e-3 * ts.f_max

    # ---------------------------------------------------------- persistence
    def save(self, folder) -> Path:
        """Write the model folder (config.json + weights_*.pt).

        Parameters
        ----------
        folder : str or Path
            Created if needed.

        Returns
        -------
        Path
        """
        torch = require_torch()
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for ch in TARGET_CHANNELS:
            w = self.weights[ch]
            torch.save(_to_state_dict(w, torch), folder / f"weights_{ch[-1]}.pt")
        cfg = {"format": MODEL_FORMAT, "kind": self.kind, "config": asdict(self.config),
               "inputs": list(INPUT_CHANNELS), "targets": list(TARGET_CHANNELS),
               "input_scaler": self.input_scaler.to_dict(),
               "target_scalers": {k: v.f_max for k, v in self.target_scalers.items()},
               "force_scale": self.force_scale, "interval_scale": self.interval_scale, "history": self.history}
        if self.model_based is not None:
            from drivesense.io.axes_file import write_axes_file

            write_axes_file(folder / "model_based.toml", self.model_based)
            cfg["model_based"] = "model_based.toml"
        tmp = folder / ".config.json.tmp"
        tmp.write_text(json.dumps(cfg, indent=1), encoding="utf-8")
        tmp.replace(folder / "config.json")
        return folder

    @classmethod
    def load(cls, folder) -> "LearnedModel":
        """Read a model folder written by :meth:`save` (``torch.load(weights_only=True)``).

        Parameters
        ----------
        folder : str or Path
            A folder written by :meth:`save`.

        Returns
        -------
        LearnedModel
        """
        torch = require_torch()
        folder = Path(folder)
        path = folder / "config.json"
        if not path.is_file():
            raise FileNotFoundError(f"'{folder}' is not a drivesense model folder (no config.json)")
        cfg = json.loads(path.read_text(encoding="utf-8"))
        if cfg.get("format") not in _READABLE_FORMATS:
            raise ConfigError(f"'{path}': unknown model format {cfg.get('format')!r} (this drivesense reads "
                              f"{', '.join(_READABLE_FORMATS)}; a newer drivesense wrote it?)")
        settings = dict(cfg["config"])
        settings.setdefault("position_harmonics", 0)     # models saved before these had the paper's network
        settings.setdefault("linear_skip", False)
        settings.setdefault("presliding_length", 0.0)
        settings.setdefault("skip_taps", 1)
        try:
            config = TrainConfig(**settings)
        except TypeError as exc:
            raise ConfigError(f"'{path}': bad training config: {exc}") from None
        weights = {}
        for ch in TARGET_CHANNELS:
            state = torch.load(folder / f"weights_{ch[-1]}.pt", weights_only=True)
            weights[ch] = LSTMWeights.from_state_dict(state, config.layers, config.dropout)
        model_based = None
        if "model_based" in cfg:
            from drivesense.io.axes_file import read_axes_file

            model_based = read_axes_file(folder / cfg["model_based"])
        return cls(cfg["kind"], config, Scaler.from_dict(cfg["input_scaler"]),
                   {k: TargetScaler(v) for k, v in cfg["target_scalers"].items()}, weights,
                   cfg.get("force_scale", {}), cfg.get("interval_scale", {}), cfg.get("history", {}), model_based)


def hybrid_base(model_based) -> ModelBased:
    """The estimate a hybrid corrects: the model, with the regression ``identify nc`` chose on an axis where the
    physics lost or could not be identified (``--per-axis auto``).

    Parameters
    ----------
    model_based : ThreeAxisModel or ControllerModel
        The identified axes.
    """
    from drivesense.machine.controller_model import ControllerModel

    if isinstance(model_based, ControllerModel) and model_based.regression is not None and model_based.choice:
        return ModelBased(model_based, per_axis="auto")
    return ModelBased(model_based)


def _to_state_dict(w: LSTMWeights, torch) -> dict:
    state = {}
    for k in range(w.layers):
        n_in = int(w.in_dims[k])
        state[f"lstm.weight_ih_l{k}"] = torch.from_numpy(w.w_ih[k, :, :n_in].copy())
        state[f"lstm.weight_hh_l{k}"] = torch.from_numpy(w.w_hh[k].copy())
        state[f"lstm.bias_ih_l{k}"] = torch.from_numpy(w.bias[k].copy())
        state[f"lstm.bias_hh_l{k}"] = torch.zeros(w.bias.shape[1], dtype=torch.float64)
    state["head.weight"] = torch.from_numpy(w.head_w[None, :].copy())
    state["head.bias"] = torch.tensor([w.head_b], dtype=torch.float64)
    if w.skip_w is not None:
        state["skip.weight"] = torch.from_numpy(skip_to_torch(w.skip_w))
    return state


def _mc_spread(w: LSTMWeights, x: np.ndarray, samples: int, seed: int, warmup: int = 0) -> np.ndarray:
    draws = np.stack([run_lstm(w, LSTMState(w, warmup=warmup), x, seed=seed + 1 + k) for k in range(samples)])
    return draws.std(axis=0)
