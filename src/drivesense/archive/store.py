"""The store protocol every archive backend implements, and what the backends share.

An archive holds experiments (:class:`~drivesense.io.xml_format.Experiment`:
measurements as Recordings, plus id and creation time).  For each it keeps

- the metadata (experiment row, one row per measurement with the Recording's
  exact metadata JSON, one row per channel with units, interface and sensor);
- a full-text index over every text of the document (keys, values, names,
  units, experimenters, foreign XML content), so that search terms need not
  be known when the data is stored;
- structured filter columns: machine, tool, material, operator (found under
  those keys anywhere in the metadata; experimenters count as operators),
  creation time, and every numeric value of the start/end states;
- the samples (float64, little-endian) in chunked blobs, which searches never
  read.

An import runs in one transaction: a failed or killed import leaves no trace.
Text is tokenised here (casefolded, accents stripped, split at anything that is
not a letter or digit), so both backends index and query the same words.
"""

from __future__ import annotations

import json
import re
import unicodedata
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import date, datetime, timezone
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from ..errors import ConfigError, MissingChannelError
from ..io.xml_format import Experiment, default_sensor, utc_now
from ..recording import META_ATTR, Recording

__all__ = ["ExperimentStore", "SearchHit", "tokenize", "parse_query", "as_experiment", "normalise_time",
           "FILTER_KEYS", "MAX_INDEXED_CHARS", "CHUNK_SAMPLES"]

#: Metadata keys whose values fill the structured filter columns.
FILTER_KEYS: dict[str, tuple[str, ...]] = {
    "machine": ("machine", "machine_tool"),
    "tool": ("tool", "cutter", "tool_id"),
    "material": ("material", "workpiece_material"),
    "operator": ("operator",),
}
#: Characters of tokenised text indexed per experiment (beyond them words are not indexed).
MAX_INDEXED_CHARS = 400_000
#: Samples per stored blob (4 MiB of float64).
CHUNK_SAMPLES = 1 << 19

_WORD = re.compile(r"[^\W_]+")
_FOLD = str.maketrans({"ø": "o", "æ": "ae", "œ": "oe", "ł": "l", "đ": "d", "ð": "d", "þ": "th", "ı": "i"})
_TERM = re.compile(r'"([^"]*)"|(\S+)')


@dataclass(frozen=True)
class SearchHit:
    """One experiment found by :meth:`ExperimentStore.search`.

    Parameters
    ----------
    id : str
        Experiment id.
    created : str
        Creation time, ISO 8601 UTC.
    name : str
        Measurement names, joined by ``", "``.
    machine, tool, material, operator : str
        The filter fields as stored (may be empty).
    measurements : int
        Number of measurements.
    channels : int
        Number of channels (all measurements).
    samples : int
        Number of samples (all channels).
    """

    id: str
    created: str
    name: str
    machine: str
    tool: str
    material: str
    operator: str
    measurements: int
    channels: int
    samples: int

    def to_dict(self) -> dict:
        """The hit as a plain dict (for JSON).

        Returns
        -------
        dict
        """
        return dict(self.__dict__)


@runtime_checkable
class ExperimentStore(Protocol):
    """What every archive backend offers (:class:`~drivesense.archive.SqliteStore`,
    :class:`~drivesense.archive.PostgresStore`)."""

    location: str

    def add(self, source: Any) -> str:
        """Import an experiment (XML/netCDF/CSV path, Recording(s) or Experiment); returns its id.

        Parameters
        ----------
        source : str, Path, Recording, sequence of Recording or Experiment
            What to import.
        """
        ...

    def search(self, text: str | None = None, **filters: Any) -> list[SearchHit]:
        """Experiments matching every word of `text` and every filter, best first.

        Parameters
        ----------
        text : str, optional
            Words that must all occur in the document (see :func:`parse_query`).
        **filters
            Field filters (``machine``, ``tool``, ``since``, ``start``, ``limit``...).
        """
        ...

    def show(self, id: str) -> dict:
        """Metadata of one experiment (no samples).

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).
        """
        ...

    def load(self, id: str) -> Experiment:
        """One experiment with its samples.

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).
        """
        ...

    def export(self, id: str, path: str | Path) -> Path:
        """Write one experiment as XML (or a single-measurement one as .nc/.csv).

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).
        path : str or Path
            File to write; its suffix chooses the format.
        """
        ...

    def remove(self, id: str) -> None:
        """Delete one experiment.

        Parameters
        ----------
        id : str
            Experiment id (or a unique prefix).
        """
        ...

    def resolve(self, prefix: str) -> str:
        """The full id of the one experiment whose id starts with `prefix`.

        Parameters
        ----------
        prefix : str
            Leading characters of an experiment id.
        """
        ...

    def count(self) -> int:
        """Number of experiments."""
        ...

    def close(self) -> None:
        """Release the connection."""
        ...


# ------------------------------------------------------------------ text
def tokenize(text: str) -> list[str]:
    """Words of `text` as the index sees them: casefolded, accents stripped, letters/digits only.

    Parameters
    ----------
    text : str

    Returns
    -------
    list of str
        E.g. ``"x_current_ref Fräser Ø6"`` -> ``["x", "current", "ref", "fraser", "o6"]``.
    """
    folded = unicodedata.normalize("NFKD", text.casefold().translate(_FOLD))
    folded = "".join(c for c in folded if not unicodedata.combining(c))
    return _WORD.findall(folded)


def parse_query(text: str | None) -> list[tuple[list[str], bool]]:
    """Split a search string into terms: ``[(tokens, prefix), ...]``, all of which must match.

    Parameters
    ----------
    text : str or None
        Words (each must occur), ``"quoted phrases"`` (words in this order),
        ``word*`` (prefix).  A word such as ``x_current_ref`` or ``0.005`` is
        a phrase of its tokens.

    Returns
    -------
    list of (list of str, bool)
    """
    terms = []
    for quoted, bare in _TERM.findall(text or ""):
        raw = quoted if quoted else bare
        prefix = not quoted and raw.endswith("*")
        tokens = tokenize(raw)
        if tokens:
            terms.append((tokens, prefix))
    return terms


def normalise_time(value: Any, *, end: bool = False) -> str:
    """A time as ISO 8601 UTC with microseconds (the archive's stored form).

    Parameters
    ----------
    value : str, datetime or date
        ISO 8601 text (``Z`` or an offset; no offset means UTC) or a date
        (``2024-05-01``).
    end : bool, optional
        For a bare date, the last microsecond of that day (for ``until``).

    Returns
    -------
    str

    Raises
    ------
    ConfigError
        Unparsable time.
    """
    if isinstance(value, datetime):
        dt = value
    elif isinstance(value, date):
        dt = datetime(value.year, value.month, value.day, 23, 59, 59, 999999) if end else \
            datetime(value.year, value.month, value.day)
    elif isinstance(value, str):
        text = value.strip()
        try:
            if re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
                return normalise_time(date.fromisoformat(text), end=end)
            dt = datetime.fromisoformat(text.replace("Z", "+00:00").replace("z", "+00:00"))
        except ValueError:
            raise ConfigError(f"time {value!r} is not ISO 8601 (e.g. 2024-05-01 or "
                              "2024-05-01T12:00:00Z)") from None
    else:
        raise ConfigError(f"time must be ISO 8601 text or a datetime, got {value!r}")
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


# ------------------------------------------------------------------ preparing an import
def as_experiment(source: Any) -> Experiment:
    """Turn what :meth:`ExperimentStore.add` accepts into an Experiment.

    Parameters
    ----------
    source : str, Path, Recording, sequence of Recording or Experiment
        A path is read by suffix: ``.xml`` (streamed, validated), ``.nc`` or
        ``.csv``.

    Returns
    -------
    Experiment
    """
    if isinstance(source, Experiment):
        return source
    if isinstance(source, (str, Path)):
        path = Path(source)
        if path.suffix.lower() == ".xml":
            from ..io.xml_format import read_experiment

            return read_experiment(path)
        from ..io import read_recording

        return Experiment.from_recordings(read_recording(path))
    if isinstance(source, Recording) or (isinstance(source, Sequence) and source
                                         and all(isinstance(r, Recording) for r in source)):
        return Experiment.from_recordings(source)
    raise ConfigError(f"cannot archive a {type(source).__name__}: give an .xml/.nc/.csv path, "
                      "Recording(s) or an Experiment")


def _leaf_text(value: Any) -> str:
    if isinstance(value, dict):
        return " ".join(f"{k}={_leaf_text(v)}" for k, v in value.items())
    if isinstance(value, list):
        return " ".join(_leaf_text(v) for v in value)
    return value if isinstance(value, str) else json.dumps(value)


def _find_keys(value: Any, keys: tuple[str, ...], out: list[str]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            if k.lower() in keys:
                out.append(_leaf_text(v))
            else:
                _find_keys(v, keys, out)
    elif isinstance(value, list):
        for v in value:
            _find_keys(v, keys, out)


def _numbers(value: Any, path: str, out: list[tuple[str, float]]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _numbers(v, path if k == "#text" else (f"{path}.{k}" if path else k), out)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        out.append((path, float(value)))


@dataclass
class Prepared:
    """Rows of one experiment, ready for a backend to insert (internal)."""

    exp: Experiment
    fields: dict[str, str]
    body: str
    measurements: list[tuple]
    channels: list[tuple]
    states: list[tuple]


def prepare(exp: Experiment) -> Prepared:
    """Rows, filter fields and the tokenised full text of one experiment (used by the backends).

    Parameters
    ----------
    exp : Experiment

    Returns
    -------
    Prepared
    """
    if not exp.id:
        exp = Experiment(exp.recordings, Experiment.from_recordings(exp.recordings).id, exp.created,
                         exp.format_version, exp.personnel, exp.texts)
    try:
        created = normalise_time(exp.created) if exp.created else utc_now()
    except ConfigError:
        created = utc_now()
    fields: dict[str, list[str]] = {k: [] for k in FILTER_KEYS}
    measurements, channels, states = [], [], []
    for i, rec in enumerate(exp.recordings):
        meta = rec.meta
        for key, names in FILTER_KEYS.items():
            _find_keys(meta, names, fields[key])
        people = meta.get("personnel")
        if isinstance(people, list):
            fields["operator"].extend(p["name"] for p in people if isinstance(p, dict)
                                      and isinstance(p.get("name"), str))
        measurements.append((i, rec.name or "", rec.fs, rec.t0, rec.n_samples,
                             rec.dataset.attrs[META_ATTR]))
        for j, ch in enumerate(rec.channels):
            iface, sensor = default_sensor(ch, meta.get("sensors"))
            channels.append((i, j, ch, rec.units(ch), iface, sensor, rec.n_samples))
        for which, key in (("start", "start_state"), ("end", "end_state")):
            found: list[tuple[str, float]] = []
            _numbers(meta.get(key), "", found)
            states.extend((i, which, k, v) for k, v in found if k)
    fields["operator"].extend(p.get("name", "") for p in exp.personnel)
    joined = {k: "; ".join(dict.fromkeys(v for v in vals if v)) for k, vals in fields.items()}
    joined["name"] = ", ".join(r.name or "" for r in exp.recordings)
    joined["created"] = created
    body = " ".join(tok for text in exp.search_texts() for tok in tokenize(text))[:MAX_INDEXED_CHARS]
    return Prepared(Experiment(exp.recordings, exp.id, created, exp.format_version, exp.personnel,
                               exp.texts), joined, body, measurements, channels, states)


def like_pattern(value: str) -> str:
    """``%value%`` for a case-insensitive substring match on casefolded columns (``\\`` escapes).

    Parameters
    ----------
    value : str

    Returns
    -------
    str
    """
    folded = value.casefold().replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
    return f"%{folded}%"


def check_ranges(ranges: Mapping[str, Any] | None, which: str) -> list[tuple[str, float | None, float | None]]:
    """Validate ``{key: (low, high)}`` state filters (None = open end).

    Parameters
    ----------
    ranges : mapping or None
        State key (dotted for nested values, e.g. ``"feed.rate"``) -> (low, high).
    which : str
        ``"start"`` or ``"end"``, for messages.

    Returns
    -------
    list of (str, float or None, float or None)
    """
    out = []
    for key, bounds in (ranges or {}).items():
        try:
            low, high = bounds
            low = None if low is None else float(low)
            high = None if high is None else float(high)
        except (TypeError, ValueError):
            raise ConfigError(f"{which} filter {key!r}: expected (low, high) numbers or None, "
                              f"got {bounds!r}") from None
        out.append((str(key), low, high))
    return out


def missing(id: str, location: str) -> MissingChannelError:
    """The error for an unknown experiment id.

    Parameters
    ----------
    id : str
        The id or prefix asked for.
    location : str
        The archive.

    Returns
    -------
    MissingChannelError
    """
    return MissingChannelError(f"no experiment {id!r} in the archive {location}")


def rows_to_hits(rows: Iterable[Sequence]) -> list[SearchHit]:
    """SearchHits from ``SELECT id, created, name, machine, tool, material, operator, n_meas, n_chan, n_samp``.

    Parameters
    ----------
    rows : iterable of sequences

    Returns
    -------
    list of SearchHit
    """
    return [SearchHit(str(r[0]), str(r[1]), r[2] or "", r[3] or "", r[4] or "", r[5] or "", r[6] or "",
                      int(r[7]), int(r[8]), int(r[9])) for r in rows]
