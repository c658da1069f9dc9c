"""Reading experiment files (see :mod:`drivesense.io.xml_format`): streaming, validated, safe.

The file is parsed once with :func:`~drivesense.io.xml_safe.safe_iterparse`.
Each ``dataGroup`` is decoded as soon as it ends, straight into its channel's
final array (allocated from the channel's declared ``samples``, after checking
that the file can hold them), and its text is dropped; what remains is a small
skeleton tree (metadata, one empty element per group) that is validated
against the XSD and mapped to Recordings.
"""

from __future__ import annotations

import functools
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from .. import units as _units
from ..errors import ConfigError, DriveSenseError, InvalidSignalError, UnitError
from ..recording import META_ATTR, Recording
from .xml_format import (FORMAT_VERSION, INTEGER_RE, JSON_NS, NAMESPACE, SCHEMA_PATH, SUMMARY_XSLT_PATH, XML_NS,
                         Experiment, b64_decode_into, default_sensor)
from .xml_safe import DEFAULT_LIMITS, XMLLimits, local_name, parse_file, safe_iterparse

__all__ = ["read_experiment", "read_xml", "validate_xml", "transform_xml"]

_DTYPES = {("float64", "little"): "<f8", ("float32", "little"): "<f4",
           ("float64", "big"): ">f8", ("float32", "big"): ">f4"}


def _scalar(text: str) -> Any:
    try:
        v = float(text)
    except ValueError:
        return text
    return int(text) if INTEGER_RE.match(text) else (v if math.isfinite(v) else text)


def _xml_json(el: Any, where: str) -> Any:
    """Inverse of :func:`_json_xml` for one ``j:*`` element."""
    kind, text = local_name(el.tag), el.text or ""
    if el.get("escaped") == "true":
        try:
            text = json.loads(f'"{text}"')
        except ValueError:
            raise InvalidSignalError(f"{where}, line {el.sourceline}: bad escaped j:string") from None
    if kind == "string":
        return text
    if kind == "null":
        return None
    if kind == "boolean":
        if text.strip() not in ("true", "false", "1", "0"):
            raise InvalidSignalError(f"{where}, line {el.sourceline}: j:boolean {text!r:.30}")
        return text.strip() in ("true", "1")
    if kind == "number":
        v = _scalar(text.strip())
        if isinstance(v, str):
            raise InvalidSignalError(f"{where}, line {el.sourceline}: j:number {text!r:.30} is not a "
                                     "finite number")
        return v
    children = [c for c in el if isinstance(c.tag, str) and c.tag.startswith(JSON_NS)]
    if kind == "array":
        return [_xml_json(c, where) for c in children]
    if kind == "map":
        out = {}
        for c in children:
            key = c.get("key")
            if key is None:
                raise InvalidSignalError(f"{where}, line {c.sourceline}: j:{local_name(c.tag)} in a j:map "
                                         "has no key attribute")
            if c.get("escaped-key") == "true":
                key = json.loads(f'"{key}"')
            out[key] = _xml_json(c, where)
        return out
    raise InvalidSignalError(f"{where}, line {el.sourceline}: unknown JSON element j:{kind}")


def _generic(el: Any) -> Any:
    """Foreign XML as nested dicts: ``@attr``, child elements by local name, ``#text``."""
    out: dict[str, Any] = {f"@{local_name(k) or k}": v for k, v in el.attrib.items()}
    for child in el:
        if not isinstance(child.tag, str):
            continue
        key, value = local_name(child.tag), _generic(child)
        if key in out:
            out[key] = (out[key] if isinstance(out[key], list) else [out[key]]) + [value]
        else:
            out[key] = value
    text = (el.text or "").strip()
    if not out:
        return _scalar(text) if text else None
    if text:
        out["#text"] = _scalar(text)
    return out


def _free_content(el: Any, where: str) -> tuple[bool, Any]:
    """(present, value) of a configuration/state element."""
    for child in el:
        if isinstance(child.tag, str) and child.tag == JSON_NS + "map":
            return True, _xml_json(child, where)
    value = _generic(el)
    if value is None or value == {}:
        return False, None
    return True, value if isinstance(value, dict) else {"#text": value}


@functools.lru_cache(maxsize=1)
def _schema() -> Any:
    from lxml import etree

    return etree.XMLSchema(parse_file(SCHEMA_PATH))


def _int_attr(el: Any, name: str, where: str) -> int:
    text = el.get(name)
    tag = local_name(el.tag)
    if text is None:
        raise InvalidSignalError(f"{where}, line {el.sourceline}, <{tag}>: attribute {name!r} is missing")
    try:
        value = int(text.strip())
    except ValueError:
        value = -1
    if value < 0:
        raise InvalidSignalError(f"{where}, line {el.sourceline}, <{tag}>: {name}={text!r:.40} is not a "
                                 "non-negative integer")
    return value


class _Channel:
    """Decoding state of one channel while the file streams by."""

    def __init__(self, el: Any, where: str, file_size: int, limits: XMLLimits) -> None:
        self.el, self.where = el, where
        self.name = el.get("name") or "?"
        self.line = el.sourceline
        n = _int_attr(el, "samples", self.at)
        if n > min(limits.max_samples, file_size):
            raise InvalidSignalError(f"{self.at}: samples={n} is more than the file can hold "
                                     f"({file_size} bytes; limit {limits.max_samples})")
        self.data = np.empty(n, np.float64)
        self.pos = 0
        self.float32 = False

    @property
    def at(self) -> str:
        return f"{self.where}, line {self.line}, channel {self.name!r}"

    def add(self, el: Any) -> None:
        at = f"{self.where}, line {el.sourceline}, dataGroup of channel {self.name!r}"
        count = _int_attr(el, "count", at)
        if self.pos + count > self.data.size:
            raise InvalidSignalError(f"{at}: wrong length: count={count} makes {self.pos + count} samples, "
                                     f"the channel declares samples={self.data.size}")
        enc, dtype, order = el.get("encoding", "base64"), el.get("dtype", "float64"), el.get("byteOrder", "little")
        if len(el):
            raise InvalidSignalError(f"{at}: a dataGroup holds only data, found <{local_name(el[0].tag)}>")
        text = el.text or ""
        out = self.data[self.pos:self.pos + count]
        if enc == "text":
            values = text.split()
            if len(values) != count:
                raise InvalidSignalError(f"{at}: wrong length: {len(values)} values, count={count}")
            try:
                out[:] = np.array(values, dtype=np.float64)
            except ValueError:
                bad = next(i for i, v in enumerate(values) if not _is_float(v))
                raise InvalidSignalError(f"{at}: value {bad} ({values[bad]!r:.30}) is not a number") from None
        elif enc == "base64":
            if (dtype, order) not in _DTYPES:
                raise InvalidSignalError(f"{at}: dtype={dtype!r} byteOrder={order!r}; known: float64/float32, "
                                         "little/big")
            np_dtype = np.dtype(_DTYPES[dtype, order])
            if np_dtype == np.dtype(np.float64) and np_dtype.isnative:
                b64_decode_into(text, out.view(np.uint8), at)
            else:
                raw = np.empty(count * np_dtype.itemsize, np.uint8)
                b64_decode_into(text, raw, at)
                out[:] = raw.view(np_dtype)
                self.float32 |= dtype == "float32"
        else:
            raise InvalidSignalError(f"{at}: encoding={enc!r}; known: base64, text")
        self.pos += count

    def finish(self) -> None:
        if self.pos != self.data.size:
            raise InvalidSignalError(f"{self.at}: wrong length: the dataGroups hold {self.pos} samples, "
                                     f"samples={self.data.size}")


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _check_root(el: Any, where: str) -> None:
    if el.tag == XML_NS + "experimentResults":
        version = el.get("formatVersion", "")
        if version and not re.fullmatch(r"1\.[0-9]+", version):
            raise InvalidSignalError(f"{where}, line {el.sourceline}: formatVersion={version!r}; this reader "
                                     f"reads 1.x (it writes {FORMAT_VERSION})")
        return
    m = re.fullmatch(r"\{urn:drivesense:experiment:(\d+)\}experimentResults", str(el.tag))
    if m:
        raise InvalidSignalError(f"{where}: written in format version {m.group(1)}.x; this reader reads 1.x "
                                 f"(namespace {NAMESPACE})")
    raise InvalidSignalError(f"{where}, line {el.sourceline}: root element <{el.tag}> is not "
                             f"{{{NAMESPACE}}}experimentResults; not a drivesense experiment file")


def _schema_error(tree: Any, where: str) -> None:
    schema = _schema()
    if schema.validate(tree):
        return
    err = schema.error_log[0]
    msg = err.message.replace("{%s}" % NAMESPACE, "").replace("{%s}" % JSON_NS[1:-1], "j:")
    raise InvalidSignalError(f"{where}, line {err.line}: does not follow the schema: {msg}")


def _texts(root: Any) -> tuple[str, ...]:
    out: list[str] = []
    for el in root.iter():
        if not isinstance(el.tag, str) or el.tag == XML_NS + "dataGroup":
            continue
        if not el.tag.startswith((XML_NS, JSON_NS)):
            out.append(local_name(el.tag))
        out.extend(v for v in el.attrib.values() if v.strip())
        out.extend(t.strip() for t in (el.text, el.tail) if t and t.strip())
    return tuple(out)


def _recording(m: Any, base: dict, chans: dict, where: str, notes: list[str]) -> Recording:
    meta = dict(base)
    present, own = _free_content(m.find(XML_NS + "configuration"), where) if m.find(
        XML_NS + "configuration") is not None else (False, None)
    if present:
        meta.update(own)
    for key, tag in (("start_state", "startState"), ("end_state", "endState")):
        el = m.find(XML_NS + tag)
        if el is not None:
            present, value = _free_content(el, where)
            if present:
                meta[key] = value
    if "name" not in meta and m.get("name"):
        meta["name"] = m.get("name")
    label = f"{where}, line {m.sourceline}, measurement {m.get('name') or '(unnamed)'!r}"
    arrays: dict[str, tuple[np.ndarray, str]] = {}
    grouping: dict[str, list[str]] = {}
    ref = None
    for iface in m.iterfind(XML_NS + "interface"):
        for sensor in iface.iterfind(XML_NS + "sensor"):
            for el in sensor.iterfind(XML_NS + "channel"):
                ch = chans[el]
                name = ch.name
                if name in arrays:
                    raise InvalidSignalError(f"{ch.at}: channel {name!r} appears twice in the measurement")
                try:
                    fs, t0 = float(el.get("sampleRate")), float(el.get("startTime", "0"))
                except (TypeError, ValueError):
                    raise InvalidSignalError(f"{ch.at}: sampleRate/startTime are not numbers") from None
                if ref is None:
                    ref = (name, fs, t0, ch.data.size)
                elif (fs, t0, ch.data.size) != ref[1:]:
                    raise InvalidSignalError(
                        f"{ch.at}: sampleRate={fs:g} Hz, startTime={t0!r} s, samples={ch.data.size} differ from "
                        f"channel {ref[0]!r} ({ref[1]:g} Hz, {ref[2]!r} s, {ref[3]}); a Recording has one time "
                        "base: resample the channels first")
                unit = el.get("units", "")
                try:
                    info = _units.unit_info(unit, quantity=_units.quantity_of_channel(name), name=name)
                except UnitError as exc:
                    raise UnitError(f"{ch.at}: {exc}") from None
                if info.factor != 1.0:
                    ch.data *= info.factor
                    notes.append(f"{name} {unit}->{_units.SI_UNITS[info.quantity]}")
                if ch.float32:
                    notes.append(f"{name} stored as float32")
                arrays[name] = (ch.data, _units.SI_UNITS[info.quantity])
                grouping[name] = [iface.get("name", ""), sensor.get("name", "")]
    if ref is None:
        raise InvalidSignalError(f"{label}: no channels; a Recording needs at least one")
    if any(list(default_sensor(c, meta.get("sensors"))) != g for c, g in grouping.items()):
        meta["sensors"] = grouping
    if notes:
        step = f"read_xml {where}: " + "; ".join(notes)
        meta["provenance"] = [*meta.get("provenance", []), step] if isinstance(
            meta.get("provenance", []), list) else [step]
    _, fs, t0, n = ref
    ds = xr.Dataset({k: ("time", a, {"units": u}) for k, (a, u) in arrays.items()},  # no copies; Recording
                    attrs={"fs": fs, "t0": t0, META_ATTR: json.dumps(meta, ensure_ascii=False)})  # builds time
    try:
        return Recording(ds)
    except DriveSenseError as exc:
        raise type(exc)(f"{label}: {exc}") from None
    except TypeError as exc:
        raise InvalidSignalError(f"{label}: metadata is not JSON ({exc})") from None


def read_experiment(path: str | Path, *, validate: bool = True, limits: XMLLimits = DEFAULT_LIMITS
                    ) -> Experiment:
    """Read an experiment file, streaming the samples.

    Parameters
    ----------
    path : str or Path
        The ``.xml`` file.
    validate : bool, optional
        Check the file against the XSD (default True; errors name the line
        and element).
    limits : XMLLimits, optional
        Size and depth limits of the hardened parser.

    Returns
    -------
    Experiment
        One Recording per measurement (SI; units converted and noted in the
        provenance when the file uses others), the file's id, created time,
        format version, experimenters and every text of the document.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    InvalidSignalError
        Unsafe XML (DOCTYPE/entities), syntax errors or a truncated file, bad
        base64, wrong lengths, schema violations, channels of one measurement
        on different time bases, non-finite samples; naming line and element.
    UnitError
        A channel's units are unknown or do not fit its quantity.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(2, "XML file not found", str(path))
    where, size = path.name, path.stat().st_size
    chans: dict[Any, _Channel] = {}
    cur: _Channel | None = None
    root = None
    for event, el in safe_iterparse(path, where=where, limits=limits):
        if root is None:
            _check_root(el, where)
            root = el
        tag = el.tag
        if event == "start":
            if tag == XML_NS + "channel" and el.getparent() is not None and el.getparent().tag == XML_NS + "sensor":
                cur = chans[el] = _Channel(el, where, size, limits)
        elif tag == XML_NS + "dataGroup":
            if cur is not None and el.getparent() is cur.el:
                cur.add(el)
                el.text = None
        elif cur is not None and el is cur.el:
            cur.finish()
            cur = None
    if root is None:
        raise InvalidSignalError(f"{where}: no root element")
    if validate:
        _schema_error(root.getroottree(), where)
    personnel = root.find(XML_NS + "personnel")
    people = [] if personnel is None else [
        {local_name(k) or k: v for k, v in e.attrib.items()} for e in personnel.iterfind(XML_NS + "experimenter")]
    in_rec = personnel is not None and personnel.get("inRecording", "true").strip() not in ("false", "0")
    config = root.find(XML_NS + "configuration")
    base: dict = {}
    notes: list[str] = []
    if config is not None:
        present, value = _free_content(config, where)
        if present:
            base.update(value)
            if not any(c.tag == JSON_NS + "map" for c in config if isinstance(c.tag, str)):
                notes.append("configuration converted from foreign XML")
    if in_rec and people:
        base["personnel"] = people
    measurements = root.findall(XML_NS + "measurement")
    if not measurements:
        raise InvalidSignalError(f"{where}: no <measurement>; an experiment needs at least one")
    recs = tuple(_recording(m, base, chans, where, list(notes)) for m in measurements)
    return Experiment(recs, root.get("id") or "", root.get("created") or "",
                      root.get("formatVersion") or FORMAT_VERSION, tuple(people) if in_rec else (),
                      _texts(root))


def read_xml(path: str | Path, *, measurement: int | str | None = None, validate: bool = True,
             limits: XMLLimits = DEFAULT_LIMITS) -> Recording:
    """Read one measurement of an experiment file as a Recording.

    Parameters
    ----------
    path : str or Path
        The ``.xml`` file.
    measurement : int or str, optional
        Index (0-based) or name of the measurement; may be left out when the
        file holds exactly one.
    validate : bool, optional
        Check the file against the XSD (default True).
    limits : XMLLimits, optional
        Parser limits.

    Returns
    -------
    Recording

    Raises
    ------
    ConfigError
        Several measurements and none chosen, no such measurement, or a
        name that several measurements share (the message lists the indices).
    """
    exp = read_experiment(path, validate=validate, limits=limits)
    names = [r.name for r in exp.recordings]
    if measurement is None:
        if len(exp.recordings) > 1:
            raise ConfigError(f"{Path(path).name} holds {len(names)} measurements ({names}); choose one")
        return exp.recordings[0]
    if isinstance(measurement, int) and not isinstance(measurement, bool):
        if -len(names) <= measurement < len(names):
            return exp.recordings[measurement]
    elif measurement in names:
        hits = [k for k, n in enumerate(names) if n == measurement]
        if len(hits) > 1:      # files of other tools may repeat a name (drivesense's writer does not)
            choices = ", ".join(f"{k} {n!r}" for k, n in enumerate(names))
            raise ConfigError(f"{Path(path).name}: {len(hits)} measurements are named {measurement!r} (indices "
                              f"{', '.join(map(str, hits))}); choose one by its 0-based index: {choices}")
        return exp.recordings[hits[0]]
    raise ConfigError(f"{Path(path).name}: no measurement {measurement!r} (has {names})")


def validate_xml(path: str | Path, *, limits: XMLLimits = DEFAULT_LIMITS) -> dict:
    """Check a file completely (safety, syntax, schema, data) and summarise it.

    Parameters
    ----------
    path : str or Path
        The ``.xml`` file.
    limits : XMLLimits, optional
        Parser limits.

    Returns
    -------
    dict
        ``file, id, created, format_version, measurements`` (each with name,
        fs [Hz], samples, duration [s] and channels with units).

    Raises
    ------
    InvalidSignalError, UnitError
        The first problem found, naming line and element.
    """
    exp = read_experiment(path, validate=True, limits=limits)
    return {"file": str(path), "id": exp.id, "created": exp.created, "format_version": exp.format_version,
            "measurements": [{"name": r.name, "fs_hz": r.fs, "samples": r.n_samples, "duration_s": r.duration,
                              "channels": {c: r.units(c) for c in r.channels}} for r in exp.recordings]}


def transform_xml(path: str | Path, xslt: str | Path | None = None, *,
                  limits: XMLLimits = DEFAULT_LIMITS) -> str:
    """Apply an XSLT 1.0 sheet to an experiment file (no file or network access from the sheet).

    Parameters
    ----------
    path : str or Path
        The ``.xml`` file (parsed whole, with the hardened parser).
    xslt : str or Path, optional
        The sheet; default :data:`~drivesense.io.xml_format.SUMMARY_XSLT_PATH`
        (a CSV summary, one row per channel).
    limits : XMLLimits, optional
        Parser limits (for the file and the sheet).

    Returns
    -------
    str
        The transformation's output.

    Raises
    ------
    ConfigError
        The sheet is not valid XSLT, or fails while running.
    """
    from lxml import etree

    doc = parse_file(path, limits=limits)
    sheet = parse_file(SUMMARY_XSLT_PATH if xslt is None else xslt, limits=limits)
    name = Path(xslt).name if xslt is not None else SUMMARY_XSLT_PATH.name
    try:
        transform = etree.XSLT(sheet, access_control=etree.XSLTAccessControl.DENY_ALL)
        return str(transform(doc))
    except (etree.XSLTParseError, etree.XSLTApplyError) as exc:
        raise ConfigError(f"{name}: XSLT failed: {exc}") from None
