"""Where a monitored machine's drive signals come from: a replayed file, the simulator.

Every source delivers :class:`~drivesense.monitor.wire.Chunk` objects of one
machine through ``await put(item)``; ``put`` blocks while the machine's queue
is full, so a source is held back (backpressure) instead of memory growing.
A message a source cannot read is handed on as the exception itself
(``put(WireError(...))``): the service counts it against the machine and the
stream goes on.  A source that loses its connection raises from
:meth:`Source.run`; the service calls ``run`` again after a back-off, and the
source resumes where it was (sequence numbers continue).

The network sources live beside it: edge devices publishing to a broker in
:mod:`drivesense.monitor.mqtt`, controllers (MTConnect agents, OPC UA servers) in
:mod:`drivesense.monitor.controllers`.
"""

from __future__ import annotations

import asyncio
import math
import random
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable
from dataclasses import replace
from typing import Any, ClassVar


from drivesense.errors import ConfigError
from drivesense.recording import Recording
from drivesense.monitor.wire import Chunk

__all__ = ["Source", "ReplaySource", "SimulatedSource", "Put", "DEMO_FEED", "demo_condition", "check_speed"]

#: What a source hands each chunk (or unreadable message) to.
Put = Callable[[Any], Awaitable[None]]


class Source(ABC):
    """One machine's signal source.

    Parameters
    ----------
    machine : str
        Machine id the chunks carry.
    """

    #: The config's ``source.kind``.
    kind: ClassVar[str] = ""
    #: Whether :meth:`run`, once ``stop`` is set, still hands on what it has taken from its server (and the
    #: server no longer keeps) before it returns: the service waits for it then, instead of cancelling it.
    drains: ClassVar[bool] = False

    def __init__(self, machine: str) -> None:
        self.machine = machine
        self.finished = False

    @abstractmethod
    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Deliver chunks until the source is exhausted (``finished``) or ``stop`` is set.

        Parameters
        ----------
        put : callable
            ``await put(chunk_or_exception)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """

    def describe(self) -> dict:
        """What the dashboard and ``/api/machines`` show of the source."""
        return {"kind": self.kind}


async def _pace(loop: asyncio.AbstractEventLoop, start: float, due_s: float, stop: asyncio.Event) -> None:
    """Sleep until ``start + due_s`` on the loop's clock (or until stop)."""
    delay = start + due_s - loop.time()
    if delay > 0:
        try:
            await asyncio.wait_for(stop.wait(), delay)
        except asyncio.TimeoutError:
            pass


def check_speed(speed: float, option: str = "source speed") -> float:
    """Refuse a replay/publishing rate that is negative or not finite (0 means as fast as possible).

    Parameters
    ----------
    speed : float
        The rate [-]: 1 real time, 50 fifty times faster, 0 as fast as possible.
    option : str
        How the message names it (``--speed``, ``source speed``).

    Returns
    -------
    float
        The rate.

    Raises
    ------
    ConfigError
        Naming `option` and the value.
    """
    if not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed >= 0):
        raise ConfigError(f"{option} must be >= 0 (1: real time, 50: fifty times faster, 0: as fast as possible), "
                          f"got {speed!r}")
    return float(speed)


class ReplaySource(Source):
    """A recording played as a live stream, in real time or ``speed`` times faster.

    Parameters
    ----------
    machine : str
        Machine id.
    recording : Recording
        The trace (SI channels).
    speed : float
        Replay rate [-]: 1 real time, 50 fifty times faster, 0 as fast as the service takes it.
    chunk_s : float
        Length of each chunk [s].
    loop : int
        Times the recording is played (its time and sequence continue across repeats).
    """

    kind = "replay"

    def __init__(self, machine: str, recording: Recording, *, speed: float = 1.0, chunk_s: float = 0.05,
                 loop: int = 1) -> None:
        super().__init__(machine)
        check_speed(speed)
        if not (math.isfinite(chunk_s) and chunk_s > 0):
            raise ConfigError(f"source chunk_s must be > 0 [s], got {chunk_s!r}")
        if int(loop) < 1:
            raise ConfigError(f"source loop must be >= 1, got {loop!r}")
        self.recording = recording
        self.speed = float(speed)
        self.chunk_n = max(1, int(round(chunk_s * recording.fs)))
        self.loop = int(loop)
        self.seq = 0

    def describe(self) -> dict:
        """Kind, file name, speed and progress."""
        return {"kind": self.kind, "name": str(self.recording.meta.get("name", "")), "speed": self.speed,
                "duration_s": self.recording.duration * self.loop}

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Play the recording (see :class:`Source`).

        Parameters
        ----------
        put : callable
            ``await put(chunk)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        rec = self.recording
        loop = asyncio.get_running_loop()
        start = loop.time()
        n, fs = rec.n_samples, rec.fs
        arrays = {c: rec[c] for c in rec.channels}
        per_pass = math.ceil(n / self.chunk_n)
        while self.seq < per_pass * self.loop and not stop.is_set():
            k = self.seq
            rep, i = divmod(k, per_pass)
            lo, hi = i * self.chunk_n, min(n, (i + 1) * self.chunk_n)
            t0 = rec.t0 + rep * n / fs + lo / fs
            if self.speed > 0:
                await _pace(loop, start, (k * self.chunk_n + hi - lo) / fs / self.speed, stop)
                if stop.is_set():
                    return
            await put(Chunk(self.machine, k, t0, fs, {c: a[lo:hi] for c, a in arrays.items()}))
            self.seq += 1
        self.finished = self.seq >= per_pass * self.loop


#: Feed of the demo's cuts [m/s].
DEMO_FEED = 2e-3


def demo_condition():
    """The demo machine's cut: 1.5 mm radial, 1 mm axial, 6000 min^-1, 2 mm/s feed on the ball-screw stage."""
    from drivesense.sim.scenarios import CutCondition

    return CutCondition("demo", "feed", 1.5e-3, 6000.0, feed_speed=DEMO_FEED, axial_depth=1e-3)


class SimulatedSource(Source):
    """The built-in simulator as a machine: one cut after another, some with a breakage, chipping or collision.

    Cuts of ``cut_s`` seconds (the ball-screw stage of the first paper, a 2-flute 6 mm end mill) are
    simulated one ahead in a worker thread and played in real time (or ``speed`` times faster); the
    first cut is always clean (the detectors learn their baselines), then each cut holds an event with
    probability ``event_share``.  The truth of every cut is kept in :attr:`truth` (for the tests).

    Parameters
    ----------
    machine : str
        Machine id.
    seed : int
        Seed of the draws and the simulation.
    speed : float
        Replay rate [-].
    cut_s : float
        Length of each cut [s].
    event_share : float
        Share of cuts with an event [-].
    chunk_s : float
        Chunk length [s].
    first_event : str, optional
        Kind of the event of the second cut (``"breakage"`` for the demo: an alarm within seconds).
    """

    kind = "simulated"
    KINDS = ("breakage", "chipping", "collision")

    def __init__(self, machine: str, *, seed: int = 1, speed: float = 1.0, cut_s: float = 4.0,
                 event_share: float = 0.3, chunk_s: float = 0.05, first_event: str | None = "breakage") -> None:
        super().__init__(machine)
        check_speed(speed)
        self.seed = int(seed)
        self.speed = float(speed)
        self.cut_s = float(cut_s)
        self.event_share = float(event_share)
        self.chunk_s = float(chunk_s)
        self.first_event = first_event
        self.rng = random.Random(self.seed)
        self.cuts = 0
        self.truth: list[dict] = []
        self._next_t0 = 0.0
        self._seq = 0

    def describe(self) -> dict:
        """Kind, cuts played and their events."""
        return {"kind": self.kind, "cuts": self.cuts, "speed": self.speed}

    def _draw_events(self, k: int):
        from drivesense.sim.process_events import ProcessEvent

        kind = None
        if k == 1 and self.first_event:
            kind = self.first_event
        elif k > 1 and self.rng.random() < self.event_share:
            kind = self.rng.choice(self.KINDS)
        if kind is None:
            return ()
        t = self.rng.uniform(0.5, 0.8) * self.cut_s
        if kind == "collision":
            return (ProcessEvent("collision", t, force_n=800.0, rise_s=5e-4, hold_s=0.2),)
        if kind == "chipping":
            return (ProcessEvent("chipping", t, flute=1, edge_loss=0.6),)
        return (ProcessEvent("breakage", t, flute=1),)

    def simulate_cut(self, k: int) -> Recording:
        """The k-th cut (events drawn from the seed).

        Parameters
        ----------
        k : int
            Cut number (0: the first, clean).
        """
        from drivesense.sim.process_events import simulate_event_cut
        from drivesense.sim.scenarios import ScenarioSettings

        settings = replace(ScenarioSettings(), duration=self.cut_s, t_contact=0.2 * self.cut_s)
        return simulate_event_cut(demo_condition(), events=self._draw_events(k), settings=settings,
                                  seed=self.seed * 1000 + k)

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Simulate and play cuts until stopped (see :class:`Source`).

        Parameters
        ----------
        put : callable
            ``await put(chunk)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        ahead = asyncio.ensure_future(asyncio.to_thread(self.simulate_cut, self.cuts))
        try:
            while not stop.is_set():
                rec = await ahead
                ahead = asyncio.ensure_future(asyncio.to_thread(self.simulate_cut, self.cuts + 1))
                offset = self._next_t0 - rec.t0
                self.truth.append({"cut": self.cuts, "t0": self._next_t0,
                                   "events": [{**e, "time_s": e["time_s"] + offset}
                                              for e in rec.meta["truth"]["events"]]})
                player = ReplaySource(self.machine, rec, speed=self.speed, chunk_s=self.chunk_s)
                player.seq = 0

                async def shifted(chunk: Chunk) -> None:
                    chunk.seq = self._seq
                    chunk.t0 += offset
                    self._seq += 1
                    await put(chunk)

                await player.run(shifted, stop)
                self._next_t0 += rec.n_samples / rec.fs
                self.cuts += 1
        finally:
            ahead.cancel()
