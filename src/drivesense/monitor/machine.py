"""One machine's live pipeline: chunks in -> streaming estimators -> detectors -> event records.

::

    mon = MachineMonitor("vmc1", [AxisPipeline("x", estimator, detectors)])
    records = mon.process(chunk)          # event records (dicts with an id), in time order
    mon.force_history(5.0)                # the last 5 s of estimated force, for the dashboard
    mon.take_segments()                   # (event record, Segment) once the signal after an event is in

Every chunk is checked before it touches a state: the machine id, the
sequence number (a repeated or older chunk is dropped; a missing one is
counted as a gap; a new publisher session starts the stream afresh), the
sample rate and the channels.  A chunk that fails is
counted with its reason and leaves every state as it was, so one bad message
never stops the machine.  The force and the input signals of the last
seconds are kept in fixed-size ring buffers (constant memory however long
the service runs).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from drivesense.errors import ConfigError, DriveSenseError, InvalidSignalError
from drivesense.estimate.base import check_chunk
from drivesense.events.detector import Event
from drivesense.events.overload import OverloadDetector
from drivesense.nc_context import CONTEXT_CHANNELS
from drivesense.recording import Recording
from drivesense.monitor.streams import FeedSpeedStream, Ring
from drivesense.monitor.wire import Chunk, StreamCursor

__all__ = ["AxisPipeline", "MachineMonitor", "Ring", "FeedSpeedStream", "Segment", "event_id", "event_record"]

#: Signal kept around each event for the archive [s] (before, after).
SEGMENT_S = (1.0, 0.5)


@dataclass(frozen=True)
class Segment:
    """The signal around one event, copied out of the ring buffers (cheap: no Recording is built yet).

    Building the :class:`~drivesense.recording.Recording` costs milliseconds, so it is left to whoever
    stores the segment (the archive's worker thread), off the path of the alarms.

    Attributes
    ----------
    channels : dict
        Channel name -> samples (drive signals in SI units, ``force_<axis>`` [N]).
    fs : float
        Sample rate [Hz].
    t0 : float
        Time of the first sample [s], on the machine's sample clock.
    meta : dict
        ``name``, ``machine``, ``event_id``, ``event_kind``.
    """

    channels: dict
    fs: float
    t0: float
    meta: dict

    def recording(self) -> Recording:
        """The segment as a Recording."""
        return Recording.from_arrays(self.channels, fs=self.fs, t0=self.t0, meta=self.meta)


@dataclass
class AxisPipeline:
    """The estimator and the detectors of one axis.

    Attributes
    ----------
    axis : str
        Axis letter (``"x"``): the force channel is ``force_{axis}``.
    estimator : ForceEstimator
        A fitted (or tared) estimator of :mod:`drivesense.estimate`.
    detectors : list of Detector
        Detectors reading this axis's force.
    """

    axis: str
    estimator: object
    detectors: list = field(default_factory=list)


def event_id(machine: str, event: Event, session: str | None = None) -> str:
    """The id of an event: machine, detector, axis and sample time [us] (the same event, the same id).

    Parameters
    ----------
    machine : str
        Machine id.
    event : Event
        The event.
    session : str, optional
        The publisher's run, appended as ``@SESSION``: a publisher whose clock restarts with it does not
        repeat the ids of its earlier runs.
    """
    base = f"{machine}/{event.detector}/{event.axis}/{int(round(event.time_s * 1e6))}"
    return base if session is None else f"{base}@{session}"


def event_record(machine: str, event: Event, *, arrival: float, detected: float, session: str | None = None) -> dict:
    """The JSON record of an event the service logs, publishes and archives.

    Parameters
    ----------
    machine : str
        Machine id.
    event : Event
        The event.
    arrival : float
        Wall-clock arrival of the chunk holding its sample [s since the epoch].
    detected : float
        Wall-clock time it was detected [s since the epoch].
    session : str, optional
        The publisher's run the chunk came from (in the id and the record).
    """
    return {"id": event_id(machine, event, session), "machine": machine, **event.to_json(),
            "arrival": arrival, "detected": detected, **({"session": session} if session is not None else {})}


class MachineMonitor:
    """Streaming estimation and detection for one machine.

    Parameters
    ----------
    machine : str
        Machine id (chunks of another machine are refused).
    axes : sequence of AxisPipeline
        The axes monitored.
    history_s : float
        Signal kept for the dashboard and the event segments [s].
    """

    def __init__(self, machine: str, axes: Sequence[AxisPipeline], *, history_s: float = 10.0) -> None:
        if not axes:
            raise ConfigError(f"machine '{machine}': no axis to monitor")
        self.machine = machine
        self.axes = list(axes)
        self.history_s = max(float(history_s), sum(SEGMENT_S) + 0.5)
        self.fs: float | None = None
        self.cursor = StreamCursor()
        self.samples = 0
        self.chunks = 0
        self.rejected = 0
        self.gaps = 0
        self.time_jumps = 0
        self.last_error: str | None = None
        self.last_arrival: float | None = None
        self.lag_s = 0.0
        self.busy_s = 0.0
        self.t_last: float | None = None
        self.stats: dict[str, dict] = {}
        self._streams: list = []
        self._feed: FeedSpeedStream | None = None
        self._rings: dict[str, Ring] = {}
        self._pending: deque = deque()
        self._ready: list = []
        self._t0: float | None = None
        self._kept: list[str] = []
        self.required = sorted({c for a in self.axes for c in a.estimator.channel_names})

    @property
    def last_seq(self) -> int | None:
        """``seq`` of the last chunk processed (None: none yet)."""
        return self.cursor.seq

    @property
    def session(self) -> str | None:
        """The publisher's run the last chunk came from (None: it names none)."""
        return self.cursor.session

    @property
    def restarts(self) -> int:
        """Times the publisher started a new run (a new session in its chunks) while this machine ran."""
        return self.cursor.restarts

    # ------------------------------------------------------------------ checks
    def check(self, chunk: Chunk) -> dict[str, np.ndarray]:
        """Refuse a chunk this machine cannot take (raises, naming the problem; no state changes).

        Parameters
        ----------
        chunk : Chunk
            The chunk.

        Returns
        -------
        dict of str to ndarray
            Its channels as float64 arrays [SI unit of each channel].

        Raises
        ------
        InvalidSignalError
            Another machine's chunk, a repeated or older sequence number, another rate, a missing channel,
            channels of unequal length, NaN or inf.
        """
        if chunk.machine != self.machine:
            raise InvalidSignalError(f"chunk of machine '{chunk.machine}' reached machine '{self.machine}'")
        place = self.cursor.place(chunk)
        if place == "old":
            hint = (" (if its publisher restarted, the chunks must name a new 'session' in their header)"
                    if chunk.session is None and chunk.seq == 0 else "")
            raise InvalidSignalError(f"machine '{self.machine}': chunk seq {chunk.seq} is not after seq "
                                     f"{self.last_seq} (repeated or out of order, or of an ended session), "
                                     f"dropped{hint}")
        if self.fs is not None and place == "next" and abs(chunk.fs - self.fs) > 1e-6 * self.fs:
            raise InvalidSignalError(f"machine '{self.machine}': chunk at {chunk.fs:g} Hz, the stream runs at "
                                     f"{self.fs:g} Hz")
        missing = [c for c in self.required if c not in chunk.arrays]
        if missing:
            raise InvalidSignalError(f"machine '{self.machine}': chunk seq {chunk.seq} lacks channel(s) "
                                     f"{', '.join(missing)}")
        if chunk.n == 0:
            raise InvalidSignalError(f"machine '{self.machine}': chunk seq {chunk.seq} holds no samples")
        try:                                      # 1-D, one length, finite: the estimators' own chunk check
            return check_chunk(chunk.arrays, list(chunk.arrays))
        except DriveSenseError as exc:
            raise InvalidSignalError(f"machine '{self.machine}': chunk seq {chunk.seq}: {exc}") from None

    def reject(self, reason: str) -> None:
        """Count a chunk (or message) that could not be used.

        Parameters
        ----------
        reason : str
            Why, as the status and the log show it.
        """
        self.rejected += 1
        self.last_error = reason

    @property
    def kind(self) -> tuple:
        """The classes of this machine's estimators and detectors, axis by axis (machines alike share code)."""
        return tuple((type(a.estimator).__name__, *(type(d).__name__ for d in a.detectors)) for a in self.axes)

    def warm_up(self, fs: float = 10e3, seconds: float = 0.2) -> None:
        """Run a synthetic chunk through a twin of this pipeline, so compiled code is loaded now.

        The first chunk of a process otherwise pays for loading the compiled (numba) kernels -- tens of
        milliseconds on the event loop, in front of every machine's next chunk.  This machine's own state
        is untouched.

        Parameters
        ----------
        fs : float
            Sample rate of the synthetic chunk [Hz] (the kernels do not depend on it).
        seconds : float
            Its length [s].
        """
        n = max(8, int(round(fs * seconds)))
        rng = np.random.default_rng(0)
        t = np.arange(n) / fs
        arrays = {c: 1e-3 * rng.standard_normal(n) for c in self.required}
        arrays["spindle_speed"] = np.full(n, 2 * np.pi * 100.0)            # 6000 min^-1 [rad/s]
        for c in {c for c in self.required if c.endswith("_table_position")} | {"x_table_position"}:
            arrays[c] = 0.01 * t                                          # 10 mm/s [m]
        twin = MachineMonitor(self.machine, self.axes, history_s=self.history_s)
        twin.process(Chunk(self.machine, 0, 0.0, fs, arrays))

    # ------------------------------------------------------------------ processing
    def _start(self, chunk: Chunk) -> None:
        self.fs = float(chunk.fs)
        self._t0 = float(chunk.t0)
        self._streams = [(a, a.estimator.stream(self.fs),
                          [d.stream(self.fs, t0=chunk.t0) for d in a.detectors],
                          float(a.estimator.latency_s(self.fs))) for a in self.axes]
        self._feed = FeedSpeedStream(self.fs)
        cap = int(math.ceil(self.history_s * self.fs))
        self._kept = [*self.required, *sorted(c for c in chunk.arrays if c not in self.required)]
        for c in [*self._kept, *(f"force_{a.axis}" for a in self.axes)]:
            self._rings[c] = Ring(cap)

    def _restart(self) -> None:
        """The publisher started a new run: its signal does not continue the last one's.  The segments of
        events still waiting for signal are cut where the run ended; estimators and detectors start afresh
        with the next chunk (as at the first one)."""
        if self._pending:
            self._collect_segments(cut=True)
        self.fs = None
        self.t_last = None
        self._streams = []

    def process(self, chunk: Chunk, *, emit: bool = True) -> list[dict]:
        """Estimate and detect on one chunk; the event records it raised, in time order.

        A chunk that fails :meth:`check` is counted (``rejected``) and nothing else happens.

        Parameters
        ----------
        chunk : Chunk
            The next chunk of this machine.
        emit : bool
            False: only bring the state up to date (re-priming on signal another worker already handled);
            its events are neither returned nor kept for a segment.
        """
        try:
            arrays = self.check(chunk)
        except InvalidSignalError as exc:
            self.reject(str(exc))
            return []
        began = time.perf_counter()
        place = self.cursor.place(chunk)
        if place == "restart":
            self._restart()
        if self.fs is None:
            self._start(chunk)
        if place == "next" and self.last_seq is not None and chunk.seq > self.last_seq + 1:
            self.gaps += chunk.seq - self.last_seq - 1
        if self.t_last is not None:               # lost chunks or a clock jump: events keep their true time
            jump = chunk.t0 - (self.t_last + 1.0 / self.fs)
            if abs(jump) > 0.5 / self.fs:
                self.time_jumps += 1
                self._t0 += jump
                for _, _, det_streams, _ in self._streams:
                    for stream in det_streams:
                        stream.shift_time(jump)
        self.cursor.advance(chunk)
        extra = {c: arrays[c] for c in ("spindle_speed", "spindle_power", *CONTEXT_CHANNELS) if c in arrays}
        positions = {c: arrays[c] for c in arrays if c.endswith("_table_position")}
        if positions:
            extra["feed_speed"] = self._feed.push(positions)
        events: list[Event] = []
        try:
            for axis, est_stream, det_streams, est_latency in self._streams:
                forces = est_stream.push_arrays(*(arrays[c] for c in est_stream.channel_names))
                inputs = {**forces, **extra, **positions}
                self._rings[f"force_{axis.axis}"].extend(forces[f"force_{axis.axis}"])
                for stream in det_streams:
                    out = stream.push_arrays(inputs)
                    for e in out.events:
                        events.append(Event(e.kind, e.time_s, e.axis, e.confidence, e.latency_s + est_latency,
                                            e.detector, e.evidence))
                    self._note_stats(stream, axis.axis, out)
        except DriveSenseError as exc:       # a detector or estimator refusing this data: the machine goes on
            self.reject(f"machine '{self.machine}': chunk seq {chunk.seq}: {exc}")
            return []
        for c in self._kept:                 # an optional channel a chunk lacks holds its last value
            self._rings[c].extend(arrays[c] if c in arrays else np.full(chunk.n, self._rings[c].last(1)[0]
                                                                        if self._rings[c].written else 0.0))
        self.samples += chunk.n
        self.chunks += 1
        self.t_last = chunk.t0 + (chunk.n - 1) / chunk.fs
        self.last_arrival = chunk.arrival
        now = time.time()
        records = [event_record(self.machine, e, arrival=chunk.arrival, detected=now, session=chunk.session)
                   for e in sorted(events, key=lambda e: e.time_s)] if emit else []
        for r in records:
            self._pending.append((r, self._ring_index(r["time_s"])))
        self._collect_segments()
        self.busy_s += time.perf_counter() - began
        self.lag_s = max(0.0, time.time() - chunk.arrival)
        return records

    def replay_from(self) -> float | None:
        """Earliest time [s] from which replaying the signal rebuilds every detector's state (None: a few seconds do).

        A fleet worker keeps the signal since then for the next worker (see :mod:`~drivesense.monitor.fleet`).
        """
        times = [t for _, _, det_streams, _ in self._streams for s in det_streams
                 if (t := s.replay_from()) is not None]
        return min(times) if times else None

    def _note_stats(self, stream, axis: str, out) -> None:
        stat = out.statistic[-1] if np.size(out.statistic) else float("nan")
        thr = out.threshold[-1] if np.size(out.threshold) else float("nan")
        key = f"{stream.detector.name}:{axis}"
        self.stats[key] = {"detector": stream.detector.name, "axis": axis,
                           "statistic": float(stat) if math.isfinite(stat) else None,
                           "threshold": float(thr) if math.isfinite(thr) else None}

    # ------------------------------------------------------------------ history, segments
    def _ring_index(self, time_s: float) -> int:
        """Absolute sample index (samples since the stream began) of a time [s]."""
        return int(round((time_s - self._t0) * self.fs))

    def _collect_segments(self, cut: bool = False) -> None:
        ring = self._rings[self.required[0]]
        before, after = (int(round(s * self.fs)) for s in SEGMENT_S)
        while self._pending and (cut or self._pending[0][1] + after <= ring.written):
            record, index = self._pending.popleft()
            end = ring.written
            start = max(index - before, end - ring.capacity, 0)
            n = end - start
            channels = {c: self._rings[c].last(n) for c in self._rings}
            seg = Segment(channels, fs=self.fs, t0=self._t0 + start / self.fs,
                          meta={"name": f"{record['id']} segment", "machine": self.machine,
                                "event_id": record["id"], "event_kind": record["kind"]})
            self._ready.append((record, seg))

    def take_segments(self) -> list:
        """Events whose segment is complete: ``(record, Segment)`` pairs, taken once.

        The :class:`Segment` holds the drive signals and the estimated forces from 1 s before the event to 0.5 s
        after it (:data:`SEGMENT_S`).
        """
        ready, self._ready = self._ready, []
        return ready

    def pending_segments(self) -> list[dict]:
        """Event records still waiting for the signal after them (at shutdown: archive them without one)."""
        return [r for r, _ in self._pending]

    def force_history(self, seconds: float, *, max_points: int = 2000) -> dict:
        """The last ``seconds`` of estimated force per axis, thinned to ``max_points`` (min/max kept).

        Parameters
        ----------
        seconds : float
            How much [s].
        max_points : int
            Points per axis at most.

        Returns
        -------
        dict
            ``{"t": [...] [s], "force_x": [...] [N], ...}`` (empty lists before the first chunk).
        """
        if self.fs is None:
            return {"t": [], **{f"force_{a.axis}": [] for a in self.axes}}
        n = int(min(max(seconds, 0.0) * self.fs, self._rings[f"force_{self.axes[0].axis}"].written))
        step = max(1, int(math.ceil(2 * n / max_points)))
        out: dict = {}
        end_t = self.t_last if self.t_last is not None else 0.0
        t = end_t - (np.arange(n)[::-1]) / self.fs
        for a in self.axes:
            f = self._rings[f"force_{a.axis}"].last(n)
            if step > 1:
                m = (n // step) * step
                blocks = f[n - m:].reshape(-1, step)
                lo, hi = blocks.min(axis=1), blocks.max(axis=1)
                f = np.column_stack([lo, hi]).ravel()
                tt = np.repeat(t[n - m:].reshape(-1, step)[:, [0, -1]].mean(axis=1), 2)
            else:
                tt = t
            out[f"force_{a.axis}"] = np.round(f, 4).tolist()
            out["t"] = np.round(tt, 6).tolist()
        return out

    def spectrum(self, axis: str, seconds: float = 0.5) -> dict:
        """Amplitude spectrum of the last ``seconds`` of one axis's force (Hann window).

        Parameters
        ----------
        axis : str
            Axis letter.
        seconds : float
            Window [s].

        Returns
        -------
        dict
            ``{"f": [...] [Hz], "amplitude": [...] [N]}``.
        """
        ring = self._rings.get(f"force_{axis}")
        if ring is None or self.fs is None or ring.written < 16:
            return {"f": [], "amplitude": []}
        x = ring.last(int(seconds * self.fs))
        x = x - x.mean()
        w = np.hanning(x.size)
        amp = 2 * np.abs(np.fft.rfft(x * w)) / w.sum()
        f = np.fft.rfftfreq(x.size, 1 / self.fs)
        keep = slice(0, min(f.size, 1024))
        return {"f": np.round(f[keep], 3).tolist(), "amplitude": np.round(amp[keep], 5).tolist()}

    def set_force_limit(self, axis: str, limit_n: float) -> None:
        """Change the collision/overload limit of an axis while running.

        Parameters
        ----------
        axis : str
            Axis letter.
        limit_n : float
            New limit [N] (> 0).

        Raises
        ------
        ConfigError
            Unknown axis, no overload detector on it, or a limit that is not a positive number.
        """
        if not (isinstance(limit_n, (int, float)) and not isinstance(limit_n, bool) and math.isfinite(limit_n)
                and limit_n > 0):
            raise ConfigError(f"force_limit_n must be a positive number [N], got {limit_n!r}")
        for a in self.axes:
            if a.axis == axis:
                dets = [d for d in a.detectors if isinstance(d, OverloadDetector)]
                if not dets:
                    raise ConfigError(f"machine '{self.machine}' axis '{axis}' has no overload detector")
                for d in dets:
                    d.limit_n = float(limit_n)
                return
        raise ConfigError(f"machine '{self.machine}' has no axis '{axis}'")

    def limits(self) -> dict:
        """Force limit [N] per axis (None without an overload detector)."""
        out = {}
        for a in self.axes:
            dets = [d for d in a.detectors if isinstance(d, OverloadDetector)]
            out[a.axis] = float(dets[0].limit_n) if dets else None
        return out

    def status(self) -> dict:
        """Counters and state for the API and the metrics (strict-JSON values)."""
        return {"machine": self.machine, "axes": [a.axis for a in self.axes],
                "detectors": sorted({d.name for a in self.axes for d in a.detectors}),
                "fs": self.fs, "samples": self.samples, "chunks": self.chunks, "rejected": self.rejected,
                "gaps": self.gaps, "time_jumps": self.time_jumps, "session": self.session,
                "publisher_restarts": self.restarts, "last_error": self.last_error,
                "lag_s": round(self.lag_s, 6),
                "busy_s": round(self.busy_s, 6), "t_last": self.t_last, "limits": self.limits(),
                "statistics": list(self.stats.values())}
