"""MTConnect ingest: Devices documents, Streams documents and SHDR logs into Recordings.

- :func:`parse_devices` reads an agent's ``/probe`` answer (``MTConnectDevices``)
  and maps every DataItem to a drivesense channel: a linear axis ``X``'s actual
  ``POSITION`` is ``x_table_position`` [m], its ``AXIS_FEEDRATE`` ``x_velocity``
  [m/s], ``AMPERAGE`` ``x_current`` [A]; a spindle's ``ROTARY_VELOCITY`` /
  ``SPINDLE_SPEED`` is ``spindle_speed`` [rad/s], ``WATTAGE`` ``spindle_power``
  [W]; anything else ``{component}_{type}[_{subtype}]`` in lower case.  Units
  are converted to SI (``PERCENT`` becomes a fraction); items whose unit
  drivesense has no SI entry for (``CELSIUS``...) are kept as events.
- :func:`parse_streams` reads ``/current`` and ``/sample`` answers
  (``MTConnectStreams``); :func:`parse_shdr` reads adapter logs
  (``timestamp|key|value|key|value...``; conditions, messages, alarms and time
  series are multi-field items on a line of their own).
- :func:`to_recording` resamples the irregular observations *explicitly* onto a
  uniform grid (linear interpolation or zero-order hold, stated in the
  provenance with the rate, span and gaps); events, messages and conditions go
  to ``meta["mtconnect"]``.  ``UNAVAILABLE`` stretches are bridged and listed
  as gaps.

The HTTP client is :class:`drivesense.io.mtconnect_client.MTConnectClient`.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidSignalError
from .mtconnect_assets import read_asset_command
from .xml_safe import XMLLimits, local_name, parse_bytes

__all__ = ["context_channel", "context_factor", "DataItem", "DeviceModel", "Observation", "StreamsDocument",
           "AgentError", "MTConnectWarning", "parse_devices", "parse_streams", "parse_shdr", "to_recording", "read_mtconnect", "parse_timestamp", "MTC_UNITS"]

_REV = 2.0 * math.pi
#: MTConnect unit -> (factor to SI, drivesense SI unit).
MTC_UNITS: dict[str, tuple[float, str]] = {
    "MILLIMETER": (1e-3, "m"), "MILLIMETER_3D": (1e-3, "m"), "METER": (1.0, "m"), "INCH": (0.0254, "m"),
    "MILLIMETER/SECOND": (1e-3, "m/s"), "MILLIMETER/MINUTE": (1e-3 / 60.0, "m/s"),
    "METER/SECOND": (1.0, "m/s"), "MILLIMETER/SECOND^2": (1e-3, "m/s^2"), "METER/SECOND^2": (1.0, "m/s^2"),
    "REVOLUTION/MINUTE": (_REV / 60.0, "rad/s"), "DEGREE/SECOND": (math.pi / 180.0, "rad/s"),
    "RADIAN/SECOND": (1.0, "rad/s"), "DEGREE": (math.pi / 180.0, "rad"), "DEGREE_3D": (math.pi / 180.0, "rad"),
    "RADIAN": (1.0, "rad"), "AMPERE": (1.0, "A"), "MILLIAMPERE": (1e-3, "A"), "WATT": (1.0, "W"),
    "KILOWATT": (1e3, "W"), "VOLT": (1.0, "V"), "NEWTON": (1.0, "N"), "NEWTON_METER": (1.0, "N*m"),
    "PERCENT": (0.01, "1"), "SECOND": (1.0, "s"), "MILLISECOND": (1e-3, "s"), "COUNT": (1.0, "1"),
}
_AXIS_TYPES = {("POSITION", "ACTUAL"): "table_position", ("POSITION", ""): "table_position",
               ("POSITION", "COMMANDED"): "position_commanded", ("POSITION", "PROGRAMMED"): "position_programmed",
               ("AXIS_FEEDRATE", "ACTUAL"): "velocity", ("AXIS_FEEDRATE", ""): "velocity",
               ("AXIS_FEEDRATE", "COMMANDED"): "velocity_commanded", ("ACCELERATION", ""): "acceleration",
               ("ACCELERATION", "ACTUAL"): "acceleration", ("AMPERAGE", ""): "current",
               ("ELECTRIC_CURRENT", ""): "current", ("LOAD", ""): "load", ("ANGLE", "ACTUAL"): "angle",
               ("ANGLE", ""): "angle"}
_SPINDLE_TYPES = {"ROTARY_VELOCITY": "spindle_speed", "SPINDLE_SPEED": "spindle_speed",
                  "AMPERAGE": "spindle_current", "ELECTRIC_CURRENT": "spindle_current",
                  "WATTAGE": "spindle_power", "LOAD": "spindle_load"}
_LEVELS = ("NORMAL", "WARNING", "FAULT", "UNAVAILABLE")


def snake_case(text: str) -> str:
    return re.sub(r"[^0-9a-z]+", "_", re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", text).lower()).strip("_")


@dataclass(frozen=True)
class DataItem:
    """One DataItem of a Devices document and the channel it maps to.

    Parameters
    ----------
    id, name : str
        MTConnect id and name (name may be empty).
    category : str
        ``SAMPLE``, ``EVENT`` or ``CONDITION``.
    type, sub_type : str
        E.g. ``POSITION`` / ``ACTUAL``.
    units, native_units : str
        Units of Streams values and of adapter (SHDR) values.
    representation : str
        ``VALUE`` or ``TIME_SERIES`` (...).
    sample_rate : float or None
        Time-series rate [Hz].
    component, component_name, device : str
        Component type (``Linear``...), its name (``X``...) and the device name.
    channel : str
        drivesense channel name.
    """

    id: str
    name: str
    category: str
    type: str
    sub_type: str
    units: str
    native_units: str
    representation: str
    sample_rate: float | None
    component: str
    component_name: str
    device: str
    channel: str

    def scale(self, native: bool = False) -> tuple[float, str] | None:
        """(factor to SI, SI unit) for values in :attr:`units` (or :attr:`native_units`); None if unknown.

        Parameters
        ----------
        native : bool, optional
            Values come from an adapter (SHDR), in native units when given.
        """
        unit = (self.native_units if native and self.native_units else self.units) or "COUNT"
        return MTC_UNITS.get(unit)


def context_channel(item: DataItem) -> str | None:
    """The NC context channel (:mod:`drivesense.nc_context`) a data item reports, or None.

    ``EXECUTION`` -> ``execution``; ``PROGRAM`` -> ``program_number``;
    ``LINE_NUMBER`` (absolute) or the older ``LINE`` -> ``block_number``;
    ``TOOL_NUMBER`` (or ``TOOL_ID``) -> ``tool_number``;
    ``PATH_FEEDRATE_OVERRIDE`` (programmed) or ``PATH_FEEDRATE``/``OVERRIDE``
    -> ``feed_override``; ``ROTARY_VELOCITY_OVERRIDE`` or a spindle speed's
    ``OVERRIDE`` -> ``spindle_override``.

    Parameters
    ----------
    item : DataItem
        From a Devices document.
    """
    typ, sub = item.type, item.sub_type
    if typ == "EXECUTION":
        return "execution"
    if typ == "PROGRAM" and sub in ("", "MAIN", "ACTIVE"):
        return "program_number"
    if typ in ("LINE_NUMBER", "LINE") and sub in ("", "ABSOLUTE"):
        return "block_number"
    if typ in ("TOOL_NUMBER", "TOOL_ID"):
        return "tool_number"
    if (typ == "PATH_FEEDRATE_OVERRIDE" and sub in ("", "PROGRAMMED")) or (typ == "PATH_FEEDRATE" and sub == "OVERRIDE"):
        return "feed_override"
    if typ == "ROTARY_VELOCITY_OVERRIDE" or (typ in ("ROTARY_VELOCITY", "SPINDLE_SPEED") and sub == "OVERRIDE"):
        return "spindle_override"
    return None


def context_factor(channel: str, item: DataItem) -> float:
    """Factor from a context data item's values to the channel's: overrides in percent (MTConnect's unit) -> ratio.

    Parameters
    ----------
    channel : str
        The context channel.
    item : DataItem
        The data item reporting it.
    """
    if channel in ("feed_override", "spindle_override") and (item.units or "PERCENT").upper() == "PERCENT":
        return 0.01
    return 1.0


def _channel(component: str, cname: str, typ: str, sub: str, name: str) -> str:
    axis = cname.lower()
    if component == "Linear" and axis in ("x", "y", "z") and (typ, sub) in _AXIS_TYPES:
        return f"{axis}_{_AXIS_TYPES[typ, sub]}"
    if component == "Linear" and axis in ("x", "y", "z") and (typ, "") in _AXIS_TYPES and sub:
        return f"{axis}_{_AXIS_TYPES[typ, '']}_{sub.lower()}"
    if component in ("Rotary", "Spindle") and typ in _SPINDLE_TYPES and sub in ("", "ACTUAL"):
        return _SPINDLE_TYPES[typ]
    comp, kind = snake_case(cname or component), typ.lower()
    base = kind if kind.startswith(comp + "_") else f"{comp}_{kind}"
    return base + (f"_{sub.lower()}" if sub else "")


@dataclass
class DeviceModel:
    """The DataItems of a Devices document, by id and name.

    Parameters
    ----------
    items : list of DataItem
    devices : list of dict
        ``{"name", "uuid", "id", "manufacturer", "model", "serial", "description"}`` per device.
    header : dict
        The document's Header attributes.
    """

    items: list[DataItem]
    devices: list[dict] = field(default_factory=list)
    header: dict = field(default_factory=dict)

    def lookup(self, key: str) -> DataItem | None:
        """The DataItem whose id (or else name) is `key`.

        Parameters
        ----------
        key : str
        """
        by_id = {i.id: i for i in self.items}
        if key in by_id:
            return by_id[key]
        return next((i for i in self.items if i.name == key), None)


def parse_devices(source: str | Path | bytes, *, limits: XMLLimits = XMLLimits(max_bytes=64 * 2**20),
                  where: str | None = None) -> DeviceModel:
    """Read a Devices document (an agent's ``/probe`` answer).

    Parameters
    ----------
    source : str, Path or bytes
        File path or the document's bytes.
    limits : XMLLimits, optional
        Parser limits (default 64 MiB).
    where : str, optional
        Name of the document for messages (default: the file name).

    Returns
    -------
    DeviceModel

    Raises
    ------
    InvalidSignalError
        Not an ``MTConnectDevices`` document, unsafe or broken XML.
    """
    data, name = _load(source)
    where = where or name
    root = parse_bytes(data, where=where, limits=limits).getroot()
    if local_name(root.tag) != "MTConnectDevices":
        _raise_agent_error(root, where)
        raise InvalidSignalError(f"{where}: root <{local_name(root.tag)}> is not MTConnectDevices")
    header = next((dict(h.attrib) for h in root if local_name(h.tag) == "Header"), {})
    items: list[DataItem] = []
    devices = []

    def walk(el: Any, device: str) -> None:
        comp, cname = local_name(el.tag), el.get("name") or el.get("id") or ""
        for child in el:
            tag = local_name(child.tag)
            if tag == "DataItems":
                for di in child:
                    if local_name(di.tag) != "DataItem":
                        continue
                    typ, sub = (di.get("type") or "").upper(), (di.get("subType") or "").upper()
                    rate = di.get("sampleRate")
                    items.append(DataItem(
                        di.get("id") or "", di.get("name") or "", (di.get("category") or "").upper(), typ, sub,
                        di.get("units") or "", di.get("nativeUnits") or "", (di.get("representation") or "VALUE")
                        .upper(), float(rate) if rate else None, comp, cname, device,
                        _channel(comp, cname, typ, sub, di.get("name") or "") if (di.get("category") or "")
                        .upper() == "SAMPLE" else f"{snake_case(cname or comp)}_{typ.lower()}"))
            elif tag == "Components":
                for c in child:
                    walk(c, device)

    for dev in root.iter("{*}Device"):
        desc = next((d for d in dev if local_name(d.tag) == "Description"), None)
        devices.append({"name": dev.get("name", ""), "uuid": dev.get("uuid", ""), "id": dev.get("id", ""),
                        "manufacturer": desc.get("manufacturer", "") if desc is not None else "",
                        "model": desc.get("model", "") if desc is not None else "",
                        "serial": desc.get("serialNumber", "") if desc is not None else "",
                        "description": (desc.text or "").strip() if desc is not None else ""})
        walk(dev, dev.get("name", ""))
    seen: dict[str, int] = {}
    for k, item in enumerate(items):  # two items mapping to one channel: keep both, suffix the id
        if item.channel in seen and item.category == "SAMPLE":
            items[k] = DataItem(**{**item.__dict__, "channel": f"{item.channel}_{snake_case(item.id)}"})
        seen[items[k].channel] = k
    return DeviceModel(items, devices, header)


@dataclass(frozen=True)
class Observation:
    """One reported value.

    Parameters
    ----------
    key : str
        dataItemId (Streams) or the SHDR key (name or id).
    time_us : int
        Timestamp, microseconds since 1970-01-01 UTC.
    value : float, tuple of float, numpy.ndarray, str, dict or None
        Number, vector (``PATH_POSITION``), time series, event text, condition
        level; None for ``UNAVAILABLE``.  Numbers are as the agent reports
        them [the data item's units], not yet converted to SI.  An SHDR asset
        is a dict (see :func:`~drivesense.io.mtconnect_assets.read_asset_command`).
    kind : str
        ``SAMPLE``, ``TIME_SERIES``, ``EVENT``, ``MESSAGE``, ``CONDITION`` or
        ``ALARM``; from SHDR asset commands also ``ASSET``, ``ASSET_REMOVED``
        (key ``*`` for ``@REMOVE_ALL_ASSETS@``) and ``ASSET_UPDATED``.
    sequence : int or None
        Agent sequence number (None in SHDR).
    extra : dict
        Condition/message fields (nativeCode, qualifier, message...), ``sample_rate`` [Hz].
    """

    key: str
    time_us: int
    value: Any
    kind: str = "SAMPLE"
    sequence: int | None = None
    extra: dict = field(default_factory=dict)


@dataclass
class StreamsDocument:
    """An agent's ``/current`` or ``/sample`` answer.

    Parameters
    ----------
    header : dict
        ``instance_id``, ``first_sequence``, ``last_sequence``, ``next_sequence`` (ints)
        and the other Header attributes.
    observations : list of Observation
        Sorted by sequence.
    """

    header: dict
    observations: list[Observation]


class AgentError(InvalidSignalError):
    """An ``MTConnectError`` answer (``code`` holds the errorCode, e.g. ``OUT_OF_RANGE``).

    Parameters
    ----------
    message : str
    code : str
    """

    def __init__(self, message: str, code: str = "") -> None:
        super().__init__(message)
        self.code = code


class MTConnectWarning(UserWarning):
    """Something in an MTConnect document or SHDR log was skipped (the message names the line)."""


def _raise_agent_error(root: Any, where: str) -> None:
    if local_name(root.tag) == "MTConnectError":
        errors = [e for e in root.iter("{*}Error")]
        code = errors[0].get("errorCode", "") if errors else ""
        text = "; ".join(f"{e.get('errorCode', '')}: {(e.text or '').strip()}" for e in errors)
        raise AgentError(f"{where}: agent error {text or '(no details)'}", code)


def parse_timestamp(text: str, where: str = "timestamp") -> int:
    """ISO 8601 time -> microseconds since the epoch (UTC; no offset means UTC).

    Parameters
    ----------
    text : str
        E.g. ``2024-03-05T09:00:00.123456Z``; an SHDR ``@duration`` suffix is ignored.
    where : str, optional
        For messages.

    Returns
    -------
    int
    """
    s = text.strip().split("@", 1)[0]
    m = re.fullmatch(r"(.*T\d\d:\d\d:\d\d)(\.\d+)?(Z|[+-]\d\d:?\d\d)?", s)
    try:
        if not m:
            raise ValueError
        dt = datetime.fromisoformat(m.group(1) + (m.group(3) or "").replace("Z", "+00:00"))
    except ValueError:
        raise InvalidSignalError(f"{where}: {text!r:.40} is not an ISO 8601 timestamp") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    frac = m.group(2) or ".0"
    return (int(dt.timestamp()) * 1_000_000) + int(round(float(frac) * 1e6))


def _number(text: str | None) -> Any:
    if text is None or text.strip().upper() == "UNAVAILABLE":
        return None
    parts = text.split()
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        return text.strip()
    if not vals:
        return None
    return vals[0] if len(vals) == 1 else tuple(vals)


def parse_streams(source: str | Path | bytes, *, limits: XMLLimits = XMLLimits(max_bytes=256 * 2**20),
                  where: str | None = None) -> StreamsDocument:
    """Read a Streams document (an agent's ``/current`` or ``/sample`` answer).

    Parameters
    ----------
    source : str, Path or bytes
        File path or the document's bytes.
    limits : XMLLimits, optional
        Parser limits (default 256 MiB).
    where : str, optional
        Name of the document for messages (default: the file name).

    Returns
    -------
    StreamsDocument

    Raises
    ------
    AgentError
        The document is an ``MTConnectError`` (e.g. ``OUT_OF_RANGE``).
    InvalidSignalError
        Not a Streams document, bad timestamps, unsafe or broken XML.
    """
    data, name = _load(source)
    where = where or name
    root = parse_bytes(data, where=where, limits=limits).getroot()
    _raise_agent_error(root, where)
    if local_name(root.tag) != "MTConnectStreams":
        raise InvalidSignalError(f"{where}: root <{local_name(root.tag)}> is not MTConnectStreams")
    header = next((dict(h.attrib) for h in root if local_name(h.tag) == "Header"), {})
    for key, attr in (("instance_id", "instanceId"), ("first_sequence", "firstSequence"),
                      ("last_sequence", "lastSequence"), ("next_sequence", "nextSequence")):
        if attr in header:
            try:
                header[key] = int(header[attr])
            except ValueError:
                raise InvalidSignalError(f"{where}: Header {attr}={header[attr]!r} is not an integer") from None
    obs: list[Observation] = []
    for group in root.iter("{*}Samples", "{*}Events", "{*}Condition"):
        cat = local_name(group.tag)
        for el in group:
            if not isinstance(el.tag, str) or el.get("dataItemId") is None:
                continue
            tag = local_name(el.tag)
            at = f"{where}, line {el.sourceline}"
            t = parse_timestamp(el.get("timestamp", ""), at)
            seq = int(el.get("sequence")) if el.get("sequence", "").isdigit() else None
            extra = {k: v for k, v in el.attrib.items() if k in ("nativeCode", "nativeSeverity", "qualifier",
                                                                 "type", "subType")}
            if cat == "Condition":
                extra["message"] = (el.text or "").strip()
                obs.append(Observation(el.get("dataItemId"), t, tag.upper(), "CONDITION", seq, extra))
            elif cat == "Samples" and tag.endswith("TimeSeries"):
                vals = _number(el.text)
                arr = np.atleast_1d(np.array(vals, float)) if vals is not None else None
                n = int(el.get("sampleCount", "0") or 0)
                if arr is not None and n and arr.size != n:
                    raise InvalidSignalError(f"{at}: {tag} sampleCount={n} but {arr.size} values")
                if el.get("sampleRate"):
                    extra["sample_rate"] = float(el.get("sampleRate"))
                obs.append(Observation(el.get("dataItemId"), t, arr, "TIME_SERIES", seq, extra))
            elif cat == "Samples":
                obs.append(Observation(el.get("dataItemId"), t, _number(el.text), "SAMPLE", seq, extra))
            else:
                kind = "MESSAGE" if tag == "Message" else ("ALARM" if tag == "Alarm" else "EVENT")
                text = (el.text or "").strip()
                obs.append(Observation(el.get("dataItemId"), t, None if text == "UNAVAILABLE" else text, kind,
                                       seq, extra))
    obs.sort(key=lambda o: (o.sequence if o.sequence is not None else 0, o.time_us))
    return StreamsDocument(header, obs)


def _load(source: str | Path | bytes) -> tuple[bytes, str]:
    if isinstance(source, (bytes, bytearray)):
        return bytes(source), "document"
    path = Path(source)
    if not path.is_file():
        raise FileNotFoundError(2, "MTConnect file not found", str(path))
    return path.read_bytes(), path.name


def parse_shdr(source: str | Path, devices: DeviceModel | None = None, *, text: str | None = None
               ) -> list[Observation]:
    """Read an SHDR adapter log: ``timestamp|key|value|key|value...`` lines, and its asset commands.

    Parameters
    ----------
    source : str or Path
        The log file (or a label when `text` is given).
    devices : DeviceModel, optional
        Tells which keys are conditions (5 fields: level|nativeCode|
        nativeSeverity|qualifier|message), messages (2: nativeCode|text),
        alarms (5) and time series (3: count|rate|values).  Without it, a
        ``NORMAL``/``WARNING``/``FAULT`` value with 5 fields is a condition, a
        count|rate|values triple a time series, a lone key with 2 fields a
        message, and everything else key|value pairs.
    text : str, optional
        The log's content instead of reading `source`.

    Returns
    -------
    list of Observation
        In file order; lines starting with ``*`` (protocol comments) are
        skipped.  ``@ASSET@`` (one line, or a ``--multiline--TAG`` block),
        ``@REMOVE_ASSET@``, ``@REMOVE_ALL_ASSETS@`` and ``@UPDATE_ASSET@``
        become ``ASSET*`` observations in file order at their own (possibly
        out-of-order) times; a ``CuttingTool``'s identity and life counts are parsed from
        its XML (:func:`~drivesense.io.mtconnect_assets.parse_cutting_tool`).
        Other ``@...@`` commands are skipped with one
        :class:`MTConnectWarning` naming the first such line.

    Raises
    ------
    InvalidSignalError
        A line without a valid timestamp, with a dangling key, or an asset
        block that is never closed (naming the line).
    """
    where = Path(source).name
    if text is None:
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(2, "SHDR file not found", str(path))
        text = path.read_text(encoding="utf-8", errors="replace")
    out: list[Observation] = []
    lines = text.splitlines()
    unknown: list[str] = []
    broken: list[str] = []
    i = 0
    while i < len(lines):
        line, at = lines[i], f"{where}, line {i + 1}"
        i += 1
        if not line.strip() or line.startswith("*"):
            continue
        fields = line.split("|")
        t = parse_timestamp(fields[0], at)
        rest = fields[1:]
        if rest and rest[0].strip().startswith("@"):
            got = read_asset_command(rest, lines, i, at)
            if got is None:
                unknown.append(f"{at}: unknown SHDR command {rest[0].strip()!r}")
                continue
            records, i = got
            for kind, key, value, extra in records:
                if isinstance(value, dict) and "error" in value:
                    broken.append(value["error"])
                out.append(Observation(key, t, value, kind, None, extra))
            continue
        out.extend(_shdr_fields(rest, t, devices, at))
    for notes, what, such in ((unknown, " skipped", "unknown command lines"),
                              (broken, "; the tool is kept without its XML fields", "broken CuttingTool assets")):
        if notes:
            more = f" ({len(notes)} {such} in all)" if len(notes) > 1 else ""
            warnings.warn(notes[0] + what + more, MTConnectWarning, stacklevel=2)
    return out


def _shdr_kind(key: str, rest: list[str], devices: DeviceModel | None, whole_line: bool) -> str:
    item = devices.lookup(key) if devices else None
    if item is not None:
        if item.category == "CONDITION":
            return "CONDITION"
        if item.type in ("MESSAGE", "ALARM"):
            return item.type
        if item.representation == "TIME_SERIES":
            return "TIME_SERIES"
        return "SAMPLE" if item.category == "SAMPLE" else "EVENT"
    if not whole_line:  # multi-field items stand alone on their line
        return "VALUE"
    if len(rest) == 6 and rest[1].upper() in _LEVELS[:3]:
        return "CONDITION"
    if len(rest) == 4 and rest[1].strip().isdigit() and len(rest[3].split()) == int(rest[1]) > 1:
        return "TIME_SERIES"
    if len(rest) == 3:
        return "MESSAGE"
    return "VALUE"


def _shdr_fields(rest: list[str], t: int, devices: DeviceModel | None, at: str) -> Iterable[Observation]:
    i = 0
    while i < len(rest):
        key = rest[i].strip()
        kind = _shdr_kind(key, rest[i:], devices, whole_line=i == 0)
        width = {"CONDITION": 5, "MESSAGE": 2, "ALARM": 5, "TIME_SERIES": 3}.get(kind, 1)
        vals = rest[i + 1:i + 1 + width]
        if len(vals) < width or not key:
            raise InvalidSignalError(f"{at}: {kind.lower()} item {key!r} needs {width} field(s), has {len(vals)}")
        if kind == "CONDITION":
            extra = dict(zip(("nativeCode", "nativeSeverity", "qualifier", "message"), vals[1:]))
            yield Observation(key, t, vals[0].strip().upper(), "CONDITION", None, extra)
        elif kind == "MESSAGE":
            yield Observation(key, t, vals[1], "MESSAGE", None, {"nativeCode": vals[0]})
        elif kind == "ALARM":
            yield Observation(key, t, vals[4], "ALARM", None, dict(zip(("code", "nativeCode", "severity",
                                                                      "state"), vals[:4])))
        elif kind == "TIME_SERIES":
            arr = _number(vals[2])
            arr = None if arr is None else np.atleast_1d(np.array(arr, float))
            extra = {"sample_rate": float(vals[1])} if vals[1].strip() else {}
            yield Observation(key, t, arr, "TIME_SERIES", None, extra)
        else:
            value = _number(vals[0])
            yield Observation(key, t, value, "EVENT" if kind == "EVENT" or isinstance(value, str) else "SAMPLE")
        i += 1 + width


from .mtconnect_resample import read_mtconnect, to_recording  # noqa: E402
