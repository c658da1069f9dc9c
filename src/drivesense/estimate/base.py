"""The contract every force estimator follows, whatever its drive type or method.

::

    est = ds.estimate.make("vibration", axis=AXIS, signal=SIGNAL)   # any name in available()
    est.fit(idle_runs)                  # friction map / identification / training (may be a no-op)
    forces = est.estimate(recording)    # Recording with force_{ax} [N], meta["latency_s"]
    stream = est.stream(fs)             # constant-size state; refuses chunks at another rate
    stream.push(chunk)                  # Recording in -> Recording out; mapping in -> dict out

A method implements four things: :attr:`ForceEstimator.channel_names` and
:attr:`~ForceEstimator.output_channels`, :meth:`~ForceEstimator.fit`,
:meth:`~ForceEstimator.latency_s`, and the pair
:meth:`~ForceEstimator.new_state` / :meth:`~ForceEstimator.process` that
turns input arrays into force arrays while carrying a state.  Batch
estimation is one ``process`` call from a fresh state, so batch and
streaming give the same numbers by construction (to the bit where one
compiled kernel serves both).  Input checks and the result wrapper live here
and are shared by every method.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, Callable, ClassVar

import numpy as np
from numba import njit

from drivesense.errors import ConfigError, InvalidSignalError, MissingChannelError
from drivesense.recording import Recording
from drivesense.timebase import check_fs

__all__ = ["ForceEstimator", "ForceStream", "read_inputs", "check_chunk", "declared_delay", "wrap_forces"]

#: Relative tolerance on a chunk's sample rate against its stream's.
RATE_TOLERANCE = 1e-6


def declared_delay(recording: Recording) -> float:
    """The delay a trace declares for its own signals [s] (``meta["nc_delay_s"]``, 0 if absent).

    A logger's anti-alias filter or a controller's trace buffer delays every
    channel alike; no causal method can undo it, so it adds to the latency.

    Parameters
    ----------
    recording : Recording
        The trace.
    """
    delay = recording.meta.get("nc_delay_s", 0.0)
    if isinstance(delay, bool) or not isinstance(delay, (int, float)) or not math.isfinite(delay) or delay < 0:
        raise ConfigError(f"recording meta 'nc_delay_s' must be a delay >= 0 [s], got {delay!r}")
    return float(delay)


def read_inputs(recording: Recording, channels: Sequence[str]) -> dict[str, np.ndarray]:
    """The input arrays of ``channels`` from a Recording (validated on construction: finite, SI).

    Parameters
    ----------
    recording : Recording
        Trace holding every channel.
    channels : sequence of str
        Canonical channel names.

    Raises
    ------
    MissingChannelError
        Naming every missing channel.
    """
    recording.require(*channels)
    return {c: recording[c] for c in channels}


def _bare_names(channels: Sequence[str]) -> dict[str, str]:
    """``{bare: canonical}`` for channels whose axis-less name is unique (``current_ref`` -> ``x_current_ref``)."""
    bare: dict[str, list[str]] = {}
    for c in channels:
        head, _, tail = c.partition("_")
        if tail and len(head) == 1:
            bare.setdefault(tail, []).append(c)
    return {b: cs[0] for b, cs in bare.items() if len(cs) == 1}


def check_chunk(chunk: Mapping[str, Any], channels: Sequence[str], fs: float | None = None,
                stream_fs: float | None = None) -> dict[str, np.ndarray]:
    """Validate a mapping chunk and return float64 arrays of ``channels``.

    Parameters
    ----------
    chunk : mapping of str to array_like
        Channel -> samples (SI).  Canonical names (``x_current_ref``), or the
        bare name (``current_ref``) where it names one input unambiguously.
        An optional ``"time"`` entry [s] is checked against the stream's rate.
    channels : sequence of str
        Inputs the estimator needs.
    fs : float, optional
        Rate the caller says the chunk has [Hz]; checked against ``stream_fs``.
    stream_fs : float, optional
        The stream's rate [Hz].

    Raises
    ------
    MissingChannelError
        Naming every missing channel.
    InvalidSignalError
        A channel that is not 1-D, not finite, or not as long as the others;
        a chunk at another rate than the stream's.
    """
    if not isinstance(chunk, Mapping):
        raise InvalidSignalError(f"push() takes a Recording or a mapping of channel arrays, got "
                                 f"{type(chunk).__name__}")
    if stream_fs is not None:
        if fs is not None:
            _check_rate(float(fs), stream_fs, "the chunk's fs")
        if "time" in chunk:
            t = np.asarray(chunk["time"], dtype=np.float64)
            if t.ndim == 1 and t.size >= 2:
                _check_rate((t.size - 1) / (t[-1] - t[0]) if t[-1] != t[0] else math.inf, stream_fs,
                            "the chunk's 'time'")
    bare = None
    arrays: dict[str, np.ndarray] = {}
    missing = []
    n = None
    for c in channels:
        if c in chunk:
            values = chunk[c]
        else:
            bare = bare if bare is not None else {v: k for k, v in _bare_names(channels).items()}
            alias = bare.get(c)
            if alias is None or alias not in chunk:
                missing.append(c)
                continue
            values = chunk[alias]
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim != 1:
            raise InvalidSignalError(f"stream chunk channel '{c}' must be 1-D, got shape {arr.shape}")
        if n is not None and arr.size != n:
            raise InvalidSignalError(f"stream chunk channel '{c}' has {arr.size} samples, the others {n}")
        bad = _first_non_finite(arr)
        if bad >= 0:
            raise InvalidSignalError(f"stream chunk channel '{c}' holds NaN or inf (sample {bad})")
        arrays[c], n = arr, arr.size
    if missing:
        raise MissingChannelError(f"stream chunk lacks channel(s) {', '.join(repr(m) for m in missing)}")
    return arrays


@njit(cache=True)
def _first_non_finite(arr: np.ndarray) -> int:
    """Index of the first NaN or inf in ``arr``, -1 if none (a compiled loop: chunks are short and many)."""
    for i in range(arr.size):
        if not np.isfinite(arr[i]):
            return i
    return -1


def _check_rate(got: float, want: float, what: str) -> None:
    if not abs(got - want) <= RATE_TOLERANCE * want:
        raise InvalidSignalError(f"{what} is {got:g} Hz but the stream runs at {want:g} Hz: resample the "
                                 f"signals (--resample HZ) or start a stream at {got:g} Hz")


def wrap_forces(estimator: "ForceEstimator", source: Recording, forces: Mapping[str, np.ndarray],
                latency_s: float, *, fs: float | None = None, t0: float | None = None) -> Recording:
    """The result of every estimator: force channels [N] on the source's time base, with provenance.

    Parameters
    ----------
    estimator : ForceEstimator
        The method (its name and :meth:`~ForceEstimator.describe`).
    source : Recording
        The trace the forces were estimated from (name, provenance, time base).
    forces : mapping of str to ndarray
        ``force_{ax}`` [N] and any extra channels (e.g. interval bounds) [N].
    latency_s : float
        Pure delay of the estimate [s].
    fs, t0 : float, optional
        Time base [Hz], [s] when it differs from the source's.

    Returns
    -------
    Recording
        ``meta``: ``name``, ``method``, ``latency_s``, ``source``, ``sign`` and
        ``provenance`` (the source's plus this step).
    """
    source_meta = source.meta          # parsed from JSON on each access: read once
    name = source_meta.get("name", "trace")
    meta = {"name": f"{name}:{estimator.name}", "method": estimator.name, "latency_s": float(latency_s),
            "source": name, "sign": "force on the workpiece (table) along +axis",
            "provenance": list(source_meta.get("provenance", []))
            + [f"estimate {estimator.name}: {estimator.describe()}; latency {latency_s * 1e3:.3f} ms"]}
    # outputs of validated (finite) inputs: no copy, no re-validation on this hot path
    return Recording.from_computed(dict(forces), {k: "N" for k in forces},
                                   fs=source.fs if fs is None else fs, t0=source.t0 if t0 is None else t0,
                                   meta=meta)


class ForceEstimator(ABC):
    """Base of every force estimator (ball screw: current, rigid, medob, vibration; linear motor:
    model, lstm, hybrid).

    Subclasses set :attr:`name` and implement :attr:`channel_names`,
    :attr:`output_channels`, :meth:`fit`, :meth:`latency_s`,
    :meth:`new_state` and :meth:`process`; :meth:`estimate` and
    :meth:`stream` are shared.
    """

    #: Short name used by the registry, the CLI and the benchmarks.
    name: ClassVar[str] = ""
    #: ``"ballscrew"`` or ``"linear"``: the drive type whose signals the method reads.
    drive: ClassVar[str] = ""

    # ------------------------------------------------------------ the contract
    @property
    @abstractmethod
    def channel_names(self) -> tuple[str, ...]:
        """Input channels (canonical names, SI)."""

    @property
    @abstractmethod
    def output_channels(self) -> tuple[str, ...]:
        """Force channels produced (``force_x`` ...) [N]."""

    @abstractmethod
    def fit(self, runs: Sequence[Recording], **kwargs: Any) -> "ForceEstimator":
        """Adapt the method to a machine from runs (friction map, identification, training).

        Parameters
        ----------
        runs : sequence of Recording
            Air cuts / idle runs or training runs, as the method needs.
        **kwargs
            Method-specific settings.

        Returns
        -------
        self
        """

    @abstractmethod
    def latency_s(self, fs: float) -> float:
        """The method's own pure delay at sample rate ``fs`` [s] (a trace's declared delay adds to it).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """

    @abstractmethod
    def new_state(self, fs: float) -> Any:
        """A fresh carried state for signals at ``fs`` [Hz] (constant size); refuses rates it cannot serve.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """

    @abstractmethod
    def process(self, state: Any, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Forces [N] for the next samples, updating ``state`` in place.

        Parameters
        ----------
        state : object
            From :meth:`new_state`.
        arrays : mapping of str to ndarray
            Every input channel [SI unit of the channel], equally long, float64, finite.
        """

    def fast_path(self, state: Any) -> Callable[..., dict[str, np.ndarray]]:
        """A function ``step(*arrays) -> {channel: forces}`` that runs :meth:`process` on ``state`` with the
        inputs given positionally in :attr:`channel_names` order: the stream's unchecked fast path.

        A method may return a leaner function (the ball-screw methods call their kernel directly).

        Parameters
        ----------
        state : object
            From :meth:`new_state`; carried by the function.
        """
        names = self.channel_names
        return lambda *arrays: self.process(state, dict(zip(names, arrays)))

    # ------------------------------------------------------------ shared parts
    def describe(self) -> str:
        """One line for the provenance of an estimate (the method and its compensation)."""
        return type(self).__name__

    def check_trace(self, recording: Recording) -> None:
        """Refuse a whole trace the method cannot estimate (too short, outside a friction map ...).

        Parameters
        ----------
        recording : Recording
            The trace to estimate.
        """

    def prepare(self, recording: Recording) -> Recording:
        """The trace as the method reads it (e.g. resampled to a learned model's rate); default: as is.

        Parameters
        ----------
        recording : Recording
            The trace to estimate.
        """
        return recording

    def estimate(self, recording: Recording) -> Recording:
        """Estimate the process force over a whole trace.

        Parameters
        ----------
        recording : Recording
            Trace with every input channel (:attr:`channel_names`, SI).

        Returns
        -------
        Recording
            :attr:`output_channels` [N] (force on the workpiece along +axis) on
            the trace's time base; ``meta["latency_s"]`` the pure delay of the
            estimate [s]: the method's own plus the trace's declared delay.

        Raises
        ------
        MissingChannelError
            Naming the missing input channels.
        NotFittedError
            When the method needs a model it does not have.
        """
        if not isinstance(recording, Recording):
            raise InvalidSignalError(f"estimate() takes a Recording, got {type(recording).__name__}")
        rec = self.prepare(recording)
        arrays = read_inputs(rec, self.channel_names)
        self.check_trace(rec)
        forces = self.process(self.new_state(rec.fs), arrays)
        return wrap_forces(self, rec, forces, self.latency_s(rec.fs) + declared_delay(rec))

    def stream(self, fs: float, *, delay_s: float = 0.0) -> "ForceStream":
        """A streaming estimator for chunks at ``fs`` [Hz]: the same numbers as :meth:`estimate`.

        Parameters
        ----------
        fs : float
            Sample rate of the chunks [Hz]; chunks at another rate are refused.
        delay_s : float
            Delay the incoming signals carry [s] (a logger's filter), added to
            the declared latency.
        """
        return ForceStream(self, fs, delay_s=delay_s)


class ForceStream:
    """Chunk-by-chunk estimation with a carried state of constant size.

    Parameters
    ----------
    estimator : ForceEstimator
        The (fitted) method.
    fs : float
        Sample rate of the chunks [Hz].
    delay_s : float
        Delay the incoming signals carry [s].

    Attributes
    ----------
    latency_s : float
        Declared latency of every pushed sample's estimate [s].
    samples_seen : int
        Samples pushed so far.
    """

    def __init__(self, estimator: ForceEstimator, fs: float, *, delay_s: float = 0.0) -> None:
        if isinstance(delay_s, bool) or not isinstance(delay_s, (int, float)) or not (delay_s >= 0):
            raise ConfigError(f"stream delay must be a delay >= 0 [s], got {delay_s!r}")
        self.estimator = estimator
        self.fs = check_fs(fs)
        self.state = estimator.new_state(self.fs)
        self._step = estimator.fast_path(self.state)
        self.latency_s = estimator.latency_s(self.fs) + float(delay_s)
        self.samples_seen = 0

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Input channels a chunk must hold."""
        return self.estimator.channel_names

    @property
    def output_channels(self) -> tuple[str, ...]:
        """Force channels returned [N]."""
        return self.estimator.output_channels

    def push_arrays(self, *arrays: np.ndarray) -> dict[str, np.ndarray]:
        """Fast path: the input arrays in :attr:`channel_names` order (float64, finite, SI), unchecked.

        Parameters
        ----------
        *arrays : ndarray
            One array per input channel, equally long.

        Returns
        -------
        dict of str to ndarray
            Forces [N].
        """
        out = self._step(*arrays)
        self.samples_seen += len(arrays[0])
        return out

    def push(self, chunk: Recording | Mapping[str, Any], *, fs: float | None = None):
        """Process the next samples.

        Parameters
        ----------
        chunk : Recording or mapping of str to array_like
            The next samples of every input channel (SI).  A Recording's rate
            must equal the stream's; a mapping's is checked from ``fs`` or its
            ``"time"`` entry [s] when given.
        fs : float, optional
            Rate of a mapping chunk [Hz], checked against the stream's.

        Returns
        -------
        Recording or dict of str to ndarray
            The forces [N] for the chunk's samples: a Recording (on the
            chunk's time base; its latency counts the delay the chunk
            declares, else the stream's) for a Recording, a dict for a mapping.

        Raises
        ------
        InvalidSignalError
            A chunk at another rate, with NaN/inf, or with unequal lengths.
        MissingChannelError
            A chunk without an input channel.
        """
        names = self.estimator.channel_names
        if isinstance(chunk, Recording):
            _check_rate(chunk.fs, self.fs, "the chunk's rate")
            arrays = read_inputs(chunk, names)
            forces = self.estimator.process(self.state, arrays)
            self.samples_seen += chunk.n_samples
            latency = (self.estimator.latency_s(self.fs) + declared_delay(chunk) if "nc_delay_s" in chunk.meta
                       else self.latency_s)
            return wrap_forces(self.estimator, chunk, forces, latency)
        arrays = check_chunk(chunk, names, fs=fs, stream_fs=self.fs)
        forces = self.estimator.process(self.state, arrays)
        self.samples_seen += len(next(iter(arrays.values()))) if arrays else 0
        return forces

    def __repr__(self) -> str:
        return (f"ForceStream({self.estimator.name}, fs={self.fs:g} Hz, latency={self.latency_s * 1e3:.3f} ms, "
                f"samples={self.samples_seen})")
