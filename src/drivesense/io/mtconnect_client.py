"""A client for an MTConnect agent's REST interface: ``/probe``, ``/current``, ``/sample``.

:meth:`MTConnectClient.stream` walks the agent's buffer with
``/sample?from=N&count=C`` requests, each starting at the previous answer's
``nextSequence``, so no observation is read twice or skipped.  When the agent
answers ``OUT_OF_RANGE`` (the buffer has moved past ``from``, e.g. after a
pause longer than the buffer holds) or its ``instanceId`` changes (the agent
restarted), the client asks ``/current`` where the buffer now starts, resumes
there and records the sequence numbers it could not get.  Every response goes
through the hardened XML parser and is size-limited; only ``http``/``https``
URLs are fetched.
"""

from __future__ import annotations

import re
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError, InvalidSignalError
from ..recording import Recording
from .mtconnect import AgentError, DeviceModel, Observation, StreamsDocument, parse_devices, parse_streams
from .mtconnect_resample import to_recording
from .xml_safe import XMLLimits

__all__ = ["MTConnectClient", "StreamLog", "is_agent_url"]


def is_agent_url(source: str) -> bool:
    """Whether a FILE|URL argument is an agent URL (``http://``, ``https://``) rather than a file path.

    Parameters
    ----------
    source : str
        What the user gave.

    Returns
    -------
    bool

    Raises
    ------
    ConfigError
        A URL of another scheme (``ftp://``, ``file://``...), named in the message.
    """
    scheme, sep, _ = str(source).partition("://")
    if not sep or not re.fullmatch(r"[A-Za-z][A-Za-z0-9+.-]*", scheme):
        return False
    if scheme.lower() in ("http", "https"):
        return True
    raise ConfigError(f"{source}: unsupported URL scheme {scheme!r} (use http://, https:// or a file path)")


@dataclass
class StreamLog:
    """What :meth:`MTConnectClient.stream` did: requests, sequence range, losses.

    Parameters
    ----------
    requests : int
        HTTP requests made (``/sample`` and recovery ``/current``).
    first, last : int or None
        First and last sequence number received.
    lost : list of [int, int]
        Sequence ranges (inclusive) the agent no longer had.
    restarts : list of [int, int]
        ``[old, new]`` instanceId of every agent restart seen.
    """

    requests: int = 0
    first: int | None = None
    last: int | None = None
    lost: list[list[int]] = field(default_factory=list)
    restarts: list[list[int]] = field(default_factory=list)

    def to_dict(self) -> dict:
        """The log as a plain dict (for the metadata).

        Returns
        -------
        dict
        """
        return dict(self.__dict__)


class MTConnectClient:
    """Talk to one MTConnect agent.

    Parameters
    ----------
    url : str
        The agent's base URL, e.g. ``http://agent:5000`` or
        ``http://agent:5000/VMC-3Axis`` (one device).
    timeout : float, optional
        Per-request timeout [s] (default 10).
    max_bytes : int, optional
        Largest response accepted [bytes] (default 64 MiB).
    """

    def __init__(self, url: str, *, timeout: float = 10.0, max_bytes: int = 64 * 2**20) -> None:
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.netloc:
            raise ConfigError(f"agent URL must be http(s)://host[:port][/device], got {url!r}")
        self.url = url.rstrip("/")
        self.timeout = float(timeout)
        self.limits = XMLLimits(max_bytes=int(max_bytes))
        self._opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))

    def _get(self, path: str, **query: Any) -> tuple[bytes, str]:
        q = urllib.parse.urlencode({k: v for k, v in query.items() if v is not None})
        url = f"{self.url}/{path}" + (f"?{q}" if q else "")
        try:
            with self._opener.open(url, timeout=self.timeout) as resp:
                data = resp.read(self.limits.max_bytes + 1)
        except urllib.error.HTTPError as exc:  # agents answer errors with a document and 4xx
            data = exc.read(self.limits.max_bytes + 1)
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            raise ConfigError(f"cannot reach the MTConnect agent at {url}: {reason}") from None
        if len(data) > self.limits.max_bytes:
            raise InvalidSignalError(f"{url}: response larger than {self.limits.max_bytes} bytes")
        return data, url

    def probe(self) -> DeviceModel:
        """The agent's Devices document (``/probe``).

        Returns
        -------
        DeviceModel
        """
        data, url = self._get("probe")
        return parse_devices(data, limits=self.limits, where=url) if data else _empty(url)

    def current(self) -> StreamsDocument:
        """The latest value of every data item and the buffer's sequence range (``/current``).

        Returns
        -------
        StreamsDocument
        """
        data, url = self._get("current")
        return _streams(data, url, self.limits)

    def sample(self, start: int | None = None, count: int = 1000) -> StreamsDocument:
        """One ``/sample?from=start&count=count`` request.

        Parameters
        ----------
        start : int, optional
            First sequence number (default: the agent's oldest).
        count : int, optional
            Most observations returned (default 1000).

        Returns
        -------
        StreamsDocument

        Raises
        ------
        AgentError
            The agent's error (``code`` ``OUT_OF_RANGE`` when `start` is no longer buffered).
        """
        data, url = self._get("sample", **{"from": start, "count": int(count)})
        return _streams(data, url, self.limits)

    def stream(self, *, start: int | None = None, count: int = 1000, max_requests: int = 100,
               log: StreamLog | None = None) -> Iterator[StreamsDocument]:
        """Read the buffer from `start` until caught up, keeping sequence continuity.

        Parameters
        ----------
        start : int, optional
            First sequence number (default: the oldest the agent holds).
        count : int, optional
            Observations per request.
        max_requests : int, optional
            Stop after this many requests (bounds the walk; default 100).
        log : StreamLog, optional
            Filled with requests, sequence range, lost ranges and restarts.

        Yields
        ------
        StreamsDocument
            One per ``/sample`` answer; together they hold every observation from
            `start` on exactly once, except the ranges listed in ``log.lost``.
        """
        log = log if log is not None else StreamLog()
        next_seq, instance = start, None
        while log.requests < max_requests:
            log.requests += 1
            try:
                doc = self.sample(next_seq, count)
            except AgentError as exc:
                if exc.code != "OUT_OF_RANGE" or log.requests >= max_requests:
                    raise
                log.requests += 1
                head = self.current().header
                first, nxt = head.get("first_sequence"), head.get("next_sequence")
                if first is None or nxt is None:
                    raise
                if next_seq is not None and next_seq < first:
                    log.lost.append([next_seq, first - 1])
                    next_seq = first
                elif next_seq is not None and next_seq > nxt:  # agent restarted with fewer sequences
                    log.restarts.append([instance or -1, head.get("instance_id", -1)])
                    instance, next_seq = head.get("instance_id"), first
                else:
                    raise
                continue
            head = doc.header
            if instance is not None and head.get("instance_id") not in (None, instance):
                log.restarts.append([instance, head["instance_id"]])
                instance, next_seq = head["instance_id"], head.get("first_sequence")
                continue  # sequences of the old instance are meaningless now: start again
            instance = head.get("instance_id", instance)
            got = [o.sequence for o in doc.observations if o.sequence is not None]
            if next_seq is not None and got and min(got) < next_seq:
                raise InvalidSignalError(f"{self.url}: agent returned sequence {min(got)} before from={next_seq}")
            if next_seq is not None and head.get("first_sequence", 0) > next_seq:
                log.lost.append([next_seq, head["first_sequence"] - 1])
            if got:
                log.first = got[0] if log.first is None else log.first
                log.last = got[-1]
            yield doc
            new_next, last = head.get("next_sequence"), head.get("last_sequence")
            if new_next is None or (not got and next_seq is not None and new_next <= next_seq):
                return  # nothing new
            next_seq = new_next
            if last is not None and next_seq > last:
                return  # caught up with the agent

    def collect(self, *, start: int | None = None, count: int = 1000, max_requests: int = 100,
                fs: float | None = None, method: str = "linear", devices: DeviceModel | None = None
                ) -> Recording:
        """Probe the agent, read its buffer with :meth:`stream` and resample it into a Recording.

        Parameters
        ----------
        start : int, optional
            First sequence number (default: the oldest buffered).
        count : int, optional
            Observations per request.
        max_requests : int, optional
            Most requests.
        fs : float, optional
            Output rate [Hz] (see :func:`~drivesense.io.mtconnect_resample.to_recording`).
        method : {"linear", "hold"}, optional
            Resampling method.
        devices : DeviceModel, optional
            Use this instead of probing.

        Returns
        -------
        Recording
            ``meta["mtconnect"]`` holds the agent URL, instanceId, the sequence
            range read and any lost ranges or restarts.
        """
        devices = devices or self.probe()
        log = StreamLog()
        obs: list[Observation] = []
        for doc in self.stream(start=start, count=count, max_requests=max_requests, log=log):
            obs.extend(doc.observations)
        extra = {"agent": self.url, **log.to_dict()}
        return to_recording(obs, devices, fs=fs, method=method, source=self.url,
                            name=(devices.devices[0]["name"] if devices.devices else "mtconnect"), extra_meta=extra)


def _streams(data: bytes, url: str, limits: XMLLimits) -> StreamsDocument:
    if not data:
        _empty(url)
    return parse_streams(data, limits=limits, where=url)


def _empty(url: str) -> Any:
    raise InvalidSignalError(f"{url}: empty response")
