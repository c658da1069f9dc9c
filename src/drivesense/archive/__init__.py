"""The experiment archive: search everything you ever recorded (second paper, Sec. 7).

>>> import drivesense as ds
>>> with ds.archive.open_archive("lab.sqlite") as store:      # doctest: +SKIP
...     eid = store.add("cut_03.xml")                          # or a Recording, or a .nc file
...     hits = store.search("aluminium", machine="haas", start={"feed_rate": (0.05, 0.2)})
...     store.export(hits[0].id, "copy.xml")

One protocol (:class:`ExperimentStore`), two backends: :class:`SqliteStore`
(embedded, the default; a file in the user's data folder) and
:class:`PostgresStore` (a server, via psycopg).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .sqlite import SqliteStore, default_archive_path
from .store import ExperimentStore, SearchHit, parse_query, tokenize

__all__ = ["ExperimentStore", "SearchHit", "SqliteStore", "PostgresStore", "open_archive",
           "default_archive_path", "tokenize", "parse_query"]


def open_archive(location: str | Path | None = None, *, create: bool = True, **kw: Any) -> ExperimentStore:
    """Open (creating if needed) an archive.

    Parameters
    ----------
    location : str or Path, optional
        A SQLite file path, or a PostgreSQL DSN (``postgresql://...`` or
        ``dbname=... host=...``); default :func:`default_archive_path`.
    create : bool, optional
        Create a missing SQLite archive (default).  False for reading: a
        missing file or one that is no archive is an error naming the path
        (a PostgreSQL archive's schema is created on connecting, as before).
    **kw
        Passed to the store (``timeout``, ``synchronous`` for SQLite;
        ``schema`` for PostgreSQL).

    Returns
    -------
    ExperimentStore
    """
    from .postgres import is_postgres_dsn

    if is_postgres_dsn(location):
        from .postgres import PostgresStore

        return PostgresStore(str(location), **kw)
    return SqliteStore(location, create=create, **kw)


def __getattr__(name: str) -> Any:
    if name == "PostgresStore":  # imported lazily: psycopg is optional
        from .postgres import PostgresStore

        return PostgresStore
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
