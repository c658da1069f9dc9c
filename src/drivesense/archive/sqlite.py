"""The embedded archive: one SQLite file (WAL mode) with an FTS5 index; the shared SQL logic.

:class:`SQLArchive` holds everything both backends do the same way (imports in
one transaction, structured filters, loading, export); :class:`SqliteStore`
adds SQLite's connection handling, DDL and FTS5, :class:`~drivesense.archive.
postgres.PostgresStore` the PostgreSQL equivalents.  Queries are written with
``?`` placeholders and translated for psycopg.

Safety: SQLite runs in WAL mode with ``synchronous=FULL`` by default (a commit
is on disk when ``add`` returns); writers take the write lock up front
(``BEGIN IMMEDIATE``) and wait up to `timeout` seconds for each other, so
concurrent writer processes serialise instead of failing; a process killed
mid-import leaves only an uncommitted WAL tail, which SQLite discards.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from ..errors import ConfigError, DriveSenseError
from ..io import write_recording
from ..io.xml_format import Experiment, utc_now, write_xml
from ..recording import META_ATTR, Recording
from .events import EVENTS_DDL, EventsTable
from .store import (CHUNK_SAMPLES, FILTER_KEYS, SearchHit, as_experiment, check_ranges, like_pattern,
                    missing, normalise_time, parse_query, prepare, rows_to_hits)

__all__ = ["SQLArchive", "SqliteStore", "default_archive_path"]

_HIT_COLUMNS = ("e.id, e.created, e.name, e.machine, e.tool, e.material, e.operator, e.n_measurements, "
                "e.n_channels, e.n_samples")
_FIELDS = tuple(FILTER_KEYS)


def default_archive_path() -> Path:
    """Where the archive lives when none is given.

    Returns
    -------
    Path
        ``$DRIVESENSE_ARCHIVE`` if set, else ``$XDG_DATA_HOME/drivesense/archive.sqlite``
        (``~/.local/share/drivesense/archive.sqlite``).
    """
    env = os.environ.get("DRIVESENSE_ARCHIVE")
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "drivesense" / "archive.sqlite"


def _as_recording(arrays: dict[str, tuple[np.ndarray, str]], fs: float, t0: float, n: int,
                  meta_json: str) -> Recording:
    ds = xr.Dataset({k: ("time", a, {"units": u}) for k, (a, u) in arrays.items()},
                    attrs={"fs": fs, "t0": t0, META_ATTR: meta_json})
    return Recording(ds, validate=False)


class SQLArchive(EventsTable):
    """Backend-neutral archive logic over a DB-API connection (subclassed per database)."""

    location: str = ""
    _placeholder = "?"

    # -- hooks a backend provides
    @contextmanager
    def _write(self) -> Iterator[Any]:  # pragma: no cover - abstract
        raise NotImplementedError
        yield

    @contextmanager
    def _read(self) -> Iterator[Any]:  # pragma: no cover - abstract
        raise NotImplementedError
        yield

    def _index(self, cur: Any, pk: int, body: str) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _unindex(self, cur: Any, pk: int) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _fts(self, terms: list[tuple[list[str], bool]]) -> tuple[str, str, list, str, list]:  # pragma: no cover
        """(join, where, where params, order, order params) of a full-text condition."""
        raise NotImplementedError

    # -- shared
    def _q(self, sql: str) -> str:
        return sql if self._placeholder == "?" else sql.replace("?", self._placeholder)

    def _exec(self, cur: Any, sql: str, params: tuple | list = ()) -> Any:
        cur.execute(self._q(sql), params)
        return cur

    def add(self, source: Any) -> str:
        """Import one experiment, atomically.

        Parameters
        ----------
        source : str, Path, Recording, sequence of Recording or Experiment
            An ``.xml`` experiment file (streamed and validated), a ``.nc`` or
            ``.csv`` recording, Recording(s) (a new id, created now) or an
            :class:`~drivesense.io.xml_format.Experiment`.

        Returns
        -------
        str
            The experiment id.

        Raises
        ------
        ConfigError
            An experiment with this id is already archived.
        InvalidSignalError, UnitError
            The source cannot be read (nothing is stored).
        """
        prep = prepare(as_experiment(source))
        with self._write() as cur:
            self._insert_experiment(cur, prep)
        return prep.exp.id

    def _insert_experiment(self, cur: Any, prep: Any) -> None:
        """Insert one prepared experiment inside the caller's transaction."""
        exp, f = prep.exp, prep.fields
        recs = exp.recordings
        if self._exec(cur, "SELECT 1 FROM experiments WHERE id = ?", (exp.id,)).fetchone():
            raise ConfigError(f"experiment {exp.id!r} is already in the archive {self.location}; "
                              "remove it first to replace it")
        row = (exp.id, f["created"], utc_now(), exp.format_version, f["name"],
               *(f[k] for k in _FIELDS), *(f[k].casefold() for k in _FIELDS), len(recs),
               sum(len(r.channels) for r in recs), sum(len(r.channels) * r.n_samples for r in recs),
               json.dumps(list(exp.personnel)))
        pk = self._exec(cur, "INSERT INTO experiments(id, created, added, format_version, name, machine, "
                        "tool, material, operator, machine_cf, tool_cf, material_cf, operator_cf, "
                        "n_measurements, n_channels, n_samples, personnel) VALUES "
                        "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING pk", row).fetchone()[0]
        cur.executemany(self._q("INSERT INTO measurements VALUES (?, ?, ?, ?, ?, ?, ?)"),
                        [(pk, *m) for m in prep.measurements])
        cur.executemany(self._q("INSERT INTO channels VALUES (?, ?, ?, ?, ?, ?, ?, ?)"),
                        [(pk, *c) for c in prep.channels])
        if prep.states:
            cur.executemany(self._q("INSERT INTO states VALUES (?, ?, ?, ?, ?)"),
                            [(pk, *s) for s in prep.states])
        self._index(cur, pk, prep.body)
        for i, rec in enumerate(recs):
            for j, ch in enumerate(rec.channels):
                data = np.ascontiguousarray(rec[ch], dtype="<f8")
                for seq, k in enumerate(range(0, data.size, CHUNK_SAMPLES)):
                    self._exec(cur, "INSERT INTO samples VALUES (?, ?, ?, ?, ?)",
                               (pk, i, j, seq, memoryview(data[k:k + CHUNK_SAMPLES]).cast("B")))

    def search(self, text: str | None = None, *, machine: str | None = None, tool: str | None = None,
               material: str | None = None, operator: str | None = None, since: Any = None,
               until: Any = None, start: dict | None = None, end: dict | None = None,
               limit: int = 50) -> list[SearchHit]:
        """Find experiments; never reads samples.

        Parameters
        ----------
        text : str, optional
            Words that must all occur somewhere in the document (any key,
            value, name, unit, experimenter...); ``"quoted phrase"``, ``word*``
            for a prefix.  Case and accents are ignored.
        machine, tool, material, operator : str, optional
            Case-insensitive substring of the field (values found under those
            keys in the metadata; experimenters are operators).
        since, until : str, date or datetime, optional
            Creation time range (inclusive; a bare date ``until`` includes that day).
        start, end : dict, optional
            Numeric ranges of start/end state values: ``{"feed_rate": (0.05, 0.2)}``
            (dotted keys for nested values, None for an open end); an experiment
            matches when one of its measurements has the value in range.
        limit : int, optional
            Most hits returned (default 50).

        Returns
        -------
        list of SearchHit
            Best text match first (newest first without `text`).
        """
        if not isinstance(limit, int) or limit < 1:
            raise ConfigError(f"limit must be a positive integer, got {limit!r}")
        conds, params = [], []
        for key, value in zip(_FIELDS, (machine, tool, material, operator)):
            if value:
                conds.append(f"e.{key}_cf LIKE ? ESCAPE '\\'")
                params.append(like_pattern(value))
        if since is not None:
            conds.append("e.created >= ?")
            params.append(normalise_time(since))
        if until is not None:
            conds.append("e.created <= ?")
            params.append(normalise_time(until, end=True))
        for which, ranges in (("start", start), ("end", end)):
            for key, low, high in check_ranges(ranges, which):
                sub = "e.pk IN (SELECT s.exp FROM states s WHERE s.which = ? AND s.key = ?"  # uncorrelated
                params += [which, key]
                for op, bound in ((">=", low), ("<=", high)):
                    if bound is not None:
                        sub += f" AND s.value {op} ?"
                        params.append(bound)
                conds.append(sub + ")")
        terms = parse_query(text)
        join, order, order_params = "", "e.created DESC, e.id", []
        if terms:
            join, where, where_params, rank, order_params = self._fts(terms)
            conds.insert(0, where)
            params = where_params + params
            order = f"{rank}, e.created DESC, e.id"
        sql = (f"SELECT {_HIT_COLUMNS} FROM experiments e {join} "
               f"{'WHERE ' + ' AND '.join(conds) if conds else ''} ORDER BY {order} LIMIT ?")
        with self._read() as cur:
            return rows_to_hits(self._exec(cur, sql, [*params, *order_params, limit]).fetchall())

    def resolve(self, prefix: str) -> str:
        """The full id of the experiment whose id is or starts with `prefix`.

        Parameters
        ----------
        prefix : str
            An id or a unique prefix of one.

        Returns
        -------
        str

        Raises
        ------
        MissingChannelError
            No such experiment (a KeyError).
        ConfigError
            The prefix matches several.
        """
        if not isinstance(prefix, str) or not prefix:
            raise ConfigError(f"experiment id must be a non-empty string, got {prefix!r}")
        with self._read() as cur:
            if self._exec(cur, "SELECT 1 FROM experiments WHERE id = ?", (prefix,)).fetchone():
                return prefix
            pattern = prefix.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"
            ids = [r[0] for r in self._exec(cur, "SELECT id FROM experiments WHERE id LIKE ? ESCAPE '\\' "
                                                 "ORDER BY id LIMIT 4", (pattern,)).fetchall()]
        if not ids:
            raise missing(prefix, self.location)
        if len(ids) > 1:
            raise ConfigError(f"experiment id prefix {prefix!r} is ambiguous ({', '.join(ids[:3])}, ...)")
        return ids[0]

    def _pk(self, cur: Any, id: str) -> tuple:
        row = self._exec(cur, "SELECT pk, id, created, added, format_version, name, machine, tool, material, "
                              "operator, n_measurements, n_channels, n_samples, personnel FROM experiments "
                              "WHERE id = ?", (id,)).fetchone()
        if row is None:
            raise missing(id, self.location)
        return row

    def show(self, id: str) -> dict:
        """Metadata of one experiment, without its samples.

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).

        Returns
        -------
        dict
            id, created, added, format_version, the filter fields, personnel,
            and per measurement: name, fs [Hz], t0 [s], samples, duration [s],
            meta, channels (name, units [SI], interface, sensor).
        """
        id = self.resolve(id)
        with self._read() as cur:
            row = self._pk(cur, id)
            meas = self._exec(cur, "SELECT idx, name, fs, t0, n_samples, meta FROM measurements WHERE exp = ? "
                                   "ORDER BY idx", (row[0],)).fetchall()
            chans = self._exec(cur, "SELECT meas, name, units, interface, sensor FROM channels WHERE exp = ? "
                                    "ORDER BY meas, idx", (row[0],)).fetchall()
        out = dict(zip(("id", "created", "added", "format_version", "name", "machine", "tool", "material",
                        "operator", "n_measurements", "n_channels", "n_samples"), row[1:13]))
        out["personnel"] = json.loads(row[13])
        out["measurements"] = [
            {"name": m[1], "fs_hz": m[2], "t0_s": m[3], "samples": m[4], "duration_s": m[4] / m[2],
             "meta": json.loads(m[5]),
             "channels": [dict(zip(("name", "units", "interface", "sensor"), c[1:])) for c in chans
                          if c[0] == m[0]]} for m in meas]
        return out

    def load(self, id: str) -> Experiment:
        """One experiment with its samples (bit-exact as imported).

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).

        Returns
        -------
        Experiment
        """
        id = self.resolve(id)
        recs = []
        with self._read() as cur:
            row = self._pk(cur, id)
            pk = row[0]
            meas = self._exec(cur, "SELECT idx, fs, t0, n_samples, meta FROM measurements WHERE exp = ? "
                                   "ORDER BY idx", (pk,)).fetchall()
            for idx, fs, t0, n, meta_json in meas:
                arrays = {}
                for j, name, units in self._exec(cur, "SELECT idx, name, units FROM channels WHERE exp = ? AND "
                                                      "meas = ? ORDER BY idx", (pk, idx)).fetchall():
                    data, pos = np.empty(n, np.float64), 0
                    for (blob,) in self._exec(cur, "SELECT data FROM samples WHERE exp = ? AND meas = ? AND "
                                                   "chan = ? ORDER BY seq", (pk, idx, j)):
                        chunk = np.frombuffer(blob, "<f8")
                        data[pos:pos + chunk.size] = chunk
                        pos += chunk.size
                    if pos != n:
                        raise DriveSenseError(f"archive {self.location}: experiment {id}, channel {name!r} "
                                              f"has {pos} of {n} samples")
                    arrays[name] = (data, units)
                recs.append(_as_recording(arrays, float(fs), float(t0), int(n), meta_json))
        return Experiment(tuple(recs), id, row[2], row[4], tuple(json.loads(row[13])))

    def export(self, id: str, path: str | Path, *, measurement: int | None = None) -> Path:
        """Write one experiment to a file, atomically.

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).
        path : str or Path
            ``.xml`` (the whole experiment, same id and creation time) or
            ``.nc`` / ``.csv`` (one measurement).
        measurement : int, optional
            Which measurement for ``.nc`` / ``.csv`` (0-based; may be left out
            when there is one).

        Returns
        -------
        Path
        """
        exp = self.load(id)
        path = Path(path)
        if path.suffix.lower() == ".xml":
            return write_xml(exp, path)
        if measurement is None and len(exp.recordings) > 1:
            raise ConfigError(f"experiment {exp.id} has {len(exp.recordings)} measurements: choose one "
                              "for a .nc/.csv file, or export .xml")
        rec = exp.recordings[measurement or 0]
        if path.suffix.lower() not in (".nc", ".csv"):
            raise ConfigError(f"{path}: export to .xml, .nc or .csv")
        return write_recording(rec, path)

    def remove(self, id: str) -> None:
        """Delete one experiment (metadata, index and samples), atomically.

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).
        """
        id = self.resolve(id)
        with self._write() as cur:
            pk = self._pk(cur, id)[0]
            for table in ("samples", "states", "channels", "measurements"):
                self._exec(cur, f"DELETE FROM {table} WHERE exp = ?", (pk,))
            self._unindex(cur, pk)
            self._exec(cur, "DELETE FROM experiments WHERE pk = ?", (pk,))

    def count(self) -> int:
        """Number of experiments in the archive.

        Returns
        -------
        int
        """
        with self._read() as cur:
            return int(self._exec(cur, "SELECT count(*) FROM experiments").fetchone()[0])

    def __enter__(self) -> SQLArchive:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden
        """Release the connection."""

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.location}>"


_DDL = """
CREATE TABLE IF NOT EXISTS experiments(
  pk INTEGER PRIMARY KEY, id TEXT NOT NULL UNIQUE, created TEXT NOT NULL, added TEXT NOT NULL,
  format_version TEXT NOT NULL, name TEXT NOT NULL,
  machine TEXT NOT NULL, tool TEXT NOT NULL, material TEXT NOT NULL, operator TEXT NOT NULL,
  machine_cf TEXT NOT NULL, tool_cf TEXT NOT NULL, material_cf TEXT NOT NULL, operator_cf TEXT NOT NULL,
  n_measurements INTEGER NOT NULL, n_channels INTEGER NOT NULL, n_samples INTEGER NOT NULL,
  personnel TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS experiments_created ON experiments(created);
CREATE TABLE IF NOT EXISTS measurements(exp INTEGER NOT NULL, idx INTEGER NOT NULL, name TEXT NOT NULL,
  fs REAL NOT NULL, t0 REAL NOT NULL, n_samples INTEGER NOT NULL, meta TEXT NOT NULL, PRIMARY KEY(exp, idx));
CREATE TABLE IF NOT EXISTS channels(exp INTEGER NOT NULL, meas INTEGER NOT NULL, idx INTEGER NOT NULL,
  name TEXT NOT NULL, units TEXT NOT NULL, interface TEXT NOT NULL, sensor TEXT NOT NULL,
  n_samples INTEGER NOT NULL, PRIMARY KEY(exp, meas, idx));
CREATE TABLE IF NOT EXISTS samples(exp INTEGER NOT NULL, meas INTEGER NOT NULL, chan INTEGER NOT NULL,
  seq INTEGER NOT NULL, data BLOB NOT NULL, PRIMARY KEY(exp, meas, chan, seq));
CREATE TABLE IF NOT EXISTS states(exp INTEGER NOT NULL, meas INTEGER NOT NULL, which TEXT NOT NULL,
  key TEXT NOT NULL, value REAL NOT NULL);
CREATE INDEX IF NOT EXISTS states_key ON states(which, key, value);
CREATE INDEX IF NOT EXISTS states_exp ON states(exp);
CREATE VIRTUAL TABLE IF NOT EXISTS fts USING fts5(body, tokenize = 'unicode61 remove_diacritics 2');
"""


class SqliteStore(SQLArchive):
    """The embedded archive: a SQLite file in WAL mode with an FTS5 full-text index.

    Parameters
    ----------
    path : str or Path, optional
        The database file (created with its folder if missing, unless
        `create` is false); default :func:`default_archive_path`.
    timeout : float, optional
        How long a writer waits for another one [s] (default 60).
    synchronous : {"FULL", "NORMAL"}, optional
        ``FULL`` (default): every import is on disk when :meth:`add` returns;
        ``NORMAL``: faster, still never corrupt, but the last imports can be
        lost on power failure (not on a crash of the process).
    create : bool, optional
        Create the archive if missing (default).  False (searching, showing,
        exporting, removing): a missing file raises FileNotFoundError and a
        file that is no drivesense archive ConfigError; nothing is created.
    """

    def __init__(self, path: str | Path | None = None, *, timeout: float = 60.0,
                 synchronous: str = "FULL", create: bool = True) -> None:
        if synchronous not in ("FULL", "NORMAL"):
            raise ConfigError(f"synchronous must be 'FULL' or 'NORMAL', got {synchronous!r}")
        self.path = Path(path).expanduser() if path is not None else default_archive_path()
        self.location = str(self.path)
        if not create and not self.path.is_file():
            raise FileNotFoundError(f"archive '{self.path}' does not exist (drivesense archive add creates one)")
        if create:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._timeout = float(timeout)
        try:
            self._conn = sqlite3.connect(self.path, timeout=self._timeout, isolation_level=None,
                                         check_same_thread=False)
            self._conn.execute(f"PRAGMA busy_timeout = {int(self._timeout * 1000)}")
            if not create and not self._conn.execute(
                    "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'experiments'").fetchone():
                self._conn.close()
                raise ConfigError(f"{self.path}: not a drivesense archive (no experiments in it; "
                                  "drivesense archive add creates one)")
            self._retry(lambda: self._conn.execute("PRAGMA journal_mode = WAL").fetchone())
            self._conn.execute(f"PRAGMA synchronous = {synchronous}")
            with self._write() as cur:
                for stmt in filter(str.strip, (_DDL + ";" + EVENTS_DDL).split(";")):
                    cur.execute(stmt)
        except sqlite3.DatabaseError as exc:
            raise ConfigError(f"{self.path}: not a usable drivesense archive ({exc})") from None

    def _retry(self, fn: Any) -> Any:
        deadline = time.monotonic() + self._timeout
        while True:
            try:
                return fn()
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) and "busy" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(0.01)

    @contextmanager
    def _write(self) -> Iterator[Any]:
        cur = self._conn.cursor()
        self._retry(lambda: cur.execute("BEGIN IMMEDIATE"))
        try:
            yield cur
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._retry(lambda: cur.execute("COMMIT"))

    @contextmanager
    def _read(self) -> Iterator[Any]:
        cur = self._conn.cursor()
        cur.execute("BEGIN")
        try:
            yield cur
        finally:
            cur.execute("COMMIT")

    def _index(self, cur: Any, pk: int, body: str) -> None:
        cur.execute("INSERT INTO fts(rowid, body) VALUES (?, ?)", (pk, body))

    def _unindex(self, cur: Any, pk: int) -> None:
        cur.execute("DELETE FROM fts WHERE rowid = ?", (pk,))

    def _fts(self, terms: list[tuple[list[str], bool]]) -> tuple[str, str, list, str, list]:
        match = " AND ".join('"' + " ".join(toks) + '"' + ("*" if prefix else "") for toks, prefix in terms)
        return "JOIN fts ON fts.rowid = e.pk", "fts MATCH ?", [match], "fts.rank", []

    def close(self) -> None:
        """Close the database connection."""
        self._conn.close()
