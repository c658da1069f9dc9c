"""The contract every process-event detector follows (breakage, chatter, overload, teach-in limits, wear).

::

    det = ds.events.BreakageDetector(axis="x", teeth=2)
    events = det.detect(forces)          # forces: a Recording with force_x [N] (and spindle_speed [rad/s])
    stream = det.stream(fs)              # constant-size state, the same events as detect()
    out = stream.push(chunk)             # Detection(events, statistic, threshold[, held])

A detector reads a force stream -- any estimator's output, or a dynamometer
-- plus the spindle speed when it needs the spindle angle (a
``spindle_speed`` channel [rad/s], or a fixed ``spindle_rpm`` given to it).
Like the estimators (:mod:`drivesense.estimate.base`) a detector implements a
fresh state and one ``process`` step; batch detection is one step from a fresh
state, so batch and stream give the same events by construction.  Every event
carries its kind, time, axis, confidence, evidence and the detection latency
the detector declares (the estimator's latency adds to it: see
:func:`attach_latency`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from drivesense.errors import InvalidSignalError, MissingChannelError
from drivesense.event import EVENT_KINDS, Event, finite_or_none as _finite
from drivesense.nc_context import CONTEXT_CHANNELS, context_at
from drivesense.recording import Recording
from drivesense.timebase import check_fs

__all__ = ["Event", "Detection", "Detector", "DetectorStream", "RecentSamples", "EVENT_KINDS", "spindle_speed_of",
           "feed_steady", "attach_latency", "events_to_json"]

def events_to_json(events: Sequence[Event], latency_s: float) -> dict:
    """The EVENTS.json document: ``{"events": [...], "latency_s": float}``.

    Parameters
    ----------
    events : sequence of Event
        The events, in time order.
    latency_s : float
        Largest declared latency of the detectors that ran, estimator's included [s].
    """
    return {"events": [e.to_json() for e in sorted(events, key=lambda e: e.time_s)],
            "latency_s": _finite(latency_s)}


def attach_latency(events: Sequence[Event], extra_s: float) -> list[Event]:
    """The events with ``extra_s`` (the estimator's latency [s]) added to their declared latency.

    Parameters
    ----------
    events : sequence of Event
        Events from a detector.
    extra_s : float
        The force stream's own latency [s].
    """
    from dataclasses import replace
    return [replace(e, latency_s=e.latency_s + float(extra_s)) for e in events]


@dataclass
class Detection:
    """What one push returns.

    Attributes
    ----------
    events : list of Event
        Events raised in the chunk.
    statistic : ndarray
        The detector's statistic per sample of the chunk (for plots) [-] or [N].
    threshold : ndarray
        The threshold it is compared with, per sample (NaN while not armed) [unit of the statistic].
    held : ndarray or None
        Per sample, 0 where the detector judged its statistic and a positive code where its guards held it
        from raising an event (the codes are the detector's ``GUARDS``) [-]; None for a detector without
        guards it reports.
    """

    events: list
    statistic: np.ndarray
    threshold: np.ndarray
    held: np.ndarray | None = None


def spindle_speed_of(chunk: Mapping[str, np.ndarray], n: int, spindle_rpm: float | None) -> np.ndarray:
    """Spindle speed per sample [rad/s]: the chunk's ``spindle_speed`` channel, else the given rpm.

    Parameters
    ----------
    chunk : mapping of str to ndarray
        The chunk's arrays [SI unit of each channel].
    n : int
        Samples in the chunk.
    spindle_rpm : float or None
        Fixed spindle speed [min^-1] (``--spindle-rpm``).

    Raises
    ------
    MissingChannelError
        Neither a ``spindle_speed`` channel nor ``--spindle-rpm``.
    """
    if "spindle_speed" in chunk:
        return np.asarray(chunk["spindle_speed"], dtype=float)
    if spindle_rpm is None:
        raise MissingChannelError("the trace has no 'spindle_speed' channel: give the spindle speed with "
                                  "--spindle-rpm RPM")
    return np.full(n, float(spindle_rpm) * 2 * math.pi / 60.0)


#: Time over which a feed change is judged [s], and the relative change that counts as one [-].
FEED_LOOKBACK_S = 0.1
FEED_CHANGE = 0.2


def feed_steady(chunk: Mapping[str, np.ndarray], state: dict) -> np.ndarray:
    """1.0 per sample where the feed runs steadily, 0.0 where it changes (a feed-override ramp, a start,
    a stop) or stands; all ones when the chunk has no ``feed_speed`` channel [m/s].

    The feed counts as changing where it differs by more than 20 % from its
    value 100 ms earlier (a feed-override ramp; the short jolt a cutting-force
    step gives the table is not one); the state keeps those last 100 ms
    (constant size).

    Parameters
    ----------
    chunk : mapping of str to ndarray
        The chunk's arrays [SI unit of each channel].
    state : dict
        The detector's state (holds ``"fs"``; the feed history is kept in it).
    """
    feed = chunk.get("feed_speed")
    if feed is None:
        n = len(next(iter(chunk.values()))) if chunk else 0
        return np.ones(n)
    v = np.abs(np.asarray(feed, dtype=float))
    lag = max(1, int(round(FEED_LOOKBACK_S * state["fs"])))
    history = state.get("feed_history")
    if history is None:
        history = np.full(lag, v[0] if v.size else 0.0)
    joined = np.concatenate([history, v])
    past = joined[:v.size]
    state["feed_history"] = joined[-lag:]
    level = np.maximum(v, past)
    return ((np.abs(v - past) <= FEED_CHANGE * level) & (level > 1e-6)).astype(float)


def _arrays(chunk: Recording | Mapping[str, Any], names: Sequence[str]) -> tuple[dict[str, np.ndarray], float | None]:
    """Float arrays of ``names`` (and ``spindle_speed`` / positions when present), plus the chunk's t0 [s]."""
    if isinstance(chunk, Recording):
        present = [c for c in chunk.channels]
        data = {c: chunk[c] for c in present}
        t0 = chunk.t0
    elif isinstance(chunk, Mapping):
        data = {k: np.asarray(v, dtype=float) for k, v in chunk.items() if k != "time"}
        t0 = float(np.asarray(chunk["time"], dtype=float)[0]) if "time" in chunk and len(chunk["time"]) else None
    else:
        raise InvalidSignalError(f"push() takes a Recording or a mapping of channel arrays, got "
                                 f"{type(chunk).__name__}")
    missing = [c for c in names if c not in data]
    if missing:
        raise MissingChannelError(f"the force stream lacks channel(s) {', '.join(repr(m) for m in missing)}")
    if isinstance(chunk, Recording):
        return data, t0                      # a Recording is finite and of one length by construction
    n = None
    for c, arr in data.items():
        if arr.ndim != 1:
            raise InvalidSignalError(f"detector input channel '{c}' must be 1-D, got shape {arr.shape}")
        if n is not None and arr.size != n:
            raise InvalidSignalError(f"detector input channel '{c}' has {arr.size} samples, the others {n}")
        if not np.all(np.isfinite(arr)):
            raise InvalidSignalError(f"detector input channel '{c}' holds NaN or inf")
        n = arr.size
    return data, t0


class Detector(ABC):
    """Base of every process-event detector.

    Subclasses set :attr:`name`, implement :attr:`channel_names`,
    :meth:`latency_s`, :meth:`new_state` and :meth:`process`.
    """

    #: Short name (the CLI's and the bench's).
    name: ClassVar[str] = ""

    @property
    @abstractmethod
    def channel_names(self) -> tuple[str, ...]:
        """Force (or power) channels the detector reads."""

    @abstractmethod
    def latency_s(self, fs: float) -> float:
        """Worst-case detection latency the detector declares at ``fs`` [s].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """

    def replay_from(self, state: Any) -> int | None:
        """Where the signal must be replayed from to rebuild ``state`` exactly, when that is far back.

        A live monitor that hands a machine to another worker replays the last seconds of signal into
        fresh detectors; a detector whose state reaches further back (a baseline learnt at the start of
        the present cut) says from where.

        Parameters
        ----------
        state : object
            The stream's state.

        Returns
        -------
        int or None
            Sample index since the stream began; None when a few seconds of signal rebuild the state.
        """
        return None

    @abstractmethod
    def new_state(self, fs: float) -> Any:
        """A fresh state of constant size for signals at ``fs`` [Hz].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """

    @abstractmethod
    def process(self, state: Any, arrays: Mapping[str, np.ndarray], start: int) -> tuple[list, np.ndarray,
                                                                                           np.ndarray]:
        """Events, statistic and threshold for the next samples, updating ``state`` in place.

        Parameters
        ----------
        state : object
            From :meth:`new_state`.
        arrays : mapping of str to ndarray
            The chunk's channels [SI unit of each channel: N, rad/s, m/s, m], equally long, finite.
        start : int
            Index of the chunk's first sample since the stream began.

        Returns
        -------
        events : list of tuple
            ``(sample_index, kind, confidence, evidence)`` per event.
        statistic, threshold : ndarray
            Per sample of the chunk.
        held : ndarray, optional
            A fourth array a detector with guards may return: per sample, 0 where it judged its statistic,
            else the code (a key of its ``GUARDS``) of the guard that held it.
        """

    def unusable(self, fs: float, spindle_rpm: float | None = None) -> str | None:
        """Why the detector cannot judge a stream at ``fs`` (None when it can), in words a user acts on.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        spindle_rpm : float, optional
            The spindle speed [min^-1] (the trace's median).
        """
        return None

    def check_ready(self, state: Any) -> None:
        """Raise when a finished batch run could not arm the detector (e.g. too short for a baseline).

        Parameters
        ----------
        state : object
            The state after the whole trace.
        """

    @property
    def axis(self) -> str:
        """The axis letter events are reported on."""
        return getattr(self, "_axis", "x")

    def stream(self, fs: float, *, t0: float = 0.0) -> "DetectorStream":
        """A streaming detector for chunks at ``fs`` [Hz].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        t0 : float
            Time of the first sample [s] when chunks carry no time.
        """
        return DetectorStream(self, fs, t0=t0)

    def detect(self, forces: Recording) -> list[Event]:
        """Every event in a whole force trace (one push from a fresh state).

        Parameters
        ----------
        forces : Recording
            Force channels [N] (and ``spindle_speed`` [rad/s] where needed).

        Returns
        -------
        list of Event
        """
        if not isinstance(forces, Recording):
            raise InvalidSignalError(f"detect() takes a Recording, got {type(forces).__name__}")
        stream = self.stream(forces.fs, t0=forces.t0)
        out = stream.push(forces)
        self.check_ready(stream.state)
        return out.events


class RecentSamples:
    """The last ``keep`` samples of some channels, carried across chunks: each chunk is kept as it came (a copy,
    never joined to the others), so that a long tail costs a chunk's copy per push, not the tail's.

    Parameters
    ----------
    keep : int
        Samples to keep at least [-].
    """

    def __init__(self, keep: int) -> None:
        self.keep = int(keep)
        self._chunks: list[tuple[int, dict[str, np.ndarray]]] = []
        self._size = 0

    def __bool__(self) -> bool:
        return bool(self._chunks)

    def push(self, n: int, arrays: Mapping[str, np.ndarray]) -> None:
        """Keep the next ``n`` samples of ``arrays``.

        Parameters
        ----------
        n : int
            Samples in the chunk [-].
        arrays : mapping of str to ndarray
            The channels to keep, each ``n`` long [their units].
        """
        if n == 0:
            return
        self._chunks.append((n, {k: np.array(v, dtype=float) for k, v in arrays.items()}))
        self._size += n
        while len(self._chunks) > 1 and self._size - self._chunks[0][0] >= self.keep:
            self._size -= self._chunks.pop(0)[0]

    def at(self, index: int) -> tuple[dict[str, np.ndarray], int]:
        """The chunk holding a sample kept, and the sample's index in it.

        Parameters
        ----------
        index : int
            The sample, counted back from the next push (-1: the last sample kept) [-]; one further back than
            what is kept gives the oldest sample kept.
        """
        for n, arrays in reversed(self._chunks):
            index += n
            if index >= 0:
                return arrays, index
        return self._chunks[0][1], 0

    def last(self, name: str, m: int) -> np.ndarray:
        """The last ``m`` (or fewer) samples kept of a channel [its unit].

        Parameters
        ----------
        name : str
            The channel.
        m : int
            Samples wanted [-].
        """
        parts = [arrays[name] for _, arrays in self._chunks if name in arrays]
        return np.concatenate(parts)[-m:] if parts else np.zeros(0)


class DetectorStream:
    """Chunk-by-chunk detection with a carried state of constant size.

    Parameters
    ----------
    detector : Detector
        The detector.
    fs : float
        Sample rate of the chunks [Hz].
    t0 : float
        Time of the first sample [s] (a chunk's own time wins when it has one).
    """

    def __init__(self, detector: Detector, fs: float, *, t0: float = 0.0) -> None:
        self.detector = detector
        self.fs = check_fs(fs)
        self.state = detector.new_state(self.fs)
        self.latency_s = detector.latency_s(self.fs)
        self.samples_seen = 0
        self._t0 = float(t0)
        self._t0_fixed = False
        # the context channels' last samples, for an event a detector emits after the chunk its sample was in
        self._context_tail = RecentSamples(int(math.ceil(self.latency_s * self.fs)) + 1)

    def shift_time(self, seconds: float) -> None:
        """Move the stream's clock by ``seconds`` [s]: the next chunk starts that much later than contiguous.

        A live stream that lost chunks (or whose source clock jumped) keeps its detector state but must
        still give events their true time.

        Parameters
        ----------
        seconds : float
            Time between the end of the last chunk and the start of the next, beyond one sample [s].
        """
        self._t0 += float(seconds)
        self._t0_fixed = True

    def replay_from(self) -> float | None:
        """Time [s] from which replaying the signal rebuilds this stream's state (see :meth:`Detector.replay_from`).

        None when a few seconds of signal do.
        """
        index = self.detector.replay_from(self.state)
        return None if index is None else self._t0 + index / self.fs

    def _context(self, arrays: Mapping[str, np.ndarray], index: int) -> dict:
        """The NC's context at the chunk's sample ``index`` (negative: that many samples before the chunk)."""
        if index >= 0 or not self._context_tail:
            return context_at(arrays, index)
        return context_at(*self._context_tail.at(index))

    def push(self, chunk: Recording | Mapping[str, Any]) -> Detection:
        """Detect in the next samples.

        Parameters
        ----------
        chunk : Recording or mapping of str to array_like
            Force channels [N] (and ``spindle_speed`` [rad/s], ``time`` [s]).

        Returns
        -------
        Detection
        """
        if isinstance(chunk, Recording) and abs(chunk.fs - self.fs) > 1e-6 * self.fs:
            raise InvalidSignalError(f"the chunk's rate is {chunk.fs:g} Hz but the detector runs at {self.fs:g} Hz")
        arrays, t0 = _arrays(chunk, self.detector.channel_names)
        if t0 is not None and not self._t0_fixed:
            self._t0 = t0 - self.samples_seen / self.fs
        return self.push_arrays(arrays)

    def push_arrays(self, arrays: Mapping[str, np.ndarray]) -> Detection:
        """Fast path: the next samples as float64 arrays already checked (finite, 1-D, equally long, SI).

        The live monitor checks each chunk once and hands it to every detector through here.

        Parameters
        ----------
        arrays : mapping of str to ndarray
            Every channel the detector reads (:attr:`Detector.channel_names`) and the optional ones
            (``spindle_speed`` [rad/s], ``feed_speed`` [m/s]...).

        Returns
        -------
        Detection
        """
        self._t0_fixed = True
        n = len(next(iter(arrays.values()))) if arrays else 0
        raw, stat, thr, *held = self.detector.process(self.state, arrays, self.samples_seen)
        # each event carries the NC's context at its sample (tool, program, block...) where the stream has it
        events = [Event(kind=kind, time_s=self._t0 + index / self.fs, axis=self.detector.axis,
                        confidence=conf, latency_s=self.latency_s, detector=self.detector.name,
                        evidence={**ev, **self._context(arrays, index - self.samples_seen)})
                  for index, kind, conf, ev in raw]
        self.samples_seen += n
        self._context_tail.push(n, {k: arrays[k] for k in CONTEXT_CHANNELS if k in arrays})
        return Detection(events, stat, thr, held[0] if held else None)
