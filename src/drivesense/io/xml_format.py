"""The XML experiment format (second paper, Sec. 7, Fig. 15): Recordings <-> self-describing XML.

A file is one experiment::

    experimentResults  formatVersion="1.0" id=... created=...
      personnel        experimenter name=... (at least one)
      configuration    free content: what does not change between measurements
      measurement      (at least one) name=...
        startState, endState   free content: the measurement's own settings
        configuration          (optional) what this measurement adds
        interface -> sensor -> channel name units sampleRate startTime samples
                                 dataGroup count encoding dtype byteOrder

Each measurement is one :class:`~drivesense.recording.Recording`.  The schema
(:data:`SCHEMA_PATH`, XSD 1.0) ships with the package; extension points and
versioning are described in it.  The mapping is lossless: samples are written
as base64 of little-endian float64 (bit-exact) unless asked otherwise, and the
Recording's metadata goes to ``configuration`` (keys every measurement shares),
the measurement's ``configuration`` (the rest), ``startState`` / ``endState``
(``meta["start_state"]`` / ``meta["end_state"]``) and ``personnel``
(``meta["personnel"]``, a list of ``{"name": ..., ...}`` with string values),
all in the W3C XPath-functions JSON vocabulary (``j:map``, ``j:string``...).
Files from other tools may put any XML there: it is converted to nested dicts.

Reading streams the file (:func:`drivesense.io.xml_safe.safe_iterparse`):
samples are decoded group by group straight into their final arrays, so the
peak memory is the sample data plus one group, and the parser is hardened
(no DTD, no entities, no network, size and depth limits).
"""

from __future__ import annotations

import binascii
import getpass
import json
import re
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numba
import numpy as np

from ..errors import ConfigError, InvalidSignalError
from ..recording import Recording

__all__ = ["NAMESPACE", "JSON_NAMESPACE", "FORMAT_VERSION", "SCHEMA_PATH", "SUMMARY_XSLT_PATH",
           "Experiment", "write_xml", "read_experiment", "read_xml", "validate_xml", "transform_xml",
           "default_sensor", "utc_now"]

#: Namespace of the format (names the major version; the minor one is ``formatVersion``).
NAMESPACE = "urn:drivesense:experiment:1"
#: W3C namespace of the JSON-in-XML vocabulary used for metadata.
JSON_NAMESPACE = "http://www.w3.org/2005/xpath-functions"
#: Version this module writes; it reads every 1.x.
FORMAT_VERSION = "1.0"
_SCHEMA_DIR = Path(__file__).with_name("schema")
#: The XSD 1.0 schema shipped with the package.
SCHEMA_PATH = _SCHEMA_DIR / "drivesense-experiment-1.0.xsd"
#: The shipped XSLT sheet: CSV summary of measurements and channels.
SUMMARY_XSLT_PATH = _SCHEMA_DIR / "summary.xsl"

XML_NS = "{%s}" % NAMESPACE
JSON_NS = "{%s}" % JSON_NAMESPACE
_STATES = (("start_state", "startState"), ("end_state", "endState"))
_GROUP = {"base64": 1 << 18, "text": 1 << 16}  # samples per dataGroup written
_BAD_CHARS = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
_NCNAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*$")
INTEGER_RE = re.compile(r"^-?[0-9]+$")


def utc_now() -> str:
    """The current time as ISO 8601 UTC with microseconds (``2024-05-01T12:00:00.000000Z``).

    Returns
    -------
    str
    """
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


# ------------------------------------------------------------------ the model
@dataclass(frozen=True)
class Experiment:
    """One experiment: its measurements as Recordings, plus identity.

    Parameters
    ----------
    recordings : tuple of Recording
        One per measurement, in file order (at least one).
    id : str
        Experiment identifier (``experimentResults/@id``), e.g. a UUID.
    created : str
        Creation time, ISO 8601 (UTC when written by drivesense).
    format_version : str, optional
        ``formatVersion`` of the file it came from (default: this module's).
    personnel : tuple of dict, optional
        Experimenters named in the data (``{"name": ..., ...}``).
    texts : tuple of str, optional
        Every text of the source document except the samples (element text,
        attribute values, names of foreign elements), for full-text search;
        empty when built from Recordings (see :meth:`search_texts`).
    """

    recordings: tuple[Recording, ...]
    id: str
    created: str
    format_version: str = FORMAT_VERSION
    personnel: tuple[dict, ...] = ()
    texts: tuple[str, ...] = field(default=(), repr=False)

    @classmethod
    def from_recordings(cls, recordings: Recording | Sequence[Recording], *, id: str | None = None,
                        created: str | None = None) -> Experiment:
        """Wrap Recordings as a new experiment.

        Parameters
        ----------
        recordings : Recording or sequence of Recording
            The measurements.
        id : str, optional
            Identifier (default: a new UUID, 32 hex digits).
        created : str, optional
            ISO 8601 time (default: now, UTC).

        Returns
        -------
        Experiment
        """
        recs = _as_recordings(recordings)
        people = _split_meta([r.meta for r in recs])[0]
        return cls(recs, id or uuid.uuid4().hex, created or utc_now(), FORMAT_VERSION,
                   tuple(people or ()))

    def search_texts(self) -> list[str]:
        """Every text of the experiment as the XML file holds it (keys, values, names, units).

        Returns
        -------
        list of str
            :attr:`texts` when read from a file; otherwise generated from the
            Recordings' metadata and channels.
        """
        if self.texts:
            return list(self.texts)
        out = [self.id, self.created]
        for rec in self.recordings:
            _json_texts(rec.meta, out)
            for ch in rec.channels:
                out.extend([ch, rec.units(ch), *default_sensor(ch, rec.meta.get("sensors"))])
        return out


def _as_recordings(recordings: Any) -> tuple[Recording, ...]:
    if isinstance(recordings, Experiment):
        return recordings.recordings
    recs = (recordings,) if isinstance(recordings, Recording) else tuple(recordings)
    if not recs or not all(isinstance(r, Recording) for r in recs):
        raise ConfigError("an experiment needs one or more Recordings")
    return recs


def _unique_names(recs: tuple[Recording, ...]) -> tuple[Recording, ...]:
    """The recordings with unique names: a repeated ``meta["name"]`` gets `` (2)``, `` (3)``... (noted in provenance).

    Measurement names select a measurement (``read_xml(measurement=NAME)``,
    ``xml import --measurement NAME``), so one experiment never holds two
    measurements of one name.
    """
    taken = {r.meta.get("name") for r in recs}
    seen: set = set()
    out = []
    for rec in recs:
        name = rec.meta.get("name")
        if isinstance(name, str) and name in seen:
            k = 2
            while f"{name} ({k})" in taken:
                k += 1
            new = f"{name} ({k})"
            taken.add(new)
            prov = rec.meta.get("provenance", [])
            step = f"write_xml: renamed {name!r} to {new!r} (measurement names are unique within an experiment)"
            rec = rec.with_meta(name=new, provenance=[*prov, step] if isinstance(prov, list) else [step])
            name = new
        seen.add(name)
        out.append(rec)
    return tuple(out)


def _json_texts(value: Any, out: list[str]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            out.append(k)
            _json_texts(v, out)
    elif isinstance(value, list):
        for v in value:
            _json_texts(v, out)
    elif value is not None:
        out.append(value if isinstance(value, str) else json.dumps(value))


def default_sensor(channel: str, sensors: Mapping | None = None) -> tuple[str, str]:
    """(interface, sensor) a channel is written under.

    Parameters
    ----------
    channel : str
        Channel name, e.g. ``"x_current_ref"``.
    sensors : mapping, optional
        ``meta["sensors"]``: channel -> ``[interface, sensor]``, which wins.

    Returns
    -------
    tuple of str
        E.g. ``("drive controller", "x servo drive")``, ``("dynamometer
        amplifier", "dynamometer")``; other channels get ``("data
        acquisition", channel)``.
    """
    if isinstance(sensors, Mapping) and isinstance(sensors.get(channel), (list, tuple)) \
            and len(sensors[channel]) == 2 and all(isinstance(s, str) for s in sensors[channel]):
        return tuple(sensors[channel])  # type: ignore[return-value]
    m = re.match(r"^([xyz])_(current_ref|current|motor_angle|table_position|position|velocity|"
                 r"acceleration)$", channel)
    if m:
        kind = {"current_ref": "servo drive", "current": "servo drive", "motor_angle": "motor encoder",
                "table_position": "linear scale", "position": "linear scale"}.get(m.group(2), "controller")
        return "drive controller", f"{m.group(1)} {kind}"
    if channel.startswith("spindle_"):
        return "drive controller", "spindle drive"
    if re.match(r"^force_[xyz]$", channel):
        return "dynamometer amplifier", "dynamometer"
    return "data acquisition", channel


# ------------------------------------------------------------------ metadata <-> XML
def _esc(text: str, attr: bool = False) -> str:
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace("\r", "&#13;")
    if attr:
        text = text.replace('"', "&quot;").replace("\t", "&#9;").replace("\n", "&#10;")
    return text


def _attrs(pairs: Mapping[str, Any]) -> str:
    return "".join(f' {k}="{_esc(str(v), True)}"' for k, v in pairs.items() if v is not None)


def _xml_ok(text: str) -> bool:
    return _BAD_CHARS.search(text) is None


def _check_text(text: str, what: str) -> str:
    if not _xml_ok(text):
        bad = _BAD_CHARS.search(text).group()
        raise ConfigError(f"{what} {text!r:.60} holds U+{ord(bad):04X}, which XML 1.0 cannot carry")
    return text


def _json_xml(value: Any, key: str | None = None) -> str:
    """A JSON value in the W3C XPath-functions vocabulary (prefix ``j``)."""
    ka = ""
    if key is not None:
        ka = f' key="{_esc(key, True)}"' if _xml_ok(key) else \
            f' key="{_esc(json.dumps(key)[1:-1], True)}" escaped-key="true"'
    if value is None:
        return f"<j:null{ka}/>"
    if isinstance(value, bool):
        return f"<j:boolean{ka}>{'true' if value else 'false'}</j:boolean>"
    if isinstance(value, (int, float)):
        return f"<j:number{ka}>{value!r}</j:number>"
    if isinstance(value, str):
        if _xml_ok(value):
            return f"<j:string{ka}>{_esc(value)}</j:string>"
        return f'<j:string{ka} escaped="true">{_esc(json.dumps(value)[1:-1])}</j:string>'
    if isinstance(value, dict):
        return f"<j:map{ka}>" + "".join(_json_xml(v, k) for k, v in value.items()) + "</j:map>"
    if isinstance(value, list):
        return f"<j:array{ka}>" + "".join(_json_xml(v) for v in value) + "</j:array>"
    raise ConfigError(f"metadata value {value!r:.60} is not JSON")


def _canonical_personnel(value: Any) -> bool:
    return (isinstance(value, list) and bool(value) and all(
        isinstance(e, dict) and isinstance(e.get("name"), str) and e["name"].strip()
        and all(isinstance(k, str) and _NCNAME.match(k) and not k.lower().startswith("xml")
                and isinstance(v, str) and _xml_ok(v) for k, v in e.items()) for e in value))


def _split_meta(metas: list[dict]) -> tuple[list | None, dict, list[dict]]:
    """(personnel or None, experiment configuration, per-measurement configuration)."""
    bodies = [{k: v for k, v in m.items() if k not in dict(_STATES)} for m in metas]
    dumped = [{k: json.dumps(v) for k, v in b.items()} for b in bodies]
    common = {k: v for k, v in bodies[0].items() if all(d.get(k) == dumped[0][k] for d in dumped[1:])}
    people = common.pop("personnel") if _canonical_personnel(common.get("personnel")) else None
    own = [{k: v for k, v in b.items() if k not in common and not (people and k == "personnel")}
           for b in bodies]
    return people, common, own


# ------------------------------------------------------------------ base64
_B64 = np.full(256, 255, np.uint8)
_B64[np.frombuffer(b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/", np.uint8)] = \
    np.arange(64, dtype=np.uint8)
_B64[np.frombuffer(b" \t\r\n", np.uint8)] = 64
_B64[ord("=")] = 65


@numba.njit(cache=True, nogil=True)
def _b64_kernel(src, lut, out):  # pragma: no cover - compiled
    """Decode base64 `src` (uint8) into `out`; returns (bytes written, error position, code)."""
    q, limit = 0, min(src.size // 4, out.size // 3)
    while q < limit:  # fast path: whole quads of alphabet characters
        a, b, c, d = lut[src[4 * q]], lut[src[4 * q + 1]], lut[src[4 * q + 2]], lut[src[4 * q + 3]]
        if (a | b | c | d) & 0xC0:
            break
        w = (np.uint32(a) << 18) | (np.uint32(b) << 12) | (np.uint32(c) << 6) | np.uint32(d)
        out[3 * q] = (w >> 16) & 255
        out[3 * q + 1] = (w >> 8) & 255
        out[3 * q + 2] = w & 255
        q += 1
    acc, k, o, pad = 0, 0, 3 * q, 0  # the rest (whitespace, padding, errors) character by character
    for i in range(4 * q, src.size):
        v = lut[src[i]]
        if v < 64:
            if pad:
                return o, i, 3
            acc = (acc << 6) | v
            k += 1
            if k == 4:
                if o + 3 > out.size:
                    return o, i, 2
                out[o] = (acc >> 16) & 255
                out[o + 1] = (acc >> 8) & 255
                out[o + 2] = acc & 255
                o += 3
                k = 0
                acc = 0
        elif v == 65:
            pad += 1
        elif v != 64:
            return o, i, 1
    if k == 0 and pad == 0:
        return o, -1, 0
    if (k == 2 and pad == 2) or (k == 3 and pad == 1):
        n = k - 1
        if o + n > out.size:
            return o, src.size, 2
        acc <<= 6 * (4 - k)
        out[o] = (acc >> 16) & 255
        if n == 2:
            out[o + 1] = (acc >> 8) & 255
        return o + n, -1, 0
    return o, src.size, 4


def b64_decode_into(text: str, out: np.ndarray, where: str) -> None:
    try:
        src = np.frombuffer(text.encode("ascii"), np.uint8)
    except UnicodeEncodeError as exc:
        raise InvalidSignalError(f"{where}: bad base64: non-ASCII character at {exc.start}") from None
    n, pos, code = _b64_kernel(src, _B64, out)
    if code == 1:
        raise InvalidSignalError(f"{where}: bad base64: character {chr(src[pos])!r} at {pos}")
    if code in (3, 4):
        raise InvalidSignalError(f"{where}: bad base64: wrong padding or a truncated group "
                                 f"(at character {pos})")
    if code == 2 or n != out.size:
        more = "more than" if code == 2 else f"{n} bytes, not"
        raise InvalidSignalError(f"{where}: wrong length: the base64 data decode to {more} the "
                                 f"{out.size} bytes that count needs")


# ------------------------------------------------------------------ writer
def _personnel_xml(people: list | None, experimenter: str | None) -> str:
    if people:
        rows = "".join(f"<experimenter{_attrs(p)}/>" for p in people)
        return f"<personnel>{rows}</personnel>"
    name = experimenter or getpass.getuser() or "unknown"
    _check_text(name, "experimenter")
    return f'<personnel inRecording="false"><experimenter{_attrs({"name": name})}/></personnel>'


def _state_xml(tag: str, meta: dict, key: str) -> str:
    return f"<{tag}>{_json_xml(meta[key])}</{tag}>" if key in meta else f"<{tag}/>"


def _channel_data(fh: Any, values: np.ndarray, encoding: str, dtype: str, name: str) -> None:
    n = values.size
    step = _GROUP[encoding]
    if encoding == "text":
        for i in range(0, n, step):
            chunk = values[i:i + step]
            fh.write(f'<dataGroup count="{chunk.size}" encoding="text">'.encode())
            fh.write(" ".join(map(repr, chunk.tolist())).encode())
            fh.write(b"</dataGroup>\n")
        return
    if dtype == "float32":
        with np.errstate(over="ignore"):
            arr = np.ascontiguousarray(values, dtype="<f4")
        if not np.isfinite(arr).all():
            raise ConfigError(f"channel {name!r}: values beyond the float32 range; write float64")
        attr = ' dtype="float32"'
    else:
        arr, attr = np.ascontiguousarray(values, dtype="<f8"), ""
    raw = memoryview(arr).cast("B")
    size = arr.itemsize
    for i in range(0, n, step):
        m = min(step, n - i)
        fh.write(f'<dataGroup count="{m}"{attr}>'.encode())
        fh.write(binascii.b2a_base64(raw[i * size:(i + m) * size], newline=False))
        fh.write(b"</dataGroup>\n")


def _measurement(fh: Any, rec: Recording, own: dict, encoding: str, dtype: str) -> None:
    meta = rec.meta
    name = meta.get("name")
    name = name if isinstance(name, str) and _xml_ok(name) else None
    fh.write(f"<measurement{_attrs({'name': name})}>".encode())
    fh.write("".join(_state_xml(tag, meta, key) for key, tag in _STATES).encode())
    if own:
        fh.write(f"<configuration>{_json_xml(own)}</configuration>".encode())
    runs: list[tuple[str, str, list[str]]] = []
    for ch in rec.channels:
        _check_text(ch, "channel name")
        iface, sensor = default_sensor(ch, meta.get("sensors"))
        if runs and runs[-1][:2] == (iface, sensor):
            runs[-1][2].append(ch)
        else:
            runs.append((iface, sensor, [ch]))
    for k, (iface, sensor, chans) in enumerate(runs):
        if k == 0 or runs[k - 1][0] != iface:
            fh.write(f"<interface{_attrs({'name': _check_text(iface, 'interface')})}>".encode())
        fh.write(f"<sensor{_attrs({'name': _check_text(sensor, 'sensor')})}>".encode())
        for ch in chans:
            head = {"name": ch, "units": rec.units(ch), "sampleRate": repr(rec.fs),
                    "startTime": repr(rec.t0), "samples": rec.n_samples}
            fh.write(f"<channel{_attrs(head)}>\n".encode())
            _channel_data(fh, np.asarray(rec[ch]), encoding, dtype, ch)
            fh.write(b"</channel>")
        fh.write(b"</sensor>")
        if k == len(runs) - 1 or runs[k + 1][0] != iface:
            fh.write(b"</interface>")
    fh.write(b"</measurement>\n")


def write_xml(recordings: Recording | Sequence[Recording] | Experiment, path: str | Path, *,
              encoding: str = "base64", dtype: str = "float64", experiment_id: str | None = None,
              created: str | None = None, experimenter: str | None = None) -> Path:
    """Write Recordings as one experiment file, atomically.

    Parameters
    ----------
    recordings : Recording, sequence of Recording, or Experiment
        The measurements (an Experiment also gives `experiment_id` and `created`).
    path : str or Path
        Target ``.xml`` file, replaced only once fully written.
    encoding : {"base64", "text"}, optional
        Sample encoding: base64 of the raw little-endian values (default,
        fast) or decimal text (``repr``, also exact for float64).
    dtype : {"float64", "float32"}, optional
        Stored precision for base64 (default float64, bit-exact; float32
        halves the size and rounds to ~7 digits).
    experiment_id : str, optional
        ``experimentResults/@id`` (default: the Experiment's, or a new UUID).
    created : str, optional
        ISO 8601 creation time (default: the Experiment's, or now, UTC).
    experimenter : str, optional
        Name written when the metadata names nobody (``meta["personnel"]``
        absent): the schema needs one experimenter; default the login name.
        Such a ``personnel`` is marked ``inRecording="false"`` and is not read
        back into the metadata.

    Notes
    -----
    Measurement names (``meta["name"]``) are unique within an experiment, as
    they select a measurement on reading: a name already used by an earlier
    measurement gets `` (2)``, `` (3)``... appended, in the file and so on
    reading back, and the renaming is noted in that measurement's provenance.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ConfigError
        Unknown `encoding`/`dtype`, text XML cannot carry (control characters
        in channel names), float32 overflow.
    """
    from . import atomic_output

    if encoding not in _GROUP:
        raise ConfigError(f"encoding must be 'base64' or 'text', got {encoding!r}")
    if dtype not in ("float64", "float32"):
        raise ConfigError(f"dtype must be 'float64' or 'float32', got {dtype!r}")
    exp = recordings if isinstance(recordings, Experiment) else None
    recs = _unique_names(_as_recordings(recordings))
    exp_id = experiment_id or (exp.id if exp else uuid.uuid4().hex)
    when = created or (exp.created if exp else utc_now())
    people, common, own = _split_meta([r.meta for r in recs])
    path = Path(path)
    root = _attrs({"formatVersion": FORMAT_VERSION, "id": _check_text(exp_id, "id"),
                   "created": _check_text(when, "created")})
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        fh.write(f'<?xml version="1.0" encoding="UTF-8"?>\n<experimentResults xmlns="{NAMESPACE}" '
                 f'xmlns:j="{JSON_NAMESPACE}"{root}>\n'.encode())
        fh.write((_personnel_xml(people, experimenter) + "\n").encode())
        fh.write(f"<configuration>{_json_xml(common)}</configuration>\n".encode())
        for rec, extra in zip(recs, own):
            _measurement(fh, rec, extra, encoding, dtype)
        fh.write(b"</experimentResults>\n")
    return path


from .xml_read import read_experiment, read_xml, transform_xml, validate_xml  # noqa: E402
