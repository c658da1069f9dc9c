"""CSV files with a ``name [unit]`` header, read into and written from Recordings.

Format
------
- Lines starting with ``#`` and blank lines are skipped; the first other line
  is the header.  Delimiter: ``,`` (or ``;`` / tab, detected from the header).
- Each header cell is ``name [unit]``, e.g. ``time [ms]``,
  ``table_position [mm]``, ``force_x [N]``, ``ratio [1]``.  A column without
  brackets is refused (values in um or rev read as SI give forces a million
  times off), unless ``assume_si`` (``--assume-si``) says the file is in the
  SI unit of each channel's quantity (``1`` for names outside the data model).
- A ``time`` column (any time unit) gives the time base; it must be uniform
  within ``rel_tol``, or be resampled explicitly (``resample``,
  ``--resample HZ``).  Without one, ``fs`` (``--fs HZ``) must be given.
- Physically impossible samples (a spindle at -3.3e6 rpm, a position jump,
  NaN) are refused naming their line, or repaired by interpolation
  (``bad_samples``, ``--bad-samples refuse|repair|off``; see
  :mod:`drivesense.io.plausibility`).
- Bare axis channel names (``current_ref``, ``motor_angle``,
  ``table_position``...) get the prefix ``{axis}_``.
- The Recording's metadata (``name``, ``nc_delay_s``, ``score_window``,
  ``latency_s``...) lives beside the CSV in a sidecar ``FILE.csv.json`` (a JSON
  object): :func:`write_csv` writes it, :func:`read_csv` reads it back, so the
  CSV itself loads with ``pandas.read_csv`` defaults and in spreadsheets.
  Files of older versions carry it on a comment line ``# meta: {...}`` before
  the header; :func:`read_csv` still reads that.

Values are converted to SI; the provenance lists every conversion and rename.
"""

from __future__ import annotations

import csv as _csv
import errno
import functools
import json
import re
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import units as _units
from ..errors import ConfigError, InvalidSignalError, TimebaseError, UnitError
from ..metadata import meta_to_json
from ..nc_context import COUNT_CHANNELS, NAMED_CHANNELS, context_value
from .column_map import ColumnMap
from .plausibility import PlausibilityLimits, check_channels, check_policy, enforce_policy, repaired_meta

if TYPE_CHECKING:  # pragma: no cover
    from ..recording import Recording

__all__ = ["read_csv", "write_csv", "sidecar_path", "read_csv_text", "BARE_AXIS_CHANNELS"]

#: Column names that are prefixed with ``{axis}_`` when read.
BARE_AXIS_CHANNELS = ("current_ref", "current", "motor_angle", "table_position",
                      "position", "velocity", "acceleration")
_AXES = ("x", "y", "z")
_HEADER_RE = re.compile(r"^(.*?)\s*\[([^\[\]]*)\]\s*$")


def _decode(raw: bytes) -> str:
    """UTF-8 (with or without BOM), else Latin-1 (e.g. 'µm' from a Windows tool)."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


_META_PREFIX = "# meta:"
#: Bytes no text CSV holds: C0 controls other than tab, line feed, vertical tab, form feed and
#: carriage return, and DEL (UTF-16, binary files, random bytes).
_NOT_TEXT = re.compile(rb"[\x00-\x08\x0e-\x1f\x7f]")
_SNIFF_BYTES = 1 << 16


def _require_text(path: Path, head: bytes | None = None) -> None:
    """FileNotFoundError, or InvalidSignalError naming the file unless its start looks like text."""
    if not path.is_file():
        raise FileNotFoundError(errno.ENOENT, "CSV file not found", str(path))
    if head is None:
        with open(path, "rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    if _NOT_TEXT.search(head[:_SNIFF_BYTES]):
        raise InvalidSignalError(f"{path.name}: not a text CSV file (binary or not UTF-8)")


def read_csv_text(path: str | Path) -> str:
    """The text of a CSV file (UTF-8 with or without BOM, else Latin-1), refusing binary files.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    str

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    InvalidSignalError
        The file is binary (or text in another encoding, e.g. UTF-16): one line naming it.
    """
    path = Path(path)
    _require_text(path)
    raw = path.read_bytes()
    _require_text(path, raw)
    return _decode(raw)


def sidecar_path(path: str | Path) -> Path:
    """The metadata sidecar of a CSV file: ``FORCE.csv`` -> ``FORCE.csv.json``.

    Parameters
    ----------
    path : str or Path
        The CSV file.

    Returns
    -------
    Path
    """
    path = Path(path)
    return path.with_name(path.name + ".json")


def _read_sidecar(path: Path) -> dict:
    """The metadata of the sidecar of `path` ({} without one); errors name the sidecar."""
    from . import read_json_file

    side = sidecar_path(path)
    if not side.is_file():
        return {}
    found = read_json_file(side, "metadata sidecar")
    if not isinstance(found, dict):
        raise InvalidSignalError(f"metadata sidecar '{side}' must hold a JSON object, got "
                                 f"{type(found).__name__}")
    return found


def _find_header(path: Path) -> tuple[int, str, dict]:
    """(1-based line number, text) of the header -- the first non-blank, non-comment line --
    and the metadata of the ``# meta: {...}`` comment lines before it."""
    _require_text(path)
    meta: dict = {}
    with open(path, "rb") as fh:
        for lineno, raw in enumerate(fh, start=1):
            line = _decode(raw).rstrip("\r\n")
            if _is_data(line):
                return lineno, line, meta
            if line.startswith(_META_PREFIX):
                try:
                    found = json.loads(line[len(_META_PREFIX):])
                except json.JSONDecodeError as exc:
                    raise InvalidSignalError(f"{path.name}, line {lineno}: the '# meta:' line is not "
                                             f"valid JSON ({exc.msg})") from None
                if not isinstance(found, dict):
                    raise InvalidSignalError(f"{path.name}, line {lineno}: the '# meta:' line must hold a "
                                             f"JSON object, got {type(found).__name__}")
                meta.update(found)
    raise InvalidSignalError(f"{path.name}: empty file (no header line)")



def _is_data(line: str) -> bool:
    s = line.strip()
    return bool(s) and not s.startswith("#")


def _data_linenos(lines: list[str], header_lineno: int) -> np.ndarray:
    """1-based file line numbers of the data rows (slow; only for error messages)."""
    return np.array([i + 1 for i in range(header_lineno, len(lines)) if _is_data(lines[i])])


def _lines(path: Path) -> list[str]:
    return _decode(path.read_bytes()).splitlines()


def _parse_values(path: Path, header_lineno: int, header: list[str], delim: str,
                  usecols: list[int] | None = None, coded: Mapping[int, str] | None = None) -> np.ndarray:
    """The data rows as a float array (n_rows, n_cols, or the columns `usecols`); errors name line and column.

    ``coded`` maps file columns to the NC context channel their cells are
    (``ACTIVE``, ``O1234``: coded by :func:`~drivesense.nc_context.context_value`).
    """
    coded = dict(coded or {})
    converters = {k: functools.partial(context_value, name) for k, name in coded.items()}
    try:  # Latin-1 never fails to decode; numbers are ASCII anyway
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "loadtxt: input contained no data")
            return np.loadtxt(path, delimiter=delim, comments="#", skiprows=header_lineno,
                              dtype=np.float64, ndmin=2, encoding="latin-1", usecols=usecols,
                              converters=converters or None)
    except (ValueError, InvalidSignalError) as exc:
        first_error = str(exc)
    lines = _lines(path)
    for lineno in _data_linenos(lines, header_lineno):  # slow path: find the first bad cell
        cells = lines[lineno - 1].split("#", 1)[0].split(delim)
        if len(cells) != len(header):
            raise InvalidSignalError(f"{path.name}, line {lineno}: {len(cells)} cells, but the "
                                     f"header has {len(header)} columns")
        for k, (col, cell) in enumerate(zip(header, cells)):
            if usecols is not None and k not in usecols:
                continue
            try:
                context_value(coded[k], cell) if k in coded else float(cell)
            except InvalidSignalError as exc:
                raise InvalidSignalError(f"{path.name}, line {lineno}, column {col!r}: {exc}") from None
            except ValueError:
                raise InvalidSignalError(f"{path.name}, line {lineno}, column {col!r}: "
                                         f"{cell.strip()!r} is not a number") from None
    raise InvalidSignalError(f"{path.name}: cannot parse the data ({first_error})")


def read_csv(path: str | Path, *, axis: str = "x", mapping: Mapping[str, str] | None = None,
             fs: float | None = None, rel_tol: float = 1e-3,
             meta: Mapping | None = None, assume_si: bool = False,
             resample: float | None = None, bad_samples: str = "refuse",
             limits: PlausibilityLimits | None = None, column_map: ColumnMap | None = None) -> Recording:
    """Read a CSV file with a ``name [unit]`` header into a Recording (SI).

    Parameters
    ----------
    path : str or Path
        The CSV file.
    axis : {"x", "y", "z"}, optional
        Axis of bare channel names (``current_ref`` -> ``x_current_ref``).
    mapping : mapping of str to str, optional
        Column name (without the bracket) -> canonical name, applied before the
        axis prefix, e.g. ``{"Strom": "x_current_ref", "Zeit": "time"}``.
    fs : float, optional
        Sampling rate [Hz]; required without a ``time`` column, checked against
        it (within `rel_tol`) otherwise.
    rel_tol : float, optional
        Allowed step jitter of the time column as a fraction of the median
        step [-], see :func:`drivesense.recording.validate_timebase`.
    meta : mapping, optional
        Metadata for the Recording, over the file's own (its sidecar
        ``FILE.csv.json``, or the ``# meta:`` line of older files); ``name``
        defaults to the file stem.
    assume_si : bool, optional
        Read columns without a ``[unit]`` in the SI unit of their quantity
        (``--assume-si``); by default they are refused.
    resample : float, optional
        Resample the channels explicitly onto a uniform grid at this rate [Hz]
        (``--resample HZ``: linear interpolation between the time stamps,
        noted in the provenance), for time columns with jitter.  Needs a time
        column; not with `fs`.
    bad_samples : {"refuse", "repair", "off"}, optional
        What to do with physically impossible samples (``--bad-samples``; see
        :mod:`drivesense.io.plausibility`), checked on the file's rows before
        any resampling: ``refuse`` (default) raises naming channel, line,
        value and why; ``repair`` interpolates them from their neighbours,
        lists them in ``meta["repaired_samples"]`` and warns
        (:class:`~drivesense.io.plausibility.BadSampleWarning`); ``off`` reads
        them as they are (non-finite values are refused all the same).
    limits : PlausibilityLimits, optional
        Thresholds of the plausibility check (default
        :class:`~drivesense.io.plausibility.PlausibilityLimits`).
    column_map : ColumnMap, optional
        The export's columns (``--columns MAP.toml``, :mod:`drivesense.io.column_map`):
        channel, unit, scale and sign per column; columns it does not name are
        left out (listed in the provenance).  Its ``resample_hz`` applies unless
        `resample` or `fs` is given.

    Returns
    -------
    Recording
        Channels in SI, time base from the time column (or `fs`, t0 = 0).

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    InvalidSignalError
        No header or no data rows, a non-numeric cell or a non-finite value
        (naming line and column).
    ImplausibleSampleError
        Physically impossible samples under `bad_samples` ``refuse`` (or
        samples ``repair`` cannot mend), naming channel, line, value and why.
    TimebaseError
        The time column is not strictly increasing or not uniform (naming the
        file line), or disagrees with `fs`.
    UnitError
        Unknown unit, or a unit that does not fit the channel (naming the column).
    ConfigError
        No time column and no `fs`; duplicate channels; bad `axis`; `resample`
        without a time column or with `fs`.
    UnitError
        Columns without a unit (naming them), unless `assume_si`.
    """
    from ..recording import Recording
    from ..timebase import check_fs, check_timebase, resample_uniform

    path = Path(path)
    bad_samples = check_policy(bad_samples)
    fs = None if fs is None else check_fs(fs)
    if resample is not None:
        if fs is not None:
            raise ConfigError("give --fs HZ (the rate of a trace without a time column) or --resample HZ "
                              "(a new uniform grid for a time column), not both")
        resample = check_fs(resample)
    if axis not in _AXES:
        raise ConfigError(f"axis must be one of {_AXES}, got {axis!r}")
    mapping = dict(mapping or {})
    header_lineno, header_line, file_meta = _find_header(path)
    delim = max([",", ";", "\t"], key=header_line.count)
    header = [c.strip() for c in next(_csv.reader([header_line], delimiter=delim))]
    left_out: list[str] = []
    if column_map is not None:
        column_map.check_header(header, path.name)
        if resample is None and fs is None and column_map.resample_hz is not None:
            resample = check_fs(column_map.resample_hz)

    # --- columns: names, units, conversions (checked before the data are parsed)
    columns: list[tuple[int, str, str, _units.UnitInfo, float]] = []  # (file column, name, header, unit, factor)
    seen: dict[str, str] = {}
    renamed, converted, no_unit = [], [], []
    time_col = None
    for j, cell in enumerate(header):
        m = _HEADER_RE.match(cell)
        raw, unit = (m.group(1).strip(), m.group(2).strip()) if m else (cell, None)
        spec = column_map.lookup(cell) if column_map is not None else None
        if column_map is not None and spec is None:
            left_out.append(cell or f"(column {j + 1}, no name)")
            continue
        if not raw:
            raise ConfigError(f"{path.name}: column {j + 1} ({cell!r}) has no name")
        name = spec.channel if spec is not None else mapping.get(raw, raw)
        if spec is not None:
            if unit is not None and unit != spec.unit:
                raise UnitError(f"{path.name}, column {cell!r}: the header says [{unit}], the column map "
                                f"{column_map.name} says {spec.unit}; correct one of them")
            unit = spec.unit
        if name.lower() == "time":
            name = "time"
        elif name in BARE_AXIS_CHANNELS:
            name = f"{axis}_{name}"
        if name != raw:
            renamed.append(f"{raw}->{name}")
        if name in seen:
            raise ConfigError(f"{path.name}: columns {seen[name]!r} and {cell!r} both give "
                              f"channel {name!r}")
        seen[name] = cell
        quantity = _units.quantity_of_channel(name)
        if unit is None and name in COUNT_CHANNELS:
            unit = "1"                               # a tool, a block, a state: counts and codes have no unit
        if unit is None:
            no_unit.append(cell)
            unit = _units.si_unit(quantity) if quantity else "1"
        try:
            info = _units.unit_info(unit, quantity=quantity, name=name)
        except UnitError as exc:
            raise UnitError(f"{path.name}, column {cell!r}: {exc}") from None
        if not _units.is_si_unit(unit):
            converted.append(f"{name} {unit}->{_units.SI_UNITS[info.quantity]}")
        if name == "time":
            time_col = j
        columns.append((j, name, cell, info, spec.factor if spec is not None else 1.0))
    if all(c[1] == "time" for c in columns):
        raise InvalidSignalError(f"{path.name}: no channel columns (header: {header_line!r})")
    if no_unit and not assume_si:
        raise UnitError(f"{path.name}: column(s) {', '.join(repr(c) for c in no_unit)} have no unit: give units "
                        "in the header ('table_position [mm]', 'time [ms]') or pass --assume-si to read them as SI "
                        "(m, rad, A, s...)")
    if time_col is None and resample is not None:
        raise ConfigError(f"{path.name}: no 'time' column to resample: --resample needs time stamps; give the "
                          "sample rate with --fs HZ instead")
    if time_col is None and fs is None:
        raise ConfigError(f"{path.name}: no 'time' column: give the sample rate with --fs HZ "
                          f"(columns: {', '.join(header)})")

    # --- data
    usecols = [c[0] for c in columns] if column_map is not None else None
    coded = {c[0]: c[1] for c in columns if c[1] in NAMED_CHANNELS}
    values = _parse_values(path, header_lineno, header, delim, usecols, coded)
    if values.size == 0:
        raise InvalidSignalError(f"{path.name}: no data rows after the header "
                                 f"(line {header_lineno})")
    if usecols is not None:
        columns = [(k, *c[1:]) for k, c in enumerate(columns)]
    elif values.shape[1] != len(header):
        raise InvalidSignalError(f"{path.name}: data rows have {values.shape[1]} cells, the "
                                 f"header has {len(header)} columns")

    channels, si_units, file_units = {}, {}, {}
    for j, name, cell, info, factor in columns:
        col = values[:, j] * (info.factor * factor) if info.factor * factor != 1.0 else values[:, j].copy()
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size and name != "time" and bad_samples != "repair":
            raise InvalidSignalError(
                f"{path.name}, column {cell!r}: channel {name!r} has {bad.size} non-finite "
                f"values (first {float(values[bad[0], j])!r} at line "
                f"{_data_linenos(_lines(path), header_lineno)[bad[0]]}); --bad-samples repair interpolates "
                "isolated ones from their neighbours")
        if name == "time":
            time = col
        else:
            channels[name] = col
            si_units[name] = _units.SI_UNITS[info.quantity]
            file_units[name] = info.unit

    # --- physically impossible samples, on the file's rows (before any resampling)
    repaired: list[dict] = []
    if bad_samples != "off":
        report = check_channels(channels, time=time if time_col is not None else None, fs=fs, units=file_units,
                                source=path.name, limits=limits)
        report = report.located(lambda: _data_linenos(_lines(path), header_lineno))
        channels, repaired = enforce_policy(channels, report, bad_samples, stacklevel=2)

    if time_col is not None and resample is not None:
        where = f"{path.name}, column {header[time_col]!r}"
        try:
            t0, channels, timebase = resample_uniform(time, channels, resample, name=where)
        except TimebaseError:  # again, with file line numbers in the message
            resample_uniform(time, channels, resample, name=where,
                             rows=_data_linenos(_lines(path), header_lineno), row_label="line")
            raise
        fs = resample
    elif time_col is not None:
        where = f"{path.name}, column {header[time_col]!r}"
        try:
            fs_t, jitter = check_timebase(time, rel_tol, where, None, "sample")
        except TimebaseError:  # again, with file line numbers in the message
            check_timebase(time, rel_tol, where, _data_linenos(_lines(path), header_lineno), "line")
            raise
        if fs is not None and abs(fs - fs_t) > rel_tol * fs:
            raise TimebaseError(f"{where}: time column gives fs={fs_t:.12g} Hz, but --fs {fs:g} was given")
        fs, t0 = fs_t, float(time[0])
        timebase = (f"fs={fs:.12g} Hz from column {header[time_col]!r} "
                    f"(max step jitter {100 * jitter:.3g} %)")
    else:
        t0 = 0.0
        timebase = f"fs={float(fs):.12g} Hz given (no time column)"

    parts = ([f"column map {column_map.name}" + (f" ({column_map.description})" if column_map.description else "")
              + (f", left out {', '.join(left_out)}" if left_out else "")
              + "".join(f"; {c.source}: scale {c.scale:g}, sign {c.sign:+d}" + (f" ({c.note})" if c.note else "")
                        for c in column_map.columns if c.factor != 1.0 or c.note)]
             if column_map is not None else []) + \
            ([f"renamed {', '.join(renamed)}"] if renamed else []) + \
            ([f"converted {', '.join(converted)}"] if converted else []) + \
            ([f"no unit, SI assumed (--assume-si): {', '.join(no_unit)}"] if no_unit else []) + [timebase]
    if repaired:
        parts.append(f"--bad-samples repair: {len(repaired)} implausible sample(s) replaced by linear "
                     "interpolation (meta['repaired_samples'])")
    meta = {"name": path.stem, **file_meta, **_read_sidecar(path), **dict(meta or {})}
    if repaired:
        meta.update(repaired_meta(meta, repaired))
    rec = Recording.from_arrays(channels, fs=fs, t0=t0, units=si_units, meta=meta)
    return rec.with_provenance(f"read_csv {path.name}: " + "; ".join(parts))


def _check_name(name: str, what: str) -> None:
    if any(c in name for c in ",;\t[]\n\r#"):
        raise ConfigError(f"{what} {name!r} cannot be written as a CSV column name")


def write_csv(rec: Recording, path: str | Path, *, units: Mapping[str, str] | None = None,
              channels: Sequence[str] | None = None, column_map: ColumnMap | None = None) -> Path:
    """Write a Recording as CSV: ``time [s]``, then one ``name [unit]`` column per channel.

    With a `column_map` the file is written as that export: its column names
    (no units in the header), units, scales and signs, the map's columns in
    its order for every channel the recording has -- what :func:`read_csv`
    with the same map reads back.

    Parameters
    ----------
    rec : Recording
        The data.
    path : str or Path
        Target file, replaced atomically.
    units : mapping of str to str, optional
        Output unit per channel name (and ``"time"``), e.g. ``{"x_table_position":
        "mm", "time": "ms"}``; default SI.
    channels : sequence of str, optional
        Channels to write, in order; default all.
    column_map : ColumnMap, optional
        Write as this export (not with `units` or `channels`).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    MissingChannelError
        A requested channel is absent.
    UnitError
        A unit is unknown or does not fit the channel.
    ConfigError
        `units` names a channel that is not written.

    Notes
    -----
    Values are written with :func:`repr` (shortest text that reads back to the
    same float64), so SI output reads back bit-exactly.  The first line is the
    header, so the file loads with ``pandas.read_csv`` defaults.  The metadata
    (JSON; provenance is not) goes beside it into the sidecar ``FILE.csv.json``
    (:func:`sidecar_path`), written atomically with the CSV; a stale sidecar is
    removed when the Recording has no metadata.
    """

    path = Path(path)
    if column_map is not None:
        if units or channels:
            raise ConfigError("write_csv: give a column map or units/channels, not both")
        return _write_mapped(rec, path, column_map)
    units = dict(units or {})
    names = list(rec.channels if channels is None else channels)
    rec.require(*names)
    extra = [k for k in units if k != "time" and k not in names]
    if extra:
        raise ConfigError(f"units given for channel(s) not written: {extra}")
    unit = units.get("time", "s")
    cols = [_units.from_si(rec.time, unit, quantity=_units.TIME, name="time")]
    head = [f"time [{unit}]"]
    for name in names:
        _check_name(name, "channel")
        unit = units.get(name, rec.units(name))
        quantity = _units.quantity_of_unit(rec.units(name))
        cols.append(_units.from_si(rec[name], unit, quantity=quantity, name=name))
        head.append(f"{name} [{unit}]")
    return _write_columns(rec, path, head, cols)


def _write_mapped(rec: Recording, path: Path, column_map: ColumnMap) -> Path:
    """The recording as the map's export: map order, the map's units, values divided by scale and sign."""
    head, cols = [], []
    for spec in column_map.columns:
        if spec.channel == "time":
            values = _units.from_si(rec.time, spec.unit, quantity=_units.TIME, name="time")
        elif spec.channel in rec.channels:
            quantity = _units.quantity_of_unit(rec.units(spec.channel))
            values = _units.from_si(rec[spec.channel], spec.unit, quantity=quantity, name=spec.channel) / spec.factor
        else:
            continue
        head.append(spec.source)
        cols.append(values)
    if not any(c for c in head if column_map.lookup(c).channel != "time"):
        raise ConfigError(f"{column_map.name}: the recording has none of the map's channels")
    return _write_columns(rec, path, head, cols)


def _write_columns(rec: Recording, path: Path, head: list[str], cols: list[np.ndarray]) -> Path:
    from . import atomic_output

    text_cols = [map(repr, c.tolist()) for c in cols]
    meta = {k: v for k, v in rec.meta.items() if k != "provenance"}   # reading adds its own
    meta_text = meta_to_json(meta) + "\n" if meta else None
    side = sidecar_path(path)
    with atomic_output(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(",".join(head) + "\n")
            fh.write("\n".join(map(",".join, zip(*text_cols))))
            fh.write("\n")
        if meta_text is None:     # no metadata: a sidecar left from an earlier write would lie
            side.unlink(missing_ok=True)
        else:
            with atomic_output(side) as tmp_side:
                tmp_side.write_text(meta_text, encoding="utf-8")
    return path
