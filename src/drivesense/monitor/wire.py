"""Drive-signal chunks on the wire: the message format of the ``mqtt`` source and ``drivesense publish``.

One MQTT message carries one chunk of one machine's drive signals::

    offset  size  content
    0       4     magic b"DSC1"
    4       4     header length H, uint32 little-endian
    8       H     header, UTF-8 strict JSON (below)
    8+H     8*n*C the C channels' samples, float64 little-endian, channel after channel (n each)

The header::

    {"machine": "vmc1", "seq": 17, "t0": 1.7, "fs": 10000.0, "n": 500,
     "channels": [["x_current", "A"], ["x_motor_angle", "rad"], ...], "sent": 1764210000.123,
     "session": "5f0c2a91d3e4"}

``seq`` counts the chunks of a machine from 0 (the service drops a repeated or
older one and counts the gap when one is missing), ``session`` (optional, 1-64
letters, digits and ``._:-``) names the publisher's run: a publisher that
restarts sends a new session and counts ``seq`` from 0 again, and the service
starts the machine's stream afresh (:class:`StreamCursor`).  Without sessions a
chunk that counts from 0 again cannot be told from one delivered twice: it is
refused, with a message that says so.  ``t0`` is the time of the
first sample [s] on the machine's clock, ``fs`` the sample rate [Hz], units
are any the :mod:`drivesense.units` table knows (converted to SI on arrival),
``sent`` the publisher's wall clock [s since the epoch] (optional).  A message
that breaks any of this is refused with a :class:`WireError` naming the field.
"""

from __future__ import annotations

import json
import math
import struct
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from drivesense.errors import InvalidSignalError
from drivesense.units import quantity_of_channel, to_si

__all__ = ["Chunk", "WireError", "encode_chunk", "decode_chunk", "StreamCursor", "MAGIC", "MAX_MESSAGE_BYTES"]

#: First bytes of every message.
MAGIC = b"DSC1"
#: Largest message accepted [bytes] (64 MiB).
MAX_MESSAGE_BYTES = 64 * 2**20
_HEADER = struct.Struct("<4sI")
#: Characters of a session name.
_SESSION_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._:-")


class WireError(InvalidSignalError):
    """A chunk message that cannot be read (bad magic, header, lengths or values)."""


@dataclass
class Chunk:
    """A piece of one machine's drive signals, in SI, as it arrives at the service.

    Attributes
    ----------
    machine : str
        Machine id.
    seq : int
        Chunk number of this machine's stream (from 0).
    t0 : float
        Time of the first sample on the machine's clock [s].
    fs : float
        Sample rate [Hz].
    arrays : dict
        Channel name -> float64 samples [SI unit of the channel], all of one length.
    arrival : float
        Wall-clock time the chunk reached the service [s since the epoch].
    sent : float or None
        Wall-clock time the source sent it [s since the epoch], when known.
    session : str or None
        The publisher's run (``seq`` counts from 0 in each), when it says.
    """

    machine: str
    seq: int
    t0: float
    fs: float
    arrays: dict
    arrival: float = field(default_factory=time.time)
    sent: float | None = None
    session: str | None = None

    @property
    def n(self) -> int:
        """Samples per channel."""
        return len(next(iter(self.arrays.values()))) if self.arrays else 0


def encode_chunk(machine: str, seq: int, t0: float, fs: float, arrays: Mapping[str, np.ndarray],
                 units: Mapping[str, str] | None = None, *, sent: float | None = None,
                 session: str | None = None) -> bytes:
    """One message of the layout above.

    Parameters
    ----------
    machine : str
        Machine id.
    seq : int
        Chunk number (from 0).
    t0 : float
        Time of the first sample [s].
    fs : float
        Sample rate [Hz].
    arrays : mapping of str to ndarray
        Channel samples [unit of ``units``, SI by default], equally long.
    units : mapping of str to str, optional
        Unit per channel (default: the channel's SI unit).
    sent : float, optional
        Publisher's wall clock [s since the epoch] (default: now).
    session : str, optional
        The publisher's run: a new one for each start of the publisher (``seq`` from 0 in each).
    """
    if session is not None and not _valid_session(session):
        raise WireError(f"session {session!r}: 1-64 letters, digits and ._:- expected")
    names = list(arrays)
    data = [np.ascontiguousarray(arrays[c], dtype="<f8") for c in names]
    n = data[0].size if data else 0
    if any(d.ndim != 1 or d.size != n for d in data):
        raise WireError("every channel of a chunk must be 1-D and equally long")
    channels = [[c, (units or {}).get(c) or _si_unit(c)] for c in names]
    fields = {"machine": machine, "seq": int(seq), "t0": float(t0), "fs": float(fs), "n": int(n),
              "channels": channels, "sent": float(time.time() if sent is None else sent)}
    if session is not None:
        fields["session"] = session
    header = json.dumps(fields, allow_nan=False).encode()
    return _HEADER.pack(MAGIC, len(header)) + header + b"".join(d.tobytes() for d in data)


def _valid_session(value: object) -> bool:
    return isinstance(value, str) and 0 < len(value) <= 64 and set(value) <= _SESSION_CHARS


def _si_unit(channel: str) -> str:
    from drivesense.units import si_unit

    quantity = quantity_of_channel(channel)
    if quantity is None:
        raise WireError(f"channel '{channel}': not a drivesense channel name, give its unit")
    return si_unit(quantity)


def _field(header: dict, key: str, kind, check) -> object:
    value = header.get(key)
    if not isinstance(value, kind) or isinstance(value, bool) or not check(value):
        raise WireError(f"chunk header field '{key}' is missing or invalid: {value!r}")
    return value


def decode_chunk(payload: bytes, *, arrival: float | None = None) -> Chunk:
    """Read one message into a :class:`Chunk` (converted to SI), refusing anything malformed.

    Parameters
    ----------
    payload : bytes
        The message.
    arrival : float, optional
        Wall-clock arrival time [s since the epoch] (default: now).

    Raises
    ------
    WireError
        Naming what is wrong: magic, header JSON, a header field, the length, a channel's unit or values.
    """
    arrival = time.time() if arrival is None else arrival
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise WireError(f"a chunk message is bytes, got {type(payload).__name__}")
    payload = bytes(payload)
    if len(payload) > MAX_MESSAGE_BYTES:
        raise WireError(f"chunk message of {len(payload)} bytes is over the limit of {MAX_MESSAGE_BYTES}")
    if len(payload) < _HEADER.size or payload[:4] != MAGIC:
        raise WireError("not a drivesense chunk message (magic b'DSC1' missing)")
    _, size = _HEADER.unpack_from(payload)
    end = _HEADER.size + size
    if end > len(payload):
        raise WireError(f"chunk header length {size} runs past the message ({len(payload)} bytes)")
    try:
        header = json.loads(payload[_HEADER.size:end].decode("utf-8"),
                            parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    except (UnicodeDecodeError, ValueError) as exc:
        raise WireError(f"chunk header is not strict JSON: {exc}") from None
    if not isinstance(header, dict):
        raise WireError("chunk header must be a JSON object")
    machine = _field(header, "machine", str, lambda v: 0 < len(v) <= 128)
    seq = _field(header, "seq", int, lambda v: v >= 0)
    t0 = float(_field(header, "t0", (int, float), math.isfinite))
    fs = float(_field(header, "fs", (int, float), lambda v: math.isfinite(v) and v > 0))
    n = _field(header, "n", int, lambda v: v > 0)
    channels = _field(header, "channels", list, lambda v: 0 < len(v) <= 256)
    sent = header.get("sent")
    sent = float(sent) if isinstance(sent, (int, float)) and not isinstance(sent, bool) and math.isfinite(sent) \
        else None
    session = header.get("session")
    if session is not None and not _valid_session(session):
        raise WireError(f"chunk header field 'session' is invalid: {session!r} (1-64 letters, digits and ._:-)")
    body = payload[end:]
    if len(body) != 8 * n * len(channels):
        raise WireError(f"chunk of machine '{machine}' seq {seq}: {len(body)} data bytes, the header announces "
                        f"{len(channels)} channels x {n} samples x 8 = {8 * n * len(channels)}")
    arrays: dict[str, np.ndarray] = {}
    values = np.frombuffer(body, dtype="<f8").reshape(len(channels), n)
    for i, entry in enumerate(channels):
        if not (isinstance(entry, list) and len(entry) == 2 and all(isinstance(s, str) for s in entry)):
            raise WireError(f"chunk header 'channels' entry {i} must be [name, unit], got {entry!r}")
        name, unit = entry
        if name in arrays:
            raise WireError(f"chunk header names channel '{name}' twice")
        row = values[i]
        if not np.all(np.isfinite(row)):
            bad = int(np.flatnonzero(~np.isfinite(row))[0])
            raise WireError(f"chunk of machine '{machine}' seq {seq}: channel '{name}' holds NaN or inf "
                            f"(sample {bad})")
        try:
            arrays[name] = to_si(row, unit, quantity=quantity_of_channel(name), name=name)[0]
        except ValueError as exc:
            raise WireError(f"chunk of machine '{machine}' seq {seq}: {exc}") from None
    return Chunk(machine=machine, seq=seq, t0=t0, fs=fs, arrays=arrays, arrival=arrival, sent=sent, session=session)


class StreamCursor:
    """Where a machine's stream stands -- its session and last ``seq`` -- and where a chunk falls in it.

    :meth:`place` says, without changing anything, whether a chunk comes after the last one
    (``"next"``), repeats or precedes it or belongs to a run that has ended (``"old"``), or starts a new
    run of the publisher (``"restart"``: another session than the last); :meth:`advance` moves the
    cursor to a chunk taken.

    Parameters
    ----------
    session : str, optional
        Session of the last chunk taken (a cursor restored from a mark).
    seq : int, optional
        Its ``seq`` (None: nothing taken yet).
    """

    #: Ended sessions remembered (a late chunk of one of them is old, not a restart).
    KEEP_ENDED = 16

    def __init__(self, session: str | None = None, seq: int | None = None) -> None:
        self.session, self.seq = session, seq
        self.ended: list[str] = []
        self.restarts = 0

    def place(self, chunk: Chunk) -> str:
        """``"next"``, ``"old"`` or ``"restart"`` (see above).

        Parameters
        ----------
        chunk : Chunk
            A chunk of this stream's machine.
        """
        if self.seq is None:
            return "next"
        if chunk.session != self.session:
            return "old" if chunk.session in self.ended else "restart"
        return "next" if chunk.seq > self.seq else "old"

    def advance(self, chunk: Chunk) -> None:
        """Take a chunk (not an old one) as the stream's last.

        Parameters
        ----------
        chunk : Chunk
            The chunk.
        """
        if self.seq is not None and self.place(chunk) == "restart":
            self.restarts += 1
            if self.session is not None and self.session not in self.ended:
                self.ended = [*self.ended, self.session][-self.KEEP_ENDED:]
        self.session, self.seq = chunk.session, chunk.seq
