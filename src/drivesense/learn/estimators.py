"""Learned force reconstruction under the common estimator contract (third paper, Sec. 2.3).

::

    est = ds.estimate.make("lstm", model="model_dir")   # or LSTM().fit(training_runs)
    forces = est.estimate(nc_trace)                      # force_x/y/z [N] (+ intervals on request)
    stream = est.stream(250.0); stream.push(chunk)       # hidden states carried: the same numbers

Training needs PyTorch; inference runs in numba (:mod:`drivesense.learn.kernel`).

A model works at its training rate.  ``estimate`` resamples a trace at another
rate to it (polyphase, noted in the provenance) and the forces back onto the
trace's own time base, so an estimate can be scored against the trace's
reference; a stream at another rate is refused.  The networks are primed on
the first input (no start transient), in batch and stream alike.  Inputs
outside the plausible range of the training data are clipped, with an
:class:`~drivesense.learn.features.InputRangeWarning` per trace.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import ConfigError, NotFittedError
from drivesense.estimate.base import ForceEstimator, declared_delay, read_inputs, wrap_forces
from drivesense.learn.features import INPUT_CHANNELS, TARGET_CHANNELS, InputRangeWarning, resample_onto, resample_to
from drivesense.learn.model import LearnedModel
from drivesense.learn.train import train_model
from drivesense.recording import Recording

__all__ = ["LSTM", "Hybrid"]


class LSTM(ForceEstimator):
    """One LSTM per force component, trained on reference forces.

    Parameters
    ----------
    model : LearnedModel, optional
        A trained model (None until :meth:`fit` or :meth:`load`).
    config : TrainConfig, optional
        Training settings used by :meth:`fit`.
    """

    name = "lstm"
    drive = "linear"
    #: Kind of :class:`~drivesense.learn.model.LearnedModel` this method runs.
    kind = "lstm"

    def __init__(self, model: LearnedModel | None = None, *, config=None) -> None:
        if model is not None and getattr(model, "kind", None) != self.kind:
            raise ConfigError(f"{type(self).__name__} needs a {self.kind!r} model, got "
                              f"{getattr(model, 'kind', type(model).__name__)!r}")
        self.model = model
        self.config = config

    @classmethod
    def load(cls, folder) -> "LSTM":
        """Load a model folder written by :meth:`save` (needs PyTorch for ``torch.load``).

        Parameters
        ----------
        folder : str or Path
            The model folder (``config.json`` + ``weights_*.pt``).
        """
        model = LearnedModel.load(folder)
        if model.kind != cls.kind:
            raise ConfigError(f"'{folder}' holds a {model.kind!r} model, not {cls.kind!r}")
        return cls(model)

    def save(self, folder):
        """Write the model folder (``config.json`` + ``weights_*.pt``).

        Parameters
        ----------
        folder : str or Path
            Where to write it.
        """
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

        Returns
        -------
        self
        """
        self.model = train_model(self.kind, runs, config=self.config, progress=progress, **kwargs)
        return self

    def _require(self) -> LearnedModel:
        if self.model is None:
            raise NotFittedError(f"{type(self).__name__} has no trained model: train it (drivesense train "
                                 f"{self.kind}) and give its folder (--model DIR)")
        return self.model

    @property
    def fs(self) -> float | None:
        """Sample rate the model works at [Hz] (None: any, for a model built by hand without one)."""
        return self._require().config.fs

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The 14 NC input channels (positions, velocities, accelerations, currents, spindle)."""
        return INPUT_CHANNELS

    @property
    def output_channels(self) -> tuple[str, ...]:
        """``force_x``, ``force_y``, ``force_z``."""
        return TARGET_CHANNELS

    def latency_s(self, fs: float) -> float:
        """None of its own: 0 s (the networks are trained on the force delayed by the trace's declared delay).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return 0.0

    def prepare(self, recording: Recording) -> Recording:
        """The trace resampled explicitly to the model's rate, if needed (noted in the provenance).

        Parameters
        ----------
        recording : Recording
            The trace.
        """
        fs = self._require().config.fs
        if fs is None or abs(recording.fs - fs) < 1e-9 * fs:
            return recording
        recording.require(*INPUT_CHANNELS)      # before resampling a trace that could not be estimated
        return resample_to(recording, fs)

    def check_trace(self, recording: Recording) -> None:
        """Warn (:class:`~drivesense.learn.features.InputRangeWarning`) about inputs outside the plausible
        range of the training data, naming each channel and its count: they are clipped.

        Parameters
        ----------
        recording : Recording
            The trace (at the model's rate).
        """
        self._warn_outside(recording, {c: recording[c] for c in INPUT_CHANNELS})

    def _warn_outside(self, recording: Recording, arrays: Mapping[str, np.ndarray]) -> None:
        counts = self._require().input_scaler.outside(np.column_stack([arrays[c] for c in INPUT_CHANNELS]))
        if counts.any():
            listed = ", ".join(f"'{c}': {int(n)}" for c, n in zip(INPUT_CHANNELS, counts) if n)
            warnings.warn(f"trace '{recording.meta.get('name', 'trace')}': input samples outside the plausible range "
                          f"of the training data, clipped ({listed})", InputRangeWarning, stacklevel=3)

    def new_state(self, fs: float) -> dict:
        """Hidden and cell states of the three networks (and presliding states), fresh.

        Parameters
        ----------
        fs : float
            Sample rate [Hz]; must be the model's.
        """
        model = self._require()
        if model.config.fs is not None and abs(fs - model.config.fs) > 1e-9 * fs:
            raise ConfigError(f"the model works at {model.config.fs:g} Hz; resample the {fs:g} Hz signals "
                              f"first (--resample {model.config.fs:g})")
        return model.new_state(fs)

    def process(self, state: dict, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``{force_ax: F}`` [N] for the next samples, carrying ``state``.

        Parameters
        ----------
        state : dict
            From :meth:`new_state`.
        arrays : mapping of str to ndarray
            The input channels (:attr:`channel_names`) [SI unit of each channel].
        """
        return self._require().forward(state, arrays)

    def describe(self) -> str:
        """The network, for the provenance."""
        cfg = self._require().config
        rate = "the trace's rate" if cfg.fs is None else f"{cfg.fs:g} Hz"
        return f"{self.kind} {cfg.layers}x{cfg.hidden} cells per force component at {rate}"

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
            ``force_x``, ``force_y``, ``force_z`` [N] on the trace's own time
            base (resampled back from the model's rate if the trace was
            resampled); ``meta["latency_s"]`` is the trace's declared NC delay
            (the networks are trained on the force delayed by it: a causal
            method cannot undo it).
        """
        if not isinstance(recording, Recording):
            return super().estimate(recording)          # the shared refusal
        model = self._require()
        rec = self.prepare(recording)
        arrays = read_inputs(rec, self.channel_names)
        self._warn_outside(rec, arrays)
        if intervals:
            forces = model.predict(rec, intervals=True)
        else:
            forces = self.process(self.new_state(rec.fs), arrays)
        out = wrap_forces(self, rec, forces, declared_delay(rec))
        if rec is not recording:
            out = resample_onto(out, recording)       # back on the trace's time base (provenance says so)
        return out.with_meta(interval_coverage=model.config.coverage) if intervals else out

    def __repr__(self) -> str:
        return f"{type(self).__name__}(trained={self.model is not None})"


class Hybrid(LSTM):
    """``ModelBased`` (Eq. 2 with identified axes) plus one LSTM per component on its residual.

    The networks see the NC inputs and the model's own estimate, and learn what
    the model gets wrong (micro friction at reversals, the accelerated axis,
    cogging it leaves over).  ``fit`` needs the identified axes:
    ``Hybrid().fit(runs, model_based=identified_axes)``.

    Parameters
    ----------
    model : LearnedModel, optional
        A trained hybrid model (None until :meth:`fit` or :meth:`load`).
    config : TrainConfig, optional
        Training settings used by :meth:`fit`.
    """

    name = "hybrid"
    kind = "hybrid"
