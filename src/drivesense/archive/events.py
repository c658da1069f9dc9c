"""The archive's events table: process events a live monitor detected, linked to their signal segment.

::

    store.add_event(record, segment)        # one transaction: the segment (an experiment) and the event row
    store.has_event(record["id"])
    store.events(machine="vmc1", kind="breakage")

An event record is the monitor's JSON (``id``, ``machine``, ``kind``,
``time_s``, ``axis``, ``detector``, ``confidence``, ``detected`` [s since the
epoch], evidence...).  Its id is the primary key: adding an event twice
(a service restarted after a crash replays what it had seen) stores it once.
The segment -- the drive signals and forces around the event -- is stored as
an ordinary experiment (searchable, exportable), whose id the event row names.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from typing import Any

from drivesense.errors import ConfigError

__all__ = ["EventsTable", "EVENTS_DDL"]

#: The table (both backends).
EVENTS_DDL = """
CREATE TABLE IF NOT EXISTS events(id TEXT PRIMARY KEY, machine TEXT NOT NULL, kind TEXT NOT NULL,
  time_s DOUBLE PRECISION NOT NULL, detected TEXT NOT NULL, axis TEXT NOT NULL, detector TEXT NOT NULL,
  confidence DOUBLE PRECISION NOT NULL, experiment TEXT, record TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS events_machine ON events(machine, detected)
"""

_REQUIRED = {"id": str, "machine": str, "kind": str, "time_s": (int, float), "axis": str, "detector": str}


def _check(record: dict) -> None:
    if not isinstance(record, dict):
        raise ConfigError(f"an event record is a dict, got {type(record).__name__}")
    for key, kind in _REQUIRED.items():
        if not isinstance(record.get(key), kind) or isinstance(record.get(key), bool):
            raise ConfigError(f"event record field '{key}' is missing or invalid: {record.get(key)!r}")


def _iso(epoch: Any) -> str:
    if isinstance(epoch, (int, float)) and not isinstance(epoch, bool):
        return datetime.fromtimestamp(float(epoch), tz=timezone.utc).isoformat(timespec="milliseconds")
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


class EventsTable:
    """Events methods of the SQL archives (mixed into :class:`~drivesense.archive.sqlite.SQLArchive`)."""

    def has_event(self, id: str) -> bool:
        """Whether the event ``id`` is archived.

        Parameters
        ----------
        id : str
            Event id.
        """
        with self._read() as cur:
            return self._exec(cur, "SELECT 1 FROM events WHERE id = ?", (id,)).fetchone() is not None

    def add_event(self, record: dict, segment: Any = None) -> bool:
        """Archive one event and its signal segment, atomically; False when it was already there.

        Parameters
        ----------
        record : dict
            The event record (see the module docstring).
        segment : Recording, optional
            Drive signals and forces around the event: stored as an experiment named after the event.

        Returns
        -------
        bool
            True when stored now.

        Raises
        ------
        ConfigError
            A record without its id, machine, kind, time, axis or detector.
        """
        from drivesense.archive.store import as_experiment, prepare

        _check(record)
        prep = None
        if segment is not None:
            prep = prepare(as_experiment(segment))
        with self._write() as cur:
            if self._exec(cur, "SELECT 1 FROM events WHERE id = ?", (record["id"],)).fetchone():
                return False
            experiment = None
            if prep is not None:
                self._insert_experiment(cur, prep)
                experiment = prep.exp.id
            self._exec(cur, "INSERT INTO events(id, machine, kind, time_s, detected, axis, detector, confidence, "
                       "experiment, record) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                       (record["id"], record["machine"], record["kind"], float(record["time_s"]),
                        _iso(record.get("detected")), record["axis"], record["detector"],
                        float(record.get("confidence") or 0.0), experiment,
                        json.dumps(record, allow_nan=False)))
        return True

    def events(self, *, machine: str | None = None, kind: str | None = None, limit: int = 1000) -> list[dict]:
        """Archived events, newest first, each its record plus ``experiment`` (the segment's id or None).

        Parameters
        ----------
        machine : str, optional
            Only this machine's.
        kind : str, optional
            Only this kind.
        limit : int
            At most this many.
        """
        where, params = [], []
        if machine is not None:
            where.append("machine = ?")
            params.append(machine)
        if kind is not None:
            where.append("kind = ?")
            params.append(kind)
        sql = ("SELECT record, experiment FROM events" + (" WHERE " + " AND ".join(where) if where else "")
               + " ORDER BY detected DESC, id LIMIT ?")
        with self._read() as cur:
            rows = self._exec(cur, sql, (*params, int(limit))).fetchall()
        return [{**json.loads(r[0]), "experiment": r[1]} for r in rows]
