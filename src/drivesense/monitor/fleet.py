"""Monitor workers sharing machines through one broker: who watches which machine, and hand-overs.

::

    drivesense monitor plant.toml --worker w1 --events /srv/drivesense/events     # on each worker
    drivesense monitor plant.toml --worker w2 --events /srv/drivesense/events

Every worker reads the same config (every machine on an ``mqtt`` source of one broker) and the same events
folder.  How they share the machines:

* **Membership.**  A worker announces itself with a retained message on
  ``drivesense/fleet/GROUP/workers/NAME`` and leaves a Will that clears it: the broker tells the others at
  once when a worker's connection drops (a ``kill -9`` closes it; a dead host is noticed after 1.5 keep-alives,
  :data:`KEEPALIVE_S`).
* **Ownership.**  Each machine goes to the live worker that ranks highest for it (rendezvous hashing,
  :func:`owner_of`): every worker computes the same answer, and a worker that leaves or joins moves only
  its own share of the machines.
* **Claims.**  A worker takes a machine only once it holds the machine's lock in the folder
  (``MACHINE.claim``, an ``flock``: the kernel lets go when the process dies), so two workers never watch
  one machine, whatever their views of the membership.  The claim file holds the mark -- the newest chunk
  whose events are logged -- and the machine's events go to ``MACHINE.jsonl``, the same log whichever worker
  watches it; an event id already in it is not logged or announced again.
* **The stream.**  Each machine has an MQTT 5 session of its own (client id ``drivesense-m-GROUP-MACHINE``;
  :class:`~drivesense.monitor.mqtt.MQTTSource` with ``hold_s``): the broker keeps what arrives while no worker
  holds it, and chunks are acknowledged only after they are marked and :data:`HOLD_S` of signal later.  The
  next holder gets the unacknowledged chunks again: those up to the mark re-prime its estimators and
  detectors (state only, no events), the rest are processed as usual.

Mosquitto's shared subscriptions (``$share/GROUP/...``) hand out messages round-robin, one by one; a machine's
stream split across workers would break the estimators' state, so they are not used for the signals.
"""

from __future__ import annotations

import asyncio
import fcntl
import hashlib
import json
import os
import secrets
import socket
import time
import urllib.parse
from pathlib import Path
from typing import Any

from drivesense.errors import ConfigError
from drivesense.monitor.machine import MachineMonitor
from drivesense.monitor.mqtt import MQTTSource, parse_mqtt_url
from drivesense.monitor.outputs import EventLog
from drivesense.monitor.wire import StreamCursor

__all__ = ["FleetWorker", "Membership", "MachineClaim", "owner_of", "HOLD_S", "KEEPALIVE_S", "TOPIC_PREFIX"]

#: Signal kept unacknowledged after processing, for the next worker to re-prime on [s] (``--hold``).  The demo
#: axis's estimator and detectors give an uninterrupted run's events from 0.5 s on (with the breakage
#: detector's cut start kept besides); twice that by default.
HOLD_S = 1.0
#: Keep-alive of a worker's membership connection [s] (a silent worker is gone after 1.5 of them).
KEEPALIVE_S = 2
#: Quiet time after a membership change before machines move [s] (workers starting together settle first).
SETTLE_S = 0.3
#: Wait before a failed claim (an unreadable event log, a folder gone) is tried again [s].
CLAIM_RETRY_S = 5.0
#: Longest wait at a hand-over for the broker to acknowledge the machine's alarms [s] (else the next holder
#: alarms them again).
ALARM_WAIT_S = 2.0
#: Topic prefix of the fleet's membership.
TOPIC_PREFIX = "drivesense/fleet"
_MARK_BYTES = 256


def owner_of(machine: str, workers) -> str | None:
    """The worker that watches ``machine``: highest rendezvous hash among ``workers`` (None: no worker).

    Parameters
    ----------
    machine : str
        Machine id.
    workers : iterable of str
        Live worker names.
    """
    return max(workers, default=None, key=lambda w: (hashlib.blake2b(f"{w}\0{machine}".encode(), digest_size=8)
                                                     .digest(), w))


class Membership:
    """The live workers of a fleet, from retained presence messages that each worker's Will clears.

    Parameters
    ----------
    loop : asyncio.AbstractEventLoop
        The service's loop (woken on every change).
    url : str
        ``mqtt://HOST[:PORT]``.
    group : str
        Fleet name.
    worker : str
        This worker's name.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, url: str, group: str, worker: str) -> None:
        import paho.mqtt.client as mqtt

        self.loop, self.group, self.worker = loop, group, worker
        self.topic = f"{TOPIC_PREFIX}/{group}/workers/"
        self.token = secrets.token_hex(8)
        self.workers: dict[str, dict] = {}
        self.connected = False
        self.conflict: str | None = None
        self.leaving = False
        self.changed = asyncio.Event()
        self.since = time.time()
        self.presence = json.dumps({"worker": worker, "host": socket.gethostname(), "pid": os.getpid(),
                                    "since": self.since, "token": self.token})
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2,      # one id per process: a twin is seen
                                  client_id=f"drivesense-w-{group}-{worker}-{self.token[:8]}")
        self.client.will_set(self.topic + worker, b"", qos=1, retain=True)
        self.client.reconnect_delay_set(0.2, 2.0)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.connect_async(*parse_mqtt_url(url), keepalive=KEEPALIVE_S)
        self.client.loop_start()

    def _wake(self) -> None:
        try:
            self.loop.call_soon_threadsafe(self.changed.set)
        except RuntimeError:                      # the loop is closed: the service is gone
            pass

    def _announce(self) -> None:
        self.client.publish(self.topic + self.worker, self.presence, qos=1, retain=True)

    def _on_connect(self, client, userdata, flags, reason, props=None) -> None:
        if not reason.is_failure:
            self.workers = {}                     # rebuilt from the retained messages the subscription brings
            client.subscribe(self.topic + "+", qos=1)
            self._announce()
            self.connected = True
            self._wake()

    def _on_disconnect(self, client, userdata, flags, reason, props=None) -> None:
        self.connected = False
        self._wake()

    def _on_message(self, client, userdata, msg) -> None:
        name = msg.topic[len(self.topic):]
        try:
            info = json.loads(msg.payload) if msg.payload else None
        except ValueError:
            info = None
        if name == self.worker and not self.leaving and (info is None or info.get("token") != self.token):
            if info is not None and float(info.get("since", 0.0)) < self.since:
                self.conflict = (f"worker name '{name}' is in use by pid {info.get('pid')} on {info.get('host')} "
                                 f"(since {time.ctime(float(info.get('since', 0.0)))}): give each worker its own "
                                 f"--worker; a worker that died leaves the fleet within {1.5 * KEEPALIVE_S:g} s")
            self._announce()                      # cleared by a predecessor's Will, or a younger twin: ours again
            return
        if info is None:
            self.workers.pop(name, None)
        else:
            self.workers[name] = info
        self._wake()

    def live(self) -> set[str]:
        """Names of the live workers (this one included)."""
        return {*self.workers, self.worker}

    def leave(self) -> None:
        """Clear this worker's presence: the others take its machines over (as it lets go of each)."""
        if not self.leaving:
            self.leaving = True
            if self.connected:
                try:
                    self.client.publish(self.topic + self.worker, b"", qos=1, retain=True).wait_for_publish(2.0)
                except (RuntimeError, ValueError):    # the connection went meanwhile: the Will clears it
                    pass

    def close(self) -> None:
        """Leave the fleet: presence cleared, connection closed."""
        self.leave()
        self.client.disconnect()
        self.client.loop_stop()


def _file_name(machine: str) -> str:
    return urllib.parse.quote(machine, safe="") or "_"


class MachineClaim:
    """A worker's hold on one machine: its lock, its mark and its event log in the fleet's folder.

    Parameters
    ----------
    folder : Path
        The fleet's events folder (shared by the workers).
    machine : str
        Machine id.
    worker : str
        This worker's name.
    """

    def __init__(self, folder: str | Path, machine: str, worker: str) -> None:
        self.folder, self.machine, self.worker = Path(folder), machine, worker
        self.claim_path = self.folder / f"{_file_name(machine)}.claim"
        self.log_path = self.folder / f"{_file_name(machine)}.jsonl"
        self.fd: int | None = None
        self.log: EventLog | None = None
        self.prime_through: int | None = None     # chunks up to this seq were handled by the last worker
        self.prime_session: str | None = None     # ... of this publisher's run
        self.marked_session: str | None = None
        self.previous: str | None = None
        self.marked: int | None = None
        self.primed = 0
        self.resumed = False

    async def acquire(self, poll_s: float = 0.05) -> None:
        """Wait for the machine's lock (another worker may still hand it over), then open its log.

        Parameters
        ----------
        poll_s : float
            Time between two tries [s].
        """
        fd = os.open(self.claim_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    await asyncio.sleep(poll_s)
            fields = os.pread(fd, _MARK_BYTES, 0).decode(errors="replace").split()
            self.log = EventLog(self.log_path)
        except BaseException:
            os.close(fd)
            raise
        self.fd = fd
        if len(fields) >= 2 and fields[0].lstrip("-").isdigit():
            self.prime_through, self.previous = int(fields[0]), fields[1]
            if len(fields) >= 4 and fields[3] != "-":
                self.prime_session = fields[3]
        self.marked, self.marked_session = self.prime_through, self.prime_session
        self._prime = StreamCursor(self.prime_session, self.prime_through)
        self.log.note({"claim": self.machine, "worker": self.worker, "at": time.time(),
                       "previous": self.previous, "prime_through": self.prime_through,
                       "prime_session": self.prime_session})

    def priming(self, chunk: Any) -> bool:
        """Whether a chunk only re-primes the state (the last worker processed it and logged its events).

        Parameters
        ----------
        chunk : Chunk
            A chunk of this machine.
        """
        if self.prime_through is not None and self._prime.place(chunk) == "old":
            self.primed += 1
            return True
        return False

    def mark(self, seq: int, session: str | None = None) -> None:
        """Record that every chunk up to ``seq`` is processed and its events logged (one ``pwrite``).

        Parameters
        ----------
        seq : int
            Chunk seq.
        session : str, optional
            The publisher's run it belongs to.
        """
        text = f"{int(seq)} {self.worker} {time.time():.6f} {session or '-'}\n".encode()
        os.pwrite(self.fd, text.ljust(_MARK_BYTES - 1) + b"\n", 0)
        self.marked, self.marked_session = int(seq), session

    def processed(self, m: Any, item: Any) -> None:
        """After each item the service handled: mark it (one ``pwrite``), then acknowledge what may go.

        Parameters
        ----------
        m : MachineSpec
            The machine.
        item : Chunk or Exception
            What was handled.
        """
        m.source.processed()
        seq, session = m.monitor.last_seq, m.monitor.session
        if seq is not None and (seq, session) != (self.marked, self.marked_session):
            self.mark(seq, session)
        if not self.resumed and seq is not None and (self.prime_through is None or session != self.prime_session
                                                     or seq > self.prime_through):
            self.resumed = True
            now = time.time()
            self.log.note({"resumed": self.machine, "worker": self.worker, "at": now, "seq": seq,
                              "primed": self.primed, "lag_s": now - item.arrival if hasattr(item, "arrival")
                              else None})
        m.source.settle(self.marked, m.monitor.replay_from())

    def release(self, seq: int | None, session: str | None = None) -> None:
        """Mark the last chunk handled, close the log and let the lock go.

        Parameters
        ----------
        seq : int or None
            The newest chunk processed (None: nothing).
        session : str, optional
            The publisher's run it belongs to.
        """
        if self.fd is None:
            return
        try:
            if seq is not None and (seq, session) != (self.marked, self.marked_session):
                self.mark(seq, session)
            self.log.note({"released": self.machine, "worker": self.worker, "at": time.time(),
                              "marked": self.marked})
            self.log.close()
        finally:
            os.close(self.fd)
            self.fd = None


class FleetWorker:
    """One worker of a fleet: joins it, takes the machines the fleet gives it, hands them on when told.

    Parameters
    ----------
    worker : str
        This worker's name (unique in the fleet).
    folder : Path
        Events folder shared by the fleet's workers (created).
    group : str
        Fleet name (workers of one fleet share machines).
    hold_s : float
        Signal kept unacknowledged for the next worker to re-prime on [s].
    """

    def __init__(self, worker: str, folder: str | Path, *, group: str = "main", hold_s: float = HOLD_S) -> None:
        for value, option in ((worker, "--worker"), (group, "--fleet")):
            if not value or any(c in value for c in "/+#\0") or value != value.strip():
                raise ConfigError(f"{option} {value!r}: give a name without '/', '+', '#' or spaces at its ends")
        if not (isinstance(hold_s, (int, float)) and 0 <= hold_s <= 60):
            raise ConfigError(f"--hold must be 0..60 [s] of signal, got {hold_s!r}")
        self.worker, self.group, self.hold_s = worker, group, float(hold_s)
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise ConfigError(f"--events {self.folder}: with --worker it must be a folder (shared by the workers)")
        self.url: str | None = None
        self.membership: Membership | None = None
        self.holding: dict[str, asyncio.Task] = {}

    def check(self, service: Any) -> None:
        """Refuse machines a fleet cannot share: each needs an ``mqtt`` source, all on one broker.

        Parameters
        ----------
        service : MonitorService
            The service.

        Raises
        ------
        ConfigError
            A machine on another kind of source or another broker.
        """
        urls = set()
        for m in service.machines.values():
            if not isinstance(m.source, MQTTSource):
                raise ConfigError(f"--worker: machine '{m.id}' has a {m.source.kind} source; workers share only "
                                  f"machines on mqtt sources")
            urls.add(parse_mqtt_url(m.source.url))
        if len(urls) > 1:
            raise ConfigError(f"--worker: the machines use {len(urls)} brokers; a fleet shares machines on one")
        self.url = next(iter(service.machines.values())).source.url
        self.folder.mkdir(parents=True, exist_ok=True)

    def owner(self, machine: str) -> str | None:
        """The live worker that should watch ``machine`` (None before this worker has joined).

        Parameters
        ----------
        machine : str
            Machine id.
        """
        return owner_of(machine, self.membership.live()) if self.membership is not None else None

    def describe(self, machine: str) -> dict:
        """A machine's place in the fleet: this worker, its owner, whether this worker holds it.

        Parameters
        ----------
        machine : str
            Machine id.
        """
        return {"worker": self.worker, "group": self.group, "owner": self.owner(machine),
                "held": machine in self.holding, "workers": sorted(self.membership.live()) if self.membership else []}

    async def run(self, service: Any, stop: asyncio.Event) -> None:
        """Join, then follow the membership until ``stop``; every machine held is handed back at the end.

        Parameters
        ----------
        service : MonitorService
            The service whose machines the fleet shares.
        stop : asyncio.Event
            Set to leave.

        Raises
        ------
        ConfigError
            Another live worker has this worker's name.
        """
        self.membership = ms = Membership(asyncio.get_running_loop(), self.url, self.group, self.worker)
        stopping = asyncio.ensure_future(stop.wait())
        stopping.add_done_callback(lambda _: ms.changed.set())           # a stop wakes the wait below at once
        try:
            while not stop.is_set():
                try:
                    await asyncio.wait_for(ms.changed.wait(), 1.0)
                except asyncio.TimeoutError:
                    pass
                while ms.changed.is_set() and not stop.is_set():      # settle: workers starting together
                    ms.changed.clear()
                    await asyncio.sleep(SETTLE_S)
                if ms.conflict:
                    raise ConfigError(ms.conflict)
                if not ms.connected or stop.is_set():
                    continue                      # without the broker's view, keep what is held
                live, going = ms.live(), []
                for mid, m in service.machines.items():
                    mine = owner_of(mid, live) == self.worker
                    if mine and mid not in self.holding:
                        self.holding[mid] = asyncio.create_task(self._hold(service, m), name=f"hold-{mid}")
                    elif not mine and mid in self.holding:
                        going.append(mid)
                await asyncio.gather(*(self._let_go(mid) for mid in going))
        finally:
            ms.leave()                            # the others start claiming now; each claim waits for its lock
            await asyncio.gather(*(self._let_go(mid) for mid in list(self.holding)))
            stopping.cancel()
            ms.close()

    async def _let_go(self, mid: str) -> None:
        task = self.holding.pop(mid)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    async def _hold(self, service: Any, m: Any) -> None:
        """Claim a machine, watch it until cancelled, then hand it over (stopped, marked, unlocked)."""
        claim = MachineClaim(self.folder, m.id, self.worker)
        m.state = "claiming"
        try:
            while True:
                try:
                    await claim.acquire()
                    break
                except Exception as exc:  # noqa: BLE001 - an unreadable log or folder: said, and tried again
                    m.state, m.source_error = "error", f"claim failed: {type(exc).__name__}: {exc}"
                    await asyncio.sleep(CLAIM_RETRY_S)
            m.source_error = None
            m.monitor = MachineMonitor(m.id, m.monitor.axes, history_s=m.monitor.history_s)   # state from scratch
            src = m.source
            m.source = MQTTSource(m.id, src.url, src.topic, client_id=f"drivesense-m-{self.group}-{m.id}",
                                  max_pending=src.max_pending, hold_s=self.hold_s)
            m.claim = claim
            if service.archive is not None:
                service.counts["archive_caught_up"] += service.archive.catch_up(list(claim.log.recent))
            if service.alarms is not None:        # the last holder died before the broker had these alarms
                service.counts["alarms_republished"] += service.alarms.republish(claim.log)
            service.start_machine(m)
            await asyncio.Event().wait()          # until cancelled
        finally:
            if m.claim is claim:
                await service.stop_machine(m)     # chunks in hand are processed and logged first
                if service.archive is not None:
                    for r in m.monitor.pending_segments():
                        service.archive.offer((r, None))
                if service.alarms is not None:    # the machine's alarms acknowledged before its log is handed on
                    deadline = time.monotonic() + ALARM_WAIT_S
                    while service.alarms.undelivered(claim.log) and time.monotonic() < deadline:
                        await asyncio.sleep(0.01)
                m.claim = None
            if claim.fd is not None:
                claim.release(m.monitor.last_seq, m.monitor.session)
            m.state = "standby"
