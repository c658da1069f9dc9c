"""Where the live monitor's events go: an append-only JSONL log, the archive, MQTT alarms, a webhook.

The log is the record of truth.  Each event is written to it (one ``write``
system call: from then on the kernel holds it, and a ``kill -9`` of the
service cannot lose it) before anything else hears of it, and ``fsync``-ed
by a syncer thread right after (group commit: the alarm does not wait for
the disk, and an event on disk survives a power loss too); on a restart
the log is read back (a line torn by the kill is
cut off), and an event already in it -- the same id, because the same
samples give the same event -- is not written or announced again.  The
archive is filled from a worker thread (an event row and its signal segment
in one transaction) and, on a restart, catches up with every logged event it
lacks.  MQTT alarms go out with QoS 1 (``{machine}/alarm``; events that call
for a stop also on ``{machine}/stop``); the paho client queues them while
the broker is away and sends them once it is back.  Once the broker has
acknowledged an alarm, an ``{"alarmed": id}`` line goes into the log; on a
restart (or a fleet worker's takeover of a machine) the events of the last
:data:`REALARM_S` seconds without that line -- logged, but killed before the
broker had their alarm -- are alarmed again, marked ``"republished": true``
(at least once: an alarm the broker had just taken may come twice, with the
same id).  Stop requests are not sent again: a late stop could halt a machine
someone has restarted since.  Every queue here is bounded.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
import urllib.request
from collections import deque
from pathlib import Path
from typing import Any

from drivesense.errors import ConfigError

__all__ = ["EventLog", "AlarmPublisher", "Webhook", "ArchiveWriter", "STOP_KINDS"]

#: Event kinds that ask the controller to stop (published on ``{machine}/stop``).
STOP_KINDS = ("breakage", "collision", "overload", "missing_tool")
#: Events detected this recently [s] whose alarm the broker never acknowledged are alarmed again on a restart.
REALARM_S = 600.0


class EventLog:
    """Append-only JSONL event log, every event fsync-ed; the ids already logged are refused.

    :meth:`append` returns once the line is written (safe from a ``kill -9``); a syncer thread ``fsync``-s
    what was written since its last pass (safe from a power loss), so the caller -- the alarm -- never
    waits for the disk.  :meth:`sync` waits for it.

    Parameters
    ----------
    path : Path, optional
        The ``EVENTS.jsonl`` file (created with its folder); None keeps events in memory only.
    keep : int
        Events kept in memory for the API (the file keeps all).
    """

    def __init__(self, path: str | Path | None = None, *, keep: int = 10000) -> None:
        self.path = None if path is None else Path(path)
        self.recent: deque = deque(maxlen=int(keep))
        self.ids: set[str] = set()
        self.acknowledged: dict[str, dict] = {}
        self.alarmed: set[str] = set()
        self.seq = 0
        self.recovered = 0
        self._fh = None
        self.written = self.synced = 0            # lines written / known to be on disk
        self.sync_errors = 0
        self.last_sync_error: str | None = None
        self._cond = threading.Condition()
        self._syncer: threading.Thread | None = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._load()
            self._fh = open(self.path, "ab", buffering=0)
            self._syncer = threading.Thread(target=self._sync_loop, name="drivesense-eventlog-sync", daemon=True)
            self._syncer.start()

    def _load(self) -> None:
        if not self.path.exists():
            return
        data = self.path.read_bytes()
        good = data.rfind(b"\n") + 1               # a line torn by a kill has no newline: cut it off
        if good < len(data):
            with open(self.path, "r+b") as fh:
                fh.truncate(good)
                os.fsync(fh.fileno())
        for n, line in enumerate(data[:good].splitlines(), 1):
            try:
                rec = json.loads(line)
            except ValueError:
                raise ConfigError(f"{self.path} line {n}: not a JSON record (--events must be a drivesense event "
                                  f"log)") from None
            if isinstance(rec, dict) and "ack" in rec:
                self.acknowledged[str(rec["ack"])] = rec
            elif isinstance(rec, dict) and "alarmed" in rec:
                self.alarmed.add(str(rec["alarmed"]))
            elif isinstance(rec, dict) and isinstance(rec.get("id"), str):
                self.ids.add(rec["id"])
                self.seq = max(self.seq, int(rec.get("seq", 0)))
                self.recent.append(rec)
                self.recovered += 1

    def _write(self, obj: dict) -> bool:
        line = json.dumps(obj, allow_nan=False).encode() + b"\n"
        with self._cond:                           # (the alarm thread writes too; never to a closed file)
            if self._fh is None:
                return False
            self._fh.write(line)                   # unbuffered: one write(2)
            self.written += 1
            self._cond.notify_all()
        return True

    def _sync_loop(self) -> None:
        """The syncer thread: fsync whatever was written since the last pass (group commit), until closed."""
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self.written > self.synced or self._fh is None)
                fh, target = self._fh, self.written
            if fh is None:
                return
            try:
                os.fsync(fh.fileno())
            except ValueError:                     # closed under us: close() syncs what is left
                return
            except OSError as exc:                 # a failing disk: said in the metrics, tried again next write
                self.sync_errors += 1
                self.last_sync_error = f"{type(exc).__name__}: {exc}"
                with self._cond:
                    self._cond.wait_for(lambda: self.written > target or self._fh is None, timeout=1.0)
                continue
            with self._cond:
                self.synced = max(self.synced, target)
                self._cond.notify_all()

    def sync(self, timeout: float | None = None) -> bool:
        """Wait until every line written so far is fsync-ed; False if ``timeout`` [s] passed first.

        Parameters
        ----------
        timeout : float, optional
            Longest wait [s] (default: no limit).
        """
        with self._cond:
            target = self.written
            return self._fh is None or self._cond.wait_for(lambda: self.synced >= target, timeout)

    def append(self, record: dict) -> dict | None:
        """Log an event (written on return, fsync-ed by the syncer thread); None when its id is already logged.

        Parameters
        ----------
        record : dict
            The event record (strict-JSON values); gets ``seq``, the log's running number.
        """
        if record["id"] in self.ids:
            return None
        self.seq += 1
        record = {**record, "seq": self.seq}
        self._write(record)
        self.ids.add(record["id"])
        self.recent.append(record)
        return record

    def note(self, record: dict) -> None:
        """Write a line that is no event (an audit note: who held a machine when); skipped when read back.

        Parameters
        ----------
        record : dict
            Strict-JSON values, with neither ``id`` nor ``ack``.
        """
        if "id" in record or "ack" in record or "alarmed" in record:
            raise ValueError("a note has neither 'id', 'ack' nor 'alarmed' (those lines are events, acknowledgements "
                             "and delivered alarms)")
        self._write(record)

    def mark_alarmed(self, event_id: str) -> bool:
        """Record that the broker acknowledged an event's alarm (an ``{"alarmed": id}`` line); False when closed.

        Parameters
        ----------
        event_id : str
            The event's id.
        """
        if not self._write({"alarmed": event_id, "at": time.time()}):
            return False
        self.alarmed.add(event_id)
        return True

    def unalarmed(self, within_s: float = REALARM_S) -> list[dict]:
        """Events detected in the last ``within_s`` seconds whose alarm the broker never acknowledged.

        Parameters
        ----------
        within_s : float
            How far back [s] (by the events' wall-clock ``detected`` time).
        """
        since = time.time() - within_s
        return [r for r in self.recent if r["id"] not in self.alarmed and float(r.get("detected", 0.0)) >= since]

    def acknowledge(self, event_id: str, by: str = "") -> dict:
        """Mark an event acknowledged (an ``{"ack": id}`` line in the log); once: acknowledging it again
        returns the first acknowledgement (who and when) unchanged.

        Parameters
        ----------
        event_id : str
            The event's id.
        by : str
            Who acknowledged it.

        Raises
        ------
        KeyError
            No event with this id (a :class:`~drivesense.errors.MissingChannelError`).
        """
        from drivesense.errors import MissingChannelError

        if event_id not in self.ids:
            raise MissingChannelError(f"no event with id {event_id!r}")
        if event_id in self.acknowledged:
            return self.acknowledged[event_id]
        ack = {"ack": event_id, "by": str(by)[:64], "at": time.time()}
        self._write(ack)
        self.sync(timeout=5.0)
        self.acknowledged[event_id] = ack
        return ack

    def since(self, seq: int = 0, limit: int = 1000) -> list[dict]:
        """Events with ``seq`` above the given one (oldest first), acknowledgement included.

        Parameters
        ----------
        seq : int
            Last seq the caller has.
        limit : int
            At most this many (the newest).
        """
        out = [{**r, "acknowledged": r["id"] in self.acknowledged} for r in self.recent if r["seq"] > seq]
        return out[-limit:]

    def close(self) -> None:
        """Sync what is written and close the file."""
        if self._fh is None:
            return
        self.sync(timeout=10.0)
        with self._cond:
            fh, self._fh = self._fh, None
            self._cond.notify_all()
        self._syncer.join()
        try:
            os.fsync(fh.fileno())
        except OSError as exc:
            self.sync_errors += 1
            self.last_sync_error = f"{type(exc).__name__}: {exc}"
        fh.close()


class AlarmPublisher:
    """Alarms (and stop requests) to an MQTT broker, QoS 1, reconnecting by itself.

    Parameters
    ----------
    url : str
        ``mqtt://HOST[:PORT]``.
    prefix : str
        Topic prefix (``""``: ``{machine}/alarm``).
    client_id : str
        MQTT client id.
    """

    def __init__(self, url: str, *, prefix: str = "", client_id: str = "drivesense-monitor") -> None:
        import paho.mqtt.client as mqtt

        from drivesense.monitor.mqtt import parse_mqtt_url

        self.host, self.port = parse_mqtt_url(url)
        self.prefix = prefix
        self.published = 0
        self.delivered = 0
        self.connected = False
        self._lock = threading.Lock()
        self._pending: dict[int, tuple | None] = {}   # mid -> (event id, logs to mark) of an unacknowledged alarm
        self._early: set[int] = set()                 # mids acknowledged before publish() filed them
        self._client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
        self._client.max_queued_messages_set(10000)
        self._client.reconnect_delay_set(0.2, 2.0)
        self._client.on_connect = lambda c, u, f, reason, p=None: setattr(self, "connected", not reason.is_failure)
        self._client.on_disconnect = lambda c, u, f, reason, p=None: setattr(self, "connected", False)
        self._client.on_publish = self._on_publish
        self._client.connect_async(self.host, self.port, keepalive=10)
        self._client.loop_start()

    def _on_publish(self, client, userdata, mid, reason_code=None, properties=None) -> None:
        """The broker acknowledged a message (paho's thread, under paho's lock: never wait on ours there)."""
        with self._lock:
            if mid not in self._pending:
                self._early.add(mid)
                return
            entry = self._pending.pop(mid)
        self._delivered(entry)

    def _delivered(self, entry: tuple | None) -> None:
        if entry is None:                              # a stop request
            return
        event_id, logs = entry
        for log in logs:
            log.mark_alarmed(event_id)
        self.delivered += 1

    def _file(self, mid: int, entry: tuple | None) -> None:
        with self._lock:
            early = mid in self._early
            if early:
                self._early.discard(mid)
            else:
                self._pending[mid] = entry
        if early:
            self._delivered(entry)

    def publish(self, record: dict, logs: tuple = ()) -> None:
        """Publish one event on ``{prefix}{machine}/alarm`` (and ``/stop`` for :data:`STOP_KINDS`).

        Parameters
        ----------
        record : dict
            The logged event record.
        logs : tuple of EventLog
            Logs to mark the alarm delivered in (:meth:`EventLog.mark_alarmed`) once the broker acknowledges it.
        """
        payload = {**record, "published": time.time()}
        info = self._client.publish(f"{self.prefix}{record['machine']}/alarm", json.dumps(payload, allow_nan=False),
                                    qos=1)
        self._file(info.mid, (record["id"], tuple(logs)))
        if record["kind"] in STOP_KINDS and not record.get("republished"):
            stop = {"machine": record["machine"], "event_id": record["id"], "kind": record["kind"],
                    "reason": f"{record['kind']} on axis {record['axis']} at {record['time_s']:.4f} s",
                    "requested": payload["published"]}
            self._file(self._client.publish(f"{self.prefix}{record['machine']}/stop", json.dumps(stop), qos=1).mid,
                       None)
        self.published += 1

    def republish(self, log: "EventLog") -> int:
        """Alarm again the recent events of ``log`` whose alarm the broker never acknowledged; how many.

        Parameters
        ----------
        log : EventLog
            A log read back after a restart, or a machine's log a fleet worker took over.
        """
        todo = log.unalarmed()
        for record in todo:
            self.publish({**record, "republished": True}, (log,))
        return len(todo)

    def undelivered(self, log: "EventLog | None" = None) -> int:
        """Alarms the broker has not acknowledged yet (those to be marked in ``log``, if given).

        Parameters
        ----------
        log : EventLog, optional
            Count only the alarms of this log.
        """
        with self._lock:
            return sum(1 for e in self._pending.values() if e is not None and (log is None or log in e[1]))

    def close(self, timeout: float = 2.0) -> None:
        """Send what is queued and wait for the broker's acknowledgements (up to ``timeout`` [s]), then disconnect.

        Parameters
        ----------
        timeout : float
            Longest wait [s]; an alarm still unacknowledged then is alarmed again at the next start.
        """
        deadline = time.time() + timeout
        while (self._client.want_write() or self.undelivered()) and self.connected and time.time() < deadline:
            time.sleep(0.01)
        self._client.disconnect()
        self._client.loop_stop()


class _Worker:
    """A daemon thread draining a bounded queue of items into ``handle``."""

    def __init__(self, name: str, maxsize: int) -> None:
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.dropped = 0
        self.failed = 0
        self.done = 0
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def offer(self, item: Any) -> bool:
        """Queue an item without waiting; False (and counted as dropped) when the queue is full.

        Parameters
        ----------
        item : object
            What :meth:`handle` gets.
        """
        try:
            self.queue.put_nowait(item)
            return True
        except queue.Full:
            self.dropped += 1
            return False

    def _loop(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            try:
                self.handle(item)
                self.done += 1
            except Exception as exc:  # noqa: BLE001 - a failing output never stops the service; counted
                self.failed += 1
                self.last_error = f"{type(exc).__name__}: {exc}"

    def handle(self, item: Any) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self, timeout: float = 10.0) -> None:
        """Finish what is queued, then stop the thread.

        Parameters
        ----------
        timeout : float
            Wait at most this long [s].
        """
        self.queue.put(None)
        self._thread.join(timeout)


class Webhook(_Worker):
    """POST each event as JSON to a URL, from a worker thread (3 tries; failures counted, never blocking).

    Parameters
    ----------
    url : str
        ``http://`` or ``https://`` URL.
    timeout : float
        Per request [s].
    """

    def __init__(self, url: str, *, timeout: float = 5.0) -> None:
        if not str(url).startswith(("http://", "https://")):
            raise ConfigError(f"webhook must be an http:// or https:// URL, got {url!r}")
        self.url = str(url)
        self.timeout = float(timeout)
        super().__init__("drivesense-webhook", 1000)

    def handle(self, item: dict) -> None:
        """POST one record (retrying twice).

        Parameters
        ----------
        item : dict
            The event record.
        """
        body = json.dumps(item, allow_nan=False).encode()
        for attempt in range(3):
            try:
                req = urllib.request.Request(self.url, data=body, headers={"Content-Type": "application/json"})
                with urllib.request.urlopen(req, timeout=self.timeout) as resp:
                    resp.read()
                return
            except OSError:
                if attempt == 2:
                    raise
                time.sleep(0.2 * (attempt + 1))


class ArchiveWriter(_Worker):
    """Events and their segments into an archive, from a worker thread.

    Parameters
    ----------
    location : str or Path
        SQLite file or PostgreSQL DSN (``--archive``).
    """

    def __init__(self, location: str | Path) -> None:
        from drivesense.archive import open_archive

        self.location = str(location)
        self.store = open_archive(location)
        super().__init__("drivesense-archive", 10000)

    def catch_up(self, records) -> int:
        """Queue every logged event the archive lacks (after a restart); how many.

        Parameters
        ----------
        records : iterable of dict
            Logged event records.
        """
        n = 0
        for r in records:
            if not self.store.has_event(r["id"]):
                self.offer((r, None))
                n += 1
        return n

    def handle(self, item) -> None:
        """Store one ``(record, segment)``.

        Parameters
        ----------
        item : tuple
            The record and its :class:`~drivesense.monitor.machine.Segment` (or None).
        """
        record, segment = item
        self.store.add_event({k: v for k, v in record.items() if k != "acknowledged"},
                             None if segment is None else segment.recording())

    def close(self, timeout: float = 30.0) -> None:
        """Finish what is queued and close the archive.

        Parameters
        ----------
        timeout : float
            Wait at most this long [s].
        """
        super().close(timeout)
        self.store.close()
