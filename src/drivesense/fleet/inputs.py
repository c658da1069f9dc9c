"""What a batch runs over: files matched by globs, or experiments an archive query finds.

Every input carries a *content* key: the BLAKE2b digest of a file's bytes (and of
a CSV's metadata sidecar ``FILE.csv.json``; a
cache next to the batch's results keeps the digests of files whose size and
modification time did not change, so a rerun over a folder of thousands of
recordings reads only the new ones), or, for an archived experiment, its id,
creation time and sample count (archived experiments are immutable: an id is
refused until the old one is removed).
"""

from __future__ import annotations

import glob
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

from drivesense.errors import ConfigError
from drivesense.fleet.jobs import file_digest

__all__ = ["BatchInput", "files_from_patterns", "file_inputs", "archive_inputs", "derived_id", "TRACE_SUFFIXES"]

#: What a folder given as an input contributes.
TRACE_SUFFIXES = (".nc", ".csv", ".xml")
#: Ids of the experiments a batch writes back into an archive (never inputs of a batch themselves).
_DERIVED = re.compile(r"-(estimate)-[0-9a-f]{12}$")


def derived_id(experiment: str, kind: str, key: str) -> str:
    """The id of a batch result written back into the archive: ``<experiment>-<kind>-<key[:12]>``.

    Parameters
    ----------
    experiment : str
        The input experiment's id.
    kind : str
        The job (``estimate``).
    key : str
        The input's batch key.
    """
    return f"{experiment}-{kind}-{key[:12]}"


@dataclass(frozen=True)
class BatchInput:
    """One input of a batch.

    Attributes
    ----------
    name : str
        What the summary calls it: the file path, or ``archive:<experiment id>``.
    content : str
        Content key (see the module docstring).
    path : str, optional
        The file.
    archive : str, optional
        Archive location (SQLite file or PostgreSQL DSN) of an archived experiment.
    experiment : str, optional
        Its id.
    machine : str
        The machine the experiment names (archive inputs), else ``""``.
    """

    name: str
    content: str
    path: str | None = None
    archive: str | None = None
    experiment: str | None = None
    machine: str = ""

    @property
    def stem(self) -> str:
        """A file-name-safe short name (the file's stem or the experiment id)."""
        raw = Path(self.path).stem if self.path else str(self.experiment)
        return "".join(c if c.isalnum() or c in "-_." else "_" for c in raw)[:60] or "input"

    def load(self, job):
        """The input as the job takes it: a Recording (traces), or the file path (wear session tables).

        Parameters
        ----------
        job : BatchJob
            The job (it knows how to read its traces).
        """
        if self.path is not None:
            return job.read_input(Path(self.path)) if hasattr(job, "read_input") else Path(self.path)
        from drivesense.archive import open_archive

        with open_archive(self.archive, create=False) as store:
            return store.load(self.experiment).recordings[0]


def files_from_patterns(patterns: list[str]) -> list[Path]:
    """Files named by glob patterns (``**`` recurses) or folders (their traces), sorted, each once.

    Parameters
    ----------
    patterns : list of str
        Globs, files or folders.

    Raises
    ------
    ConfigError
        A pattern that matches nothing.
    """
    found: dict[str, Path] = {}
    for pattern in patterns:
        p = Path(pattern)
        if p.is_dir():
            hits = [q for q in sorted(p.rglob("*")) if q.is_file() and q.suffix.lower() in TRACE_SUFFIXES]
        else:
            hits = [Path(h) for h in sorted(glob.glob(pattern, recursive=True)) if Path(h).is_file()]
        if not hits:
            raise ConfigError(f"input {pattern!r}: matches no file")
        for h in hits:
            found.setdefault(str(h.resolve()), h)
    return [found[k] for k in sorted(found)]


def file_inputs(paths: list[Path], cache: Path | None = None) -> list[BatchInput]:
    """Inputs for files, with their content digests (re-read only when size or mtime changed).

    Parameters
    ----------
    paths : list of Path
        The files.
    cache : Path, optional
        JSON cache of digests (created or updated atomically).
    """
    from drivesense.io import write_json_file

    known: dict = {}
    if cache is not None and cache.exists():
        try:
            known = json.loads(cache.read_text())
        except ValueError:
            known = {}                          # a damaged cache is only a cache: hash again
    from drivesense.io.csv import sidecar_path

    out, fresh = [], {}
    for p in paths:
        parts = [Path(p)]
        if Path(p).suffix.lower() == ".csv" and sidecar_path(p).exists():
            parts.append(sidecar_path(p))              # a CSV's metadata sidecar is part of its content
        digests = []
        for part in parts:
            st = os.stat(part)
            key = str(part.resolve())
            stamp = [st.st_size, st.st_mtime_ns]
            entry = known.get(key)
            digests.append(entry[2] if isinstance(entry, list) and entry[:2] == stamp else file_digest(part))
            fresh[key] = [*stamp, digests[-1]]
        out.append(BatchInput(name=str(p), content="file:" + "+".join(digests), path=str(p)))
    if cache is not None and fresh != {k: known.get(k) for k in fresh}:
        write_json_file(cache, {**known, **fresh}, indent=None)
    return out


def archive_inputs(location: str, *, query: str | None = None, machine: str | None = None,
                   limit: int | None = None) -> list[BatchInput]:
    """Inputs for the experiments an archive search finds (``drivesense archive search``'s words).

    The experiments batches wrote back (:func:`derived_id`) are left out.

    Parameters
    ----------
    location : str
        SQLite file or PostgreSQL DSN (``--archive``).
    query : str, optional
        Words that must all occur in the experiment (``--query``); None: every experiment.
    machine : str, optional
        Machine contains this text (``--machine``).
    limit : int, optional
        At most this many (default: all).
    """
    from drivesense.archive import open_archive

    with open_archive(location, create=False) as store:
        n = limit if limit is not None else max(1, store.count())
        hits = store.search(query or None, machine=machine, limit=n)
    if not hits:
        raise ConfigError(f"--archive {location}: the query {query or '(all)'!r} finds no experiment")
    hits = [h for h in hits if not _DERIVED.search(h.id)]       # results of earlier batches are no inputs
    if not hits:
        raise ConfigError(f"--archive {location}: the query {query or '(all)'!r} finds only results of batches")
    return [BatchInput(name=f"archive:{h.id}", content=f"archive:{h.id}:{h.created}:{h.samples}",
                       archive=str(location), experiment=h.id, machine=h.machine)
            for h in sorted(hits, key=lambda h: (h.created, h.id))]
