"""The live monitor service: per machine, source -> bounded queue -> estimators and detectors -> outputs.

::

    service = MonitorService([MachineSpec("vmc1", ReplaySource(...), MachineMonitor(...))],
                             events_path="events.jsonl", alarm_url="mqtt://127.0.0.1:1883")
    await service.run(stop)            # until stop is set (or every finite source is played out)

One asyncio loop runs everything.  Each machine has a source task and a
worker task joined by a bounded queue: a source that outruns the worker waits
(backpressure), it never piles up memory.  A source that fails is restarted
after a back-off (1 s growing to 10 s) while the other machines go on; a
chunk that cannot be used is counted against its machine.  Events are
written to the log first (safe from a kill), then published; the log's
syncer thread fsyncs them meanwhile, off the alarm's path.  Dashboard subscribers get frames
through queues of two: a slow browser loses frames, never events (those it
can re-read with ``/api/events?since=``).
"""

from __future__ import annotations

import asyncio
import hmac
import re
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivesense.errors import ConfigError, MissingChannelError
from drivesense.monitor.machine import MachineMonitor
from drivesense.monitor.outputs import AlarmPublisher, ArchiveWriter, EventLog, Webhook
from drivesense.monitor.sources import Source

__all__ = ["MachineSpec", "MonitorService", "Subscriber", "check_machine_id", "machine_id_from", "MACHINE_ID_RULE"]

#: Chunks queued per machine before its source waits.
QUEUE_CHUNKS = 64
#: Dashboard frame period [s].
FRAME_PERIOD_S = 0.2
#: Longest wait for a stopping source that hands on what it holds (:attr:`Source.drains`) [s]; then it is
#: cancelled.
SOURCE_DRAIN_S = 30.0


#: What a machine id may be: it is a path segment of the API (``/api/machines/<id>/force``), a part of every
#: event id (``machine/detector/axis/...``), of MQTT topics and of log file names.
MACHINE_ID_RULE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def check_machine_id(machine: Any, where: str = "machine id") -> str:
    """Refuse a machine id that would break a route, an event id, a topic or a file name.

    Parameters
    ----------
    machine : str
        The id: 1-64 characters, letters, digits, ``_``, ``.`` and ``-``, starting with a letter or digit.
    where : str
        How the message names it (``machine id``, ``--machine``).

    Returns
    -------
    str
        The id.

    Raises
    ------
    ConfigError
        Naming the id and the rule.
    """
    if not isinstance(machine, str) or MACHINE_ID_RULE.fullmatch(machine) is None:
        raise ConfigError(f"{where} {machine!r}: use 1-64 letters, digits, '_', '.' or '-', starting with a letter "
                          f"or digit (it is part of URLs, event ids, MQTT topics and file names)")
    return machine


def machine_id_from(name: str) -> str:
    """A valid machine id made from a file name (``--replay 'cut 1.csv'`` -> ``cut_1``).

    Parameters
    ----------
    name : str
        The name (a trace's stem).

    Returns
    -------
    str
        Every character outside the rule of :func:`check_machine_id` replaced by ``_``, cut to 64 characters
        (``machine`` when nothing is left).
    """
    cleaned = re.sub(r"[^A-Za-z0-9_.-]", "_", name).lstrip("_.-")[:64]
    return cleaned or "machine"


@dataclass
class MachineSpec:
    """A machine the service watches.

    Attributes
    ----------
    id : str
        Machine id.
    source : Source
        Where its signals come from.
    monitor : MachineMonitor
        Its estimators and detectors.
    state : str
        ``starting``, ``running``, ``reconnecting``, ``finished`` or ``stopped`` (set by the service).
    restarts : int
        Times its source was restarted after a failure.
    source_error : str or None
        The last failure of its source.
    queue : asyncio.Queue or None
        Its chunk queue while the service runs.
    tasks : list
        Its source and worker tasks while the service runs.
    claim : object or None
        A fleet worker's hold on the machine (:class:`~drivesense.monitor.fleet.MachineClaim`): its event log,
        its mark and the chunks to re-prime on.  None outside a fleet.
    stop : asyncio.Event or None
        Set to stop this machine alone (a fleet worker handing it on).
    """

    id: str
    source: Source
    monitor: MachineMonitor
    state: str = "starting"
    restarts: int = 0
    source_error: str | None = None
    queue: Any = None
    tasks: list = field(default_factory=list)
    claim: Any = None
    stop: Any = None

    def __post_init__(self) -> None:
        check_machine_id(self.id)


class Subscriber:
    """A dashboard client: a queue of two frames (old ones dropped) and a bounded queue of events.

    Parameters
    ----------
    max_events : int
        Events queued before the client counts as gone (it re-reads ``/api/events``).
    """

    def __init__(self, max_events: int = 1000) -> None:
        self.frames: asyncio.Queue = asyncio.Queue(maxsize=2)
        self.events: asyncio.Queue = asyncio.Queue(maxsize=max_events)
        self.dropped_frames = 0
        self.overflow = False

    def offer_frame(self, frame: dict) -> None:
        """Queue a frame, dropping the oldest when full.

        Parameters
        ----------
        frame : dict
            The frame.
        """
        if self.frames.full():
            self.frames.get_nowait()
            self.dropped_frames += 1
        self.frames.put_nowait(frame)

    def offer_event(self, record: dict) -> None:
        """Queue an event (a client that let 1000 pile up is marked ``overflow``).

        Parameters
        ----------
        record : dict
            The event record.
        """
        try:
            self.events.put_nowait(record)
        except asyncio.QueueFull:
            self.overflow = True


class MonitorService:
    """The service: machines, outputs, the dashboard's view of them.

    Parameters
    ----------
    machines : list of MachineSpec
        What to watch (ids unique).
    events_path : Path, optional
        JSONL event log (``--events``); None keeps events in memory.
    archive : str or Path, optional
        Archive (SQLite file or PostgreSQL DSN) for events and their segments.
    alarm_url : str, optional
        ``mqtt://HOST[:PORT]`` for alarms and stop requests.
    alarm_prefix : str
        Topic prefix of the alarms.
    webhook : str, optional
        URL each event is POSTed to.
    token : str, optional
        Secret that acknowledging alarms and changing limits need (no token: read-only).
    queue_chunks : int
        Chunks queued per machine.
    fleet : FleetWorker, optional
        Share the machines with other workers (:mod:`~drivesense.monitor.fleet`): this service watches the ones
        the fleet gives it, each with its own event log in the fleet's folder; ``events_path`` is unused.
    """

    def __init__(self, machines: list[MachineSpec], *, events_path: str | Path | None = None,
                 archive: str | Path | None = None, alarm_url: str | None = None, alarm_prefix: str = "",
                 webhook: str | None = None, token: str | None = None, queue_chunks: int = QUEUE_CHUNKS,
                 fleet: Any = None) -> None:
        ids = [m.id for m in machines]
        if not machines:
            raise ConfigError("no machine to monitor: name at least one [[machine]] in the config")
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ConfigError(f"machine id(s) {', '.join(dup)} given twice in the config")
        self.machines = {m.id: m for m in machines}
        self.fleet = fleet
        if fleet is not None:
            fleet.check(self)
            for m in machines:
                m.state = "standby"
        self.log = EventLog(None if fleet is not None else events_path)
        self.archive_location = archive
        self.alarm_url = alarm_url
        self.alarm_prefix = alarm_prefix
        self.webhook_url = webhook
        self.token = token or None
        self.queue_chunks = int(queue_chunks)
        self.started = time.time()
        self.counts: Counter = Counter()
        self.subscribers: set[Subscriber] = set()
        self.alarms: AlarmPublisher | None = None
        self.webhook: Webhook | None = None
        self.archive: ArchiveWriter | None = None
        self.running = False
        #: When :meth:`run` started the sources [s since the epoch] (None before; after the warm-up).
        self.sources_started: float | None = None
        #: Callables ``f(record)`` called with every newly logged event (the CLI prints them).
        self.listeners: list = []

    # ------------------------------------------------------------------ run
    async def run(self, stop: asyncio.Event | None = None, *, until_finished: bool = False) -> None:
        """Watch every machine until ``stop`` is set (or, with ``until_finished``, every source is played out).

        Parameters
        ----------
        stop : asyncio.Event, optional
            Set to shut down (outputs are flushed and closed).
        until_finished : bool
            Return once every source has finished and its queue is drained.
        """
        stop = stop or asyncio.Event()
        self._open_outputs()
        warmed: set = set()
        for m in self.machines.values():              # compiled code loaded before the first chunk, not during:
            if m.monitor.kind not in warmed:          # once per kind of pipeline (the code is per process)
                warmed.add(m.monitor.kind)
                try:
                    m.monitor.warm_up()
                except Exception:  # noqa: BLE001 - only an optimisation: the first real chunk shows a real problem
                    pass
        self.running = True
        self.sources_started = time.time()
        if self.fleet is None:
            for m in self.machines.values():
                self.start_machine(m)
            coordinator = None
        else:
            coordinator = asyncio.create_task(self.fleet.run(self, stop), name="fleet")
        frames = asyncio.create_task(self._frames(stop), name="frames")
        try:
            while not stop.is_set():
                if until_finished and all(m.source.finished and m.queue.empty() for m in self.machines.values()):
                    break                             # the workers finish what they hold before they end
                if coordinator is not None and coordinator.done():
                    coordinator.result()              # the fleet's failure (e.g. a worker name in use) ends the run
                try:
                    await asyncio.wait_for(stop.wait(), 0.05)
                except asyncio.TimeoutError:
                    pass
        finally:
            stop.set()
            if coordinator is not None:
                await asyncio.gather(coordinator, return_exceptions=True)     # it hands its machines back
            await asyncio.gather(*(self.stop_machine(m) for m in self.machines.values()))
            frames.cancel()
            self.running = False
            self._close_outputs()

    def start_machine(self, m: MachineSpec) -> None:
        """Start a machine's source and worker (a fleet worker calls this when it takes a machine over).

        Parameters
        ----------
        m : MachineSpec
            The machine (not running).
        """
        m.stop = asyncio.Event()
        m.queue = asyncio.Queue(maxsize=self.queue_chunks)
        m.tasks = [asyncio.create_task(self._source_loop(m, m.stop), name=f"source-{m.id}"),
                   asyncio.create_task(self._worker(m), name=f"worker-{m.id}")]

    async def stop_machine(self, m: MachineSpec) -> None:
        """Stop a machine's source; its worker finishes what is queued (nothing when it is not running).

        A source that drains (an ``mqtt`` source: messages the broker has handed over) hands on what it holds
        first, up to :data:`SOURCE_DRAIN_S`; any other is cancelled at once.

        Parameters
        ----------
        m : MachineSpec
            The machine.
        """
        if not m.tasks:
            return
        m.stop.set()
        if m.source.drains:                           # the worker goes on taking what the source hands on
            await asyncio.wait(m.tasks[:1], timeout=SOURCE_DRAIN_S)
        m.tasks[0].cancel()
        await m.queue.put(None)                       # the worker drains what is queued, then ends
        await asyncio.gather(*m.tasks, return_exceptions=True)
        m.tasks = []

    def _open_outputs(self) -> None:
        if self.alarm_url:
            self.alarms = AlarmPublisher(self.alarm_url, prefix=self.alarm_prefix, **(
                {"client_id": f"drivesense-monitor-{self.fleet.group}-{self.fleet.worker}"} if self.fleet else {}))
            if self.fleet is None:                    # (a fleet worker: each machine's log, when it claims it)
                self.counts["alarms_republished"] += self.alarms.republish(self.log)
        if self.webhook_url:
            self.webhook = Webhook(self.webhook_url)
        if self.archive_location is not None:
            self.archive = ArchiveWriter(self.archive_location)
            self.counts["archive_caught_up"] += self.archive.catch_up(list(self.log.recent))

    def _close_outputs(self) -> None:
        if self.archive is not None:
            for m in self.machines.values() if self.fleet is None else ():   # (a fleet worker's: at release)
                for r in m.monitor.pending_segments():
                    self.archive.offer((r, None))
            self.archive.close()
        if self.webhook is not None:
            self.webhook.close()
        if self.alarms is not None:
            self.alarms.close()
        self.log.close()

    async def _source_loop(self, m: MachineSpec, stop: asyncio.Event) -> None:
        backoff = 1.0
        while not stop.is_set() and not m.source.finished:
            m.state = "running"
            try:
                await m.source.run(m.queue.put, stop)
                backoff = 1.0
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - one machine's source failing never stops the others
                m.source_error = f"{type(exc).__name__}: {exc}"
                m.restarts += 1
                m.state = "reconnecting"
                try:
                    await asyncio.wait_for(stop.wait(), backoff)
                except asyncio.TimeoutError:
                    pass
                backoff = min(10.0, backoff * 2)
        m.state = "finished" if m.source.finished else "stopped"

    async def _worker(self, m: MachineSpec) -> None:
        while True:
            item = await m.queue.get()
            if item is None:
                return
            self._handle(m, item)
            if m.claim is not None:
                m.claim.processed(m, item)        # the mark, then the acknowledgements it allows
            if m.queue.empty():
                await asyncio.sleep(0)                # let the sources and the web server run

    def _handle(self, m: MachineSpec, item: Any) -> None:
        """Process one chunk of a machine (or count what could not be read): events out, segments archived."""
        if isinstance(item, Exception):
            m.monitor.reject(str(item))
            return
        try:
            if m.claim is None:
                records = m.monitor.process(item)
            else:                                     # a chunk the machine's last worker handled: state only
                records = m.monitor.process(item, emit=not m.claim.priming(item))
        except Exception as exc:  # noqa: BLE001 - a bug on one machine's data never stops the service
            m.monitor.reject(f"{type(exc).__name__}: {exc}")
            return
        segments = m.monitor.take_segments()          # taken whether archived or not: nothing piles up
        for rec in records:
            self._emit(rec, m)
        if self.archive is not None:
            for rec, seg in segments:
                self.archive.offer((rec, seg))

    def _emit(self, record: dict, m: MachineSpec | None = None) -> None:
        if m is not None and m.claim is not None and m.claim.log.append(record) is None:
            self.counts["events_repeated"] += 1      # the machine's log (shared by the fleet) has it already
            return
        logged = self.log.append(record)
        if logged is None:
            self.counts["events_repeated"] += 1
            return
        self.counts[f"events_{record['kind']}"] += 1
        if self.alarms is not None:
            self.alarms.publish(logged, (self.log,) if m is None or m.claim is None else (self.log, m.claim.log))
        if self.webhook is not None:
            self.webhook.offer(logged)
        for sub in list(self.subscribers):
            sub.offer_event({**logged, "acknowledged": False})
        for listener in self.listeners:
            listener(logged)

    async def _frames(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            await asyncio.sleep(FRAME_PERIOD_S)
            if not self.subscribers:
                continue
            frame = {"type": "frame", "time": time.time(),
                     "machines": {mid: {"force": m.monitor.force_history(2.0, max_points=400),
                                        "status": self.machine_status(mid)}
                                  for mid, m in self.machines.items()}}
            for sub in list(self.subscribers):
                sub.offer_frame(frame)

    # ------------------------------------------------------------------ the dashboard's view
    def subscribe(self) -> Subscriber:
        """A new dashboard subscriber (call :meth:`unsubscribe` when it leaves)."""
        sub = Subscriber()
        self.subscribers.add(sub)
        return sub

    def unsubscribe(self, sub: Subscriber) -> None:
        """Forget a subscriber.

        Parameters
        ----------
        sub : Subscriber
            From :meth:`subscribe`.
        """
        self.counts["frames_dropped"] += sub.dropped_frames
        self.subscribers.discard(sub)

    def machine(self, machine_id: str) -> MachineSpec:
        """A machine by id.

        Parameters
        ----------
        machine_id : str
            The id.

        Raises
        ------
        MissingChannelError
            No such machine (a ``KeyError``).
        """
        if machine_id not in self.machines:
            raise MissingChannelError(f"no machine {machine_id!r} (machines: {', '.join(self.machines)})")
        return self.machines[machine_id]

    def machine_status(self, machine_id: str) -> dict:
        """Status of one machine: source, state, counters, detector statistics and limits.

        Parameters
        ----------
        machine_id : str
            The id.
        """
        m = self.machine(machine_id)
        return {**m.monitor.status(), "state": m.state, "source": m.source.describe(), "restarts": m.restarts,
                "source_error": m.source_error, "queue": m.queue.qsize() if m.queue is not None else 0,
                "queue_max": self.queue_chunks, **({"fleet": self.fleet.describe(machine_id)} if self.fleet else {})}

    def events(self, since: int = 0, limit: int = 1000) -> list[dict]:
        """Logged events after ``since`` (their ``seq``), oldest first.

        Parameters
        ----------
        since : int
            Last seq the caller has.
        limit : int
            At most this many.
        """
        return self.log.since(since, limit)

    def check_token(self, given: str | None) -> bool:
        """Whether a write may proceed: a token is configured and ``given`` equals it (constant-time).

        Parameters
        ----------
        given : str or None
            The token the request carried.
        """
        if self.token is None or not given:
            return False
        return hmac.compare_digest(self.token.encode(), str(given).encode())

    def acknowledge(self, event_id: str, by: str = "") -> dict:
        """Acknowledge an alarm (logged).

        Parameters
        ----------
        event_id : str
            The event's id.
        by : str
            Who.
        """
        ack = self.log.acknowledge(event_id, by)
        for m in self.machines.values():          # a fleet worker: into the machine's own log too
            if m.claim is not None and event_id in m.claim.log.ids:
                m.claim.log.acknowledge(event_id, by)
        return ack

    def set_force_limit(self, machine_id: str, axis: str, limit_n: float) -> dict:
        """Change an axis's collision/overload limit while running.

        Parameters
        ----------
        machine_id : str
            Machine id.
        axis : str
            Axis letter.
        limit_n : float
            New limit [N].
        """
        mon = self.machine(machine_id).monitor
        mon.set_force_limit(axis, limit_n)
        return mon.limits()

    def metrics(self) -> str:
        """Prometheus text exposition: samples, chunks, rejects, gaps, queue depths, lag, events, alarms."""
        lines: list[str] = []

        def metric(name: str, kind: str, help_: str, values: list[tuple[dict, float]]) -> None:
            lines.append(f"# HELP drivesense_{name} {help_}")
            lines.append(f"# TYPE drivesense_{name} {kind}")
            for labels, v in values:
                lab = ",".join(f'{k}="{_esc(str(val))}"' for k, val in labels.items())
                lines.append(f"drivesense_{name}{{{lab}}} {float(v):.9g}" if lab
                             else f"drivesense_{name} {float(v):.9g}")

        ms = self.machines.values()
        metric("samples_total", "counter", "Samples processed per machine.",
               [({"machine": m.id}, m.monitor.samples) for m in ms])
        metric("chunks_total", "counter", "Chunks processed per machine.",
               [({"machine": m.id}, m.monitor.chunks) for m in ms])
        metric("rejected_total", "counter", "Chunks or messages refused per machine.",
               [({"machine": m.id}, m.monitor.rejected) for m in ms])
        metric("gaps_total", "counter", "Chunks missing from a machine's sequence.",
               [({"machine": m.id}, m.monitor.gaps) for m in ms])
        metric("publisher_restarts_total", "counter",
               "New runs of a machine's publisher (a new session in its chunks).",
               [({"machine": m.id}, m.monitor.restarts) for m in ms])
        metric("queue_depth", "gauge", "Chunks waiting per machine.",
               [({"machine": m.id}, m.queue.qsize() if m.queue is not None else 0) for m in ms])
        metric("lag_seconds", "gauge", "Arrival to end of processing of the last chunk.",
               [({"machine": m.id}, m.monitor.lag_s) for m in ms])
        metric("busy_seconds_total", "counter", "Processing time per machine.",
               [({"machine": m.id}, m.monitor.busy_s) for m in ms])
        metric("source_restarts_total", "counter", "Source reconnects per machine.",
               [({"machine": m.id}, m.restarts) for m in ms])
        kinds = sorted(k[7:] for k in self.counts if k.startswith("events_") and k != "events_repeated")
        metric("events_total", "counter", "Events logged, by kind.",
               [({"kind": k}, self.counts[f"events_{k}"]) for k in kinds])
        metric("alarms_published_total", "counter", "Alarms published to MQTT.",
               [({}, self.alarms.published if self.alarms else 0)])
        metric("alarms_delivered_total", "counter", "Alarms the broker acknowledged.",
               [({}, self.alarms.delivered if self.alarms else 0)])
        metric("alarms_undelivered", "gauge", "Alarms published and not yet acknowledged by the broker.",
               [({}, self.alarms.undelivered() if self.alarms else 0)])
        metric("alarms_republished_total", "counter", "Alarms sent again after a restart or a takeover (never "
               "acknowledged before).", [({}, self.counts["alarms_republished"])])
        metric("event_log_sync_errors_total", "counter", "fsyncs of the event log that failed (disk trouble).",
               [({}, self.log.sync_errors)])
        metric("webhook_failures_total", "counter", "Webhook posts that failed.",
               [({}, self.webhook.failed if self.webhook else 0)])
        metric("dashboard_frames_dropped_total", "counter", "Frames a slow dashboard client did not get.",
               [({}, self.counts["frames_dropped"] + sum(s.dropped_frames for s in self.subscribers))])
        if self.fleet is not None:
            metric("fleet_machine_held", "gauge", "1 for each machine this worker watches now, 0 for the others.",
                   [({"machine": m.id, "worker": self.fleet.worker}, float(m.claim is not None)) for m in ms])
            metric("fleet_workers", "gauge", "Live workers of the fleet this worker sees.",
                   [({}, len(self.fleet.membership.live()) if self.fleet.membership else 0)])
        metric("uptime_seconds", "gauge", "Seconds since the service started.", [({}, time.time() - self.started)])
        return "\n".join(lines) + "\n"


def _esc(value: str) -> str:
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
