"""Column maps: read a controller's export as it comes (``--columns MAP.toml``).

A Sinumerik, Fanuc or Heidenhain trace, or an edge device's export, names its
columns its own way (``curr_x``, ``CURRENT|1``, ``Istwert X``) and often
leaves the units out of the header.  A column map says, once per export
format, which column is which channel, in which unit, with which scale and
sign::

    [map]
    description = "KIT DMC 60H, Sinumerik 840D sl traces at 50 Hz"
    resample_hz = 50            # optional: the export's time stamps jitter; read onto this grid

    [columns]
    time   = { channel = "time", unit = "s" }
    pos_x  = { channel = "x_position", unit = "mm" }
    curr_x = { channel = "x_current", unit = "A", sign = -1 }
    f_x    = { channel = "force_x", unit = "N", scale = 1.0, note = "the DAQ's raw units" }

Keys of ``[columns]`` are the export's column names (a header cell
``name [unit]`` matches by its name too); each entry gives ``channel`` (a
canonical drivesense channel), ``unit`` (of the values in the file, after
``scale``), and optionally ``scale`` (multiplies the values; e.g. an
amplifier's newtons per volt), ``sign`` (+1 or -1: a drive that logs its
current with the opposite sign), ``optional = true`` (the column may be
missing from a file) and ``note`` (kept in the provenance).  Columns the map
does not name are left out and listed in the provenance; a column the map
names but a file lacks is an error naming both.

Shipped maps (:func:`shipped_maps`) can be named instead of a path
(``--columns kit-dmc60h``).
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from .. import units as _units
from ..errors import ConfigError, UnitError

__all__ = ["ColumnSpec", "ColumnMap", "read_column_map", "shipped_maps", "resolve_column_map"]

_MAPS_DIR = Path(__file__).with_name("maps")
_ENTRY_KEYS = {"channel", "unit", "scale", "sign", "optional", "note"}
_MAP_KEYS = {"description", "resample_hz"}
_HEADER_RE = re.compile(r"^(.*?)\s*\[([^\[\]]*)\]\s*$")


@dataclass(frozen=True)
class ColumnSpec:
    """One column of an export.

    Parameters
    ----------
    source : str
        The column's name in the export.
    channel : str
        Canonical drivesense channel (``x_current``, ``force_y``, ``time``...).
    unit : str
        Unit of the file's values after `scale` (e.g. ``"mm/s"``).
    scale : float
        Factor applied to the file's values before the unit conversion [-].
    sign : int
        +1 or -1, applied with `scale`.
    optional : bool
        The column may be missing from a file.
    note : str
        Free text kept in the provenance.
    """

    source: str
    channel: str
    unit: str
    scale: float = 1.0
    sign: int = 1
    optional: bool = False
    note: str = ""

    @property
    def factor(self) -> float:
        """``scale * sign``: what the file's values are multiplied by before the unit conversion [-]."""
        return self.scale * self.sign


@dataclass(frozen=True)
class ColumnMap:
    """An export format: its columns (:class:`ColumnSpec`) and how to read its time base.

    Parameters
    ----------
    columns : tuple of ColumnSpec
        One entry per mapped column.
    name : str
        What to call the map in messages and provenance (its file name).
    description : str
        What export the map reads.
    resample_hz : float, optional
        Read the file onto a uniform grid at this rate [Hz] (an export whose
        time stamps jitter); ``--resample`` overrides it.
    """

    columns: tuple
    name: str = "column map"
    description: str = ""
    resample_hz: float | None = None

    def lookup(self, header_cell: str) -> ColumnSpec | None:
        """The spec of a header cell (by the whole cell, then by its name without a ``[unit]``), or None.

        Parameters
        ----------
        header_cell : str
            One cell of the file's header.
        """
        cell = header_cell.strip()
        if cell in self._by_source:
            return self._by_source[cell]
        m = _HEADER_RE.match(cell)
        return self._by_source.get(m.group(1).strip()) if m else None

    @functools.cached_property
    def _by_source(self) -> dict:
        return {c.source: c for c in self.columns}

    def check_header(self, header: list[str], file_name: str) -> None:
        """ConfigError naming the map, the file and the column when a required column is missing.

        Parameters
        ----------
        header : list of str
            The file's header cells.
        file_name : str
            The file, for the message.
        """
        found = {spec.source for cell in header if (spec := self.lookup(cell)) is not None}
        missing = [c for c in self.columns if c.source not in found and not c.optional]
        if missing:
            raise ConfigError(
                f"{self.name}: column(s) {', '.join(repr(c.source) for c in missing)} "
                f"({', '.join(c.channel for c in missing)}) not in {file_name} (it has: {', '.join(header)}); "
                "mark a column optional = true in the map if some files lack it")

    @classmethod
    def from_dict(cls, data: Mapping, *, name: str = "column map") -> "ColumnMap":
        """Build from the parsed TOML (``[map]`` and ``[columns]``), naming `name` in every error.

        Parameters
        ----------
        data : mapping
            The parsed file.
        name : str
            The map's name for messages.
        """
        unknown = sorted(set(data) - {"map", "columns"})
        if unknown:
            raise ConfigError(f"{name}: unknown section(s) {', '.join(unknown)} (known: map, columns)")
        head = data.get("map", {})
        if not isinstance(head, Mapping):
            raise ConfigError(f"{name}: [map] must be a table")
        bad = sorted(set(head) - _MAP_KEYS)
        if bad:
            raise ConfigError(f"{name}: [map] has unknown key(s) {', '.join(bad)} (known: {', '.join(sorted(_MAP_KEYS))})")
        resample = head.get("resample_hz")
        if resample is not None and not (_is_number(resample) and math.isfinite(resample) and resample > 0):
            raise ConfigError(f"{name}: [map] resample_hz must be a rate > 0 [Hz], got {resample!r}")
        cols = data.get("columns")
        if not isinstance(cols, Mapping) or not cols:
            raise ConfigError(f"{name}: needs a [columns] table: export column = {{ channel = ..., unit = ... }}")
        specs, channels = [], {}
        for source, entry in cols.items():
            spec = _spec(str(source), entry, name)
            if spec.channel in channels:
                raise ConfigError(f"{name}: columns {channels[spec.channel]!r} and {source!r} both give channel "
                                  f"{spec.channel!r}")
            channels[spec.channel] = source
            specs.append(spec)
        return cls(columns=tuple(specs), name=name, description=str(head.get("description", "")),
                   resample_hz=float(resample) if resample is not None else None)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _spec(source: str, entry, name: str) -> ColumnSpec:
    where = f"{name}, column {source!r}"
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{where}: expected a table {{ channel = ..., unit = ... }}, got {entry!r}")
    bad = sorted(set(entry) - _ENTRY_KEYS)
    if bad:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(bad)} (known: {', '.join(sorted(_ENTRY_KEYS))})")
    for key in ("channel", "unit"):
        if not isinstance(entry.get(key), str) or not entry[key].strip():
            raise ConfigError(f"{where}: '{key}' must be given as text")
    channel, unit = entry["channel"].strip(), entry["unit"].strip()
    quantity = _units.quantity_of_channel(channel)
    try:
        _units.unit_info(unit, quantity=quantity, name=channel)
    except (ConfigError, UnitError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
    scale = entry.get("scale", 1.0)
    if not (_is_number(scale) and math.isfinite(scale) and scale > 0):
        raise ConfigError(f"{where}: scale must be a number > 0 (the sign goes in 'sign'), got {scale!r}")
    sign = entry.get("sign", 1)
    if sign not in (1, -1) or isinstance(sign, bool):
        raise ConfigError(f"{where}: sign must be 1 or -1, got {sign!r}")
    optional = entry.get("optional", False)
    if not isinstance(optional, bool):
        raise ConfigError(f"{where}: optional must be true or false, got {optional!r}")
    if channel == "time" and (scale != 1.0 or sign != 1):
        raise ConfigError(f"{where}: the time column takes a unit, not a scale or sign")
    return ColumnSpec(source=source, channel=channel, unit=unit, scale=float(scale), sign=int(sign),
                      optional=optional, note=str(entry.get("note", "")))


def read_column_map(path: str | Path) -> ColumnMap:
    """Read a column map (TOML, see the module docstring).

    Parameters
    ----------
    path : str or Path
        The map file.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ConfigError
        Not TOML, or an entry that is not a channel, unit, scale or sign drivesense can use.
    """
    from . import read_toml

    path = Path(path)
    return ColumnMap.from_dict(read_toml(path, "column map"), name=path.name)


def shipped_maps() -> dict[str, Path]:
    """The column maps shipped with drivesense, by name (the file stem).

    Returns
    -------
    dict of str to Path
        e.g. ``{"kit-dmc60h": .../maps/kit-dmc60h.toml, ...}``.
    """
    return {p.stem: p for p in sorted(_MAPS_DIR.glob("*.toml"))}


def resolve_column_map(value: str | Path | ColumnMap) -> ColumnMap:
    """A column map from a path, a shipped map's name or a ColumnMap.

    Parameters
    ----------
    value : str, Path or ColumnMap
        ``MAP.toml``, or a name of :func:`shipped_maps`.
    """
    if isinstance(value, ColumnMap):
        return value
    shipped = shipped_maps()
    if isinstance(value, str) and value in shipped and not Path(value).exists():
        return read_column_map(shipped[value])
    path = Path(value)
    if not path.exists():
        raise ConfigError(f"--columns {value}: no such file, and not a shipped map (shipped: {', '.join(shipped)})")
    return read_column_map(path)
