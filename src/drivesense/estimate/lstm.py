"""Learned force reconstruction under the common estimator protocol (third paper, Sec. 2.3).

::

    est = ds.estimate.LSTM.load("model_dir")      # or LSTM().fit(training_runs)
    forces = est.estimate(nc_trace)                # force_x/y/z [N] (+ intervals on request)
    state = est.stream(); state.push(chunk)        # hidden states carried: the same numbers

Training needs PyTorch; inference runs in numba (:mod:`drivesense.learn.kernel`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import ConfigError, MissingChannelError, NotFittedError
from drivesense.learn.features import INPUT_CHANNELS, TARGET_CHANNELS, resample_to
from drivesense.learn.kernel import LSTMState, run_lstm
from drivesense.recording import Recording

__all__ = ["LSTM", "LearnedStream"]


class LSTM:
    """One LSTM per force component, trained on reference forces.

    Parameters
    ----------
    model : LearnedModel, optional
        A trained model (None until :meth:`fit` or :meth:`load`).
    config : TrainConfig, optional
        Training settings used by :meth:`fit`.
    """

    #: Short name used by the CLI and the benchmarks.
    name = "lstm"
    kind = "lstm"

    def __init__(self, model=None, *, config=None) -> None:
        self.model = model
        self.config = config

    @classmethod
    def load(cls, folder) -> "LSTM":
        """Load a model folder written by :meth:`save` (needs PyTorch for ``torch.load``)."""
        from drivesense.learn.train import LearnedModel

        model = LearnedModel.load(folder)
        if model.kind != cls.kind:
            raise ConfigError(f"'{folder}' holds a {model.kind!r} model, not {cls.kind!r}")
        return cls(model)

    def save(self, folder):
        """Write the model folder (``config.json`` + ``weights_*.pt``)."""
        return self._require().save(folder)

    def fit(self, runs: Sequence[Recording], *, progress=None, **kwargs) -> "LSTM":
        """Train on ``runs`` (``meta["split"]`` ``train`` / ``val``); see :func:`drivesense.learn.train.train_model`.

        Parameters
        ----------
        runs : sequence of Recording
            Traces with the NC inputs and reference ``force_{x,y,z}``.
        progress : callable, optional
            Called with a status line per epoch.
        **kwargs
            Passed to ``train_model`` (e.g. ``model_based`` for a hybrid).
        """
        from drivesense.learn.train import train_model

        self.model = train_model(self.kind, runs, config=self.config, progress=progress, **kwargs)
        return self

    def _require(self):
        if self.model is None:
            raise NotFittedError(f"{type(self).__name__} has no trained model: fit() or load() it first")
        return self.model

    @property
    def fs(self) -> float:
        """Sample rate the model works at [Hz]."""
        return self._require().config.fs

    def estimate(self, recording: Recording, *, intervals: bool = False) -> Recording:
        """Reconstruct the process force.

        Parameters
        ----------
        recording : Recording
            NC trace with the 14 input channels (resampled explicitly to the
            model's rate if needed, noted in the provenance).
        intervals : bool
            Also return ``force_{ax}_lower`` / ``_upper``: the calibrated
            prediction interval (Monte-Carlo dropout) [N].

        Returns
        -------
        Recording
            ``force_x``, ``force_y``, ``force_z`` [N]; ``meta["latency_s"]`` is the
            trace's declared NC delay (the networks are trained on the force
            delayed by it: a causal method cannot undo it).
        """
        model = self._require()
        recording.require(*INPUT_CHANNELS)
        rec = resample_to(recording, model.config.fs)
        out = model.predict(rec, intervals=intervals)
        name = rec.meta.get("name", "trace")
        latency = float(rec.meta.get("nc_delay_s", 0.0))
        meta = {"name": f"{name}:{self.name}", "method": self.name, "latency_s": latency, "source": name,
                "provenance": list(rec.meta.get("provenance", [])) + [f"estimate {self.name}"]}
        if intervals:
            meta["interval_coverage"] = model.config.coverage
        return Recording._from_trusted(out, {k: "N" for k in out}, fs=rec.fs, t0=rec.t0, meta=meta)

    def stream(self, fs: float | None = None, *, latency_s: float = 0.0) -> "LearnedStream":
        """Chunk-by-chunk reconstruction at the model's rate.

        Parameters
        ----------
        fs : float, optional
            Rate of the incoming chunks [Hz]; must equal the model's if given.
        latency_s : float
            Delay the incoming signals carry [s] (reported as the latency).
        """
        model = self._require()
        if fs is not None and abs(fs - model.config.fs) > 1e-9 * fs:
            raise ConfigError(f"the model works at {model.config.fs:g} Hz; a {fs:g} Hz stream must be resampled first")
        return LearnedStream(model, latency_s)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(trained={self.model is not None})"


class LearnedStream:
    """Streaming state of a learned estimator: one hidden/cell state per network.

    Parameters
    ----------
    model : LearnedModel
        The trained model.
    latency_s : float
        Declared latency of the estimate [s].
    """

    def __init__(self, model, latency_s: float = 0.0) -> None:
        self.model = model
        self.latency_s = float(latency_s)
        self.states = {ch: LSTMState(w) for ch, w in model.weights.items()}
        self.base_state: dict = {}     # the hybrid's ModelBased presliding state
        self.input_state: dict = {}    # the presliding states among the inputs

    def push(self, chunk: Recording | Mapping[str, np.ndarray]):
        """Process the next samples; returns a dict of force arrays [N] (a Recording for a Recording)."""
        if isinstance(chunk, Recording):
            chunk.require(*INPUT_CHANNELS)
            arrays = {c: chunk[c] for c in chunk.channels}
        else:
            missing = [c for c in INPUT_CHANNELS if c not in chunk]
            if missing:
                raise MissingChannelError(f"stream chunk lacks channel(s) {', '.join(missing)}")
            arrays = chunk
        n = len(arrays[INPUT_CHANNELS[0]])
        x_all = self.model.scaled_inputs(arrays, self.input_state)
        bases = {ch: np.zeros(n) for ch in TARGET_CHANNELS}
        if self.model.kind == "hybrid":
            from drivesense.estimate.model_based import ModelBased

            bases = ModelBased(self.model.model_based).forces(arrays, self.base_state)
        out = {}
        for ch in TARGET_CHANNELS:
            x = self.model.network_input(x_all, bases[ch], ch)
            out[ch] = bases[ch] + self.model.target_scalers[ch].inverse(run_lstm(self.model.weights[ch],
                                                                                  self.states[ch], x))
        if isinstance(chunk, Recording):
            return Recording.from_arrays(out, fs=chunk.fs, t0=chunk.t0, units={k: "N" for k in out},
                                         meta={"name": f"{chunk.meta.get('name', 'chunk')}:{self.model.kind}",
                                               "latency_s": self.latency_s})
        return out
