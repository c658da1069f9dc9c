"""The server archive: PostgreSQL via psycopg 3, with the same API as the SQLite store.

Install with ``pip install "drivesense[postgres]"``.  Tables live in their own
schema (default ``drivesense``), created on first use under an advisory lock so
that several processes can start at once.  Full text uses a ``tsvector``
column with a GIN index over the same pre-tokenised words as SQLite's FTS5
(the ``simple`` configuration: no stemming, no stop words), so both backends
find the same experiments.  Samples are ``bytea`` chunks.  Every import is one
transaction; a client killed mid-import leaves nothing behind.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from ..errors import ConfigError
from .events import EVENTS_DDL
from .sqlite import SQLArchive

__all__ = ["PostgresStore", "is_postgres_dsn"]

_DDL = """
CREATE TABLE IF NOT EXISTS experiments(
  pk BIGSERIAL PRIMARY KEY, id TEXT NOT NULL UNIQUE, created TEXT NOT NULL, added TEXT NOT NULL,
  format_version TEXT NOT NULL, name TEXT NOT NULL,
  machine TEXT NOT NULL, tool TEXT NOT NULL, material TEXT NOT NULL, operator TEXT NOT NULL,
  machine_cf TEXT NOT NULL, tool_cf TEXT NOT NULL, material_cf TEXT NOT NULL, operator_cf TEXT NOT NULL,
  n_measurements INTEGER NOT NULL, n_channels INTEGER NOT NULL, n_samples BIGINT NOT NULL,
  personnel TEXT NOT NULL, fts TSVECTOR);
CREATE INDEX IF NOT EXISTS experiments_created ON experiments(created);
CREATE INDEX IF NOT EXISTS experiments_fts ON experiments USING GIN(fts);
CREATE TABLE IF NOT EXISTS measurements(exp BIGINT NOT NULL, idx INTEGER NOT NULL, name TEXT NOT NULL,
  fs DOUBLE PRECISION NOT NULL, t0 DOUBLE PRECISION NOT NULL, n_samples BIGINT NOT NULL, meta TEXT NOT NULL,
  PRIMARY KEY(exp, idx));
CREATE TABLE IF NOT EXISTS channels(exp BIGINT NOT NULL, meas INTEGER NOT NULL, idx INTEGER NOT NULL,
  name TEXT NOT NULL, units TEXT NOT NULL, interface TEXT NOT NULL, sensor TEXT NOT NULL,
  n_samples BIGINT NOT NULL, PRIMARY KEY(exp, meas, idx));
CREATE TABLE IF NOT EXISTS samples(exp BIGINT NOT NULL, meas INTEGER NOT NULL, chan INTEGER NOT NULL,
  seq INTEGER NOT NULL, data BYTEA NOT NULL, PRIMARY KEY(exp, meas, chan, seq));
CREATE TABLE IF NOT EXISTS states(exp BIGINT NOT NULL, meas INTEGER NOT NULL, which TEXT NOT NULL,
  key TEXT NOT NULL, value DOUBLE PRECISION NOT NULL);
CREATE INDEX IF NOT EXISTS states_key ON states(which, key, value);
CREATE INDEX IF NOT EXISTS states_exp ON states(exp)
"""


def is_postgres_dsn(location: Any) -> bool:
    """Whether `location` is a PostgreSQL connection string rather than a file path.

    Parameters
    ----------
    location : str or Path

    Returns
    -------
    bool
        ``postgresql://...``, ``postgres://...`` or a ``key=value`` DSN with ``dbname=``/``host=``.
    """
    return isinstance(location, str) and bool(
        re.match(r"^postgres(ql)?://", location) or re.search(r"(^|\s)(dbname|host|service)=", location))


class PostgresStore(SQLArchive):
    """The archive in a PostgreSQL database (same API as :class:`~drivesense.archive.SqliteStore`).

    Parameters
    ----------
    dsn : str
        libpq connection string, e.g. ``"postgresql://user:pw@host/db"`` or
        ``"dbname=drivesense host=/var/run/postgresql"``.
    schema : str, optional
        Schema holding the tables (created if missing; default ``"drivesense"``).
    connect_timeout : float, optional
        Connection timeout [s] (default 10).
    """

    _placeholder = "%s"

    def __init__(self, dsn: str, *, schema: str = "drivesense", connect_timeout: float = 10.0) -> None:
        try:
            import psycopg
            from psycopg import sql
        except ImportError:  # pragma: no cover - depends on the installation
            raise ConfigError("the PostgreSQL archive needs psycopg: pip install 'drivesense[postgres]'") from None
        if not isinstance(schema, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,62}", schema):
            raise ConfigError(f"schema must be a plain SQL identifier, got {schema!r}")
        self.location = f"{_redact(dsn)} (schema {schema})"
        try:
            self._conn = psycopg.connect(dsn, autocommit=True, connect_timeout=max(1, int(connect_timeout)))
        except psycopg.Error as exc:
            raise ConfigError(f"cannot connect to PostgreSQL at {_redact(dsn)}: "
                              f"{str(exc).strip().splitlines()[0]}") from None
        self._conn.execute(sql.SQL("SET search_path TO {}").format(sql.Identifier(schema)))
        with self._write() as cur:
            cur.execute("SELECT pg_advisory_xact_lock(hashtext('drivesense archive schema'))")
            cur.execute(sql.SQL("CREATE SCHEMA IF NOT EXISTS {}").format(sql.Identifier(schema)))
            for stmt in filter(str.strip, (_DDL + ";" + EVENTS_DDL).split(";")):
                cur.execute(stmt)

    @contextmanager
    def _write(self) -> Iterator[Any]:
        with self._conn.transaction(), self._conn.cursor() as cur:
            yield cur

    @contextmanager
    def _read(self) -> Iterator[Any]:
        with self._conn.transaction(), self._conn.cursor() as cur:
            yield cur

    def _index(self, cur: Any, pk: int, body: str) -> None:
        cur.execute("UPDATE experiments SET fts = to_tsvector('simple', %s) WHERE pk = %s", (body, pk))

    def _unindex(self, cur: Any, pk: int) -> None:
        pass  # the index lives in the experiments row

    def _fts(self, terms: list[tuple[list[str], bool]]) -> tuple[str, str, list, str, list]:
        parts = []
        for toks, prefix in terms:
            words = [f"'{t}'" for t in toks]
            if prefix:
                words[-1] += ":*"
            parts.append("(" + " <-> ".join(words) + ")")
        query = " & ".join(parts)
        return ("", "e.fts @@ to_tsquery('simple', ?)", [query],
                "ts_rank(e.fts, to_tsquery('simple', ?)) DESC", [query])

    def close(self) -> None:
        """Close the database connection."""
        self._conn.close()


def _redact(dsn: str) -> str:
    return re.sub(r"(://[^:/@]*:)[^@]*@", r"\1***@", re.sub(r"password=\S+", "password=***", dsn))
