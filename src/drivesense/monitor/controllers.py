"""Live sources of machine controllers: an MTConnect agent (:class:`MTConnectSource`), an OPC UA server
(:class:`OPCUASource`).  Both raise from ``run`` when the connection is lost; the service calls ``run`` again
and ``seq`` and ``t0`` go on (``t0`` [s]: the stream's clock, 0 at its first sample, each chunk starting
where the one before ended)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import re
import threading
import time
from collections.abc import Mapping
from datetime import datetime, timezone
from types import SimpleNamespace
from typing import Any

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.io.mtconnect import DeviceModel, Observation, context_channel, context_factor, snake_case
from drivesense.io.mtconnect_client import MTConnectClient, StreamLog
from drivesense.nc_context import CONTEXT_CHANNELS, context_value
from drivesense.monitor.sources import Put, Source
from drivesense.monitor.wire import Chunk
from drivesense.units import SI_UNITS, quantity_of_channel, to_si

__all__ = ["MTConnectSource", "OPCUASource", "MAX_FILL_S"]

#: Longest stretch without any report that :class:`MTConnectSource` fills with held values [s]; a longer one
#: (an idle machine whose agent reports nothing) is skipped: ``t0`` jumps ahead on the agent's clock.
MAX_FILL_S = 60.0


def _positive(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ConfigError(f"source {what} must be a positive number, got {value!r}")
    return float(value)


def _str_map(value: Any, what: str) -> dict[str, str]:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and isinstance(v, str) and k and v
                                                 for k, v in value.items()):
        raise ConfigError(f"source {what} must be a table of names to strings, got {value!r}")
    return dict(value)


async def _sleep(stop: asyncio.Event, seconds: float) -> None:
    with contextlib.suppress(asyncio.TimeoutError):
        await asyncio.wait_for(stop.wait(), max(seconds, 0.0))


class MTConnectSource(Source):
    """An MTConnect agent's observations, resampled live onto a uniform grid as ``drivesense mtconnect import``.

    The first run reads ``/probe`` (data items -> channels, SI units) and ``/current``, then polls
    ``/sample?from=NEXT`` every ``interval_s`` (:class:`~drivesense.io.mtconnect_client.MTConnectClient`, in a
    worker thread).  ``NEXT`` survives restarts of :meth:`run`; sequences the agent no longer holds
    (``OUT_OF_RANGE``) count as ``lost``; after an agent restart (new ``instanceId``) its buffer is read from
    the start.  The grid (linear or zero-order hold, ``UNAVAILABLE`` bridged) starts at the channels' latest
    first report and runs to the newest report of any channel (one not reported since keeps its value:
    MTConnect reports on change), each sample emitted once; a report older than that (``late``: a restarted
    agent replaying its log) only updates a held value; over :data:`MAX_FILL_S` without reports is skipped.

    Parameters
    ----------
    machine : str
        Machine id.
    url : str
        The agent, ``http://host:5000`` or ``http://host:5000/DEVICE``.
    fs : float
        Output sample rate [Hz].
    channels : dict of str to str, optional
        dataItem id or name (or the channel ``drivesense mtconnect probe`` shows) -> drivesense channel;
        only these are emitted.  Default: every numeric SAMPLE with an SI unit that ``/current`` reports,
        named as the import names it, and the NC's context (``Execution``, ``Program``, ``LineNumber``,
        ``ToolNumber``, the feed and spindle overrides: :func:`~drivesense.io.mtconnect.context_channel`;
        the first path's where a controller has two).  Context channels are held between reports, their
        states and program names coded (:mod:`drivesense.nc_context`).
    interval_s : float
        Time between polls [s].
    count : int
        Observations per ``/sample`` request.
    timeout : float
        HTTP timeout [s].
    method : {"linear", "hold"}
        Interpolation between reports (as ``import --method``).
    max_requests : int
        Most requests per poll (a long backlog is read over several polls).
    """

    kind = "mtconnect"

    def __init__(self, machine: str, url: str, *, fs: float, channels: Mapping[str, str] | None = None,
                 interval_s: float = 0.1, count: int = 1000, timeout: float = 10.0, method: str = "linear",
                 max_requests: int = 20) -> None:
        super().__init__(machine)
        if not isinstance(url, str):
            raise ConfigError(f"source url must be http(s)://host[:port][/device], got {url!r}")
        self.client, self.url = MTConnectClient(url, timeout=_positive(timeout, "timeout [s]")), url
        self.fs, self.interval_s = _positive(fs, "fs [Hz]"), _positive(interval_s, "interval_s [s]")
        self.channels = None if channels is None else _str_map(channels, "channels")
        if self.channels is not None and len(set(self.channels.values())) != len(self.channels):
            raise ConfigError(f"source channels map two data items to one channel: {self.channels!r}")
        if method not in ("linear", "hold"):
            raise ConfigError(f"source method must be linear or hold, got {method!r}")
        for name, v in (("count", count), ("max_requests", max_requests)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"source {name} must be an integer >= 1, got {v!r}")
        self.method, self.count, self.max_requests = method, count, max_requests
        self.names: list[str] | None = sorted(set(self.channels.values())) if self.channels else None
        self.lost = self.restarts = self.late = self.requests = self._k = self._seq = 0
        self.skipped_s, self.ignored, self.connected, self._behind = 0.0, set(), False, False
        self._devices: DeviceModel | None = None
        self._next: int | None = None                      # next sequence number to ask for
        self._instance = self._start_us = None             # agent instanceId; grid start [us since the epoch]
        self._routes: dict[str, tuple | None] = {}         # dataItem key -> (channel, factor to SI, DataItem)
        self._by_id: dict[str, str] = {}                   # dataItem id -> configured channel
        self._context_items: dict[str, str] = {}           # context channel -> the dataItem id reporting it
        self._pending: dict[str, list] = {}                # channel -> [(times [us], SI values)] after the anchor
        self._newest: dict[str, int] = {}                  # channel -> newest report [us]
        self._anchor: dict[str, tuple[float, float]] = {}  # last emitted sample: time from start [s], value
        self._lock = threading.Lock()

    def describe(self) -> dict:
        """Kind, agent, channels, sequence position, lost sequences, restarts, late observations."""
        start = self._start_us
        return {"kind": self.kind, "url": self.url, "fs": self.fs, "channels": self.names or [],
                "connected": self.connected, "next_sequence": self._next, "instance_id": self._instance,
                "lost": self.lost, "restarts": self.restarts, "late": self.late, "requests": self.requests,
                "ignored": sorted(self.ignored), "samples": self._k, "chunks": self._seq,
                "waiting_for": [n for n in self.names or [] if n not in self._pending and n not in self._anchor],
                "skipped_s": round(self.skipped_s, 6), "start_time_utc": None if start is None else
                datetime.fromtimestamp(start / 1e6, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")}

    def _probe(self) -> None:
        devices = self.client.probe()
        self._routes.clear()
        self._by_id.clear()
        for key, name in (self.channels or {}).items():
            item = devices.lookup(key) or next((i for i in devices.items if i.channel == key), None)
            if item is not None and name in CONTEXT_CHANNELS:       # an event (a state, a program name): coded
                self._by_id[item.id] = name
                continue
            scale, q = item and item.scale(), quantity_of_channel(name)
            if item is None or scale is None or (q is not None and SI_UNITS[q] != scale[1]):
                raise ConfigError(f"mtconnect source {self.url}: " + (
                    f"data item {key!r} is not in the agent's /probe" if item is None else
                    f"data item {key!r} is in {item.units or 'no unit'}, channel {name!r} needs a {q} unit"
                    if scale else f"data item {key!r}: no SI unit known for {item.units!r}"))
            self._by_id[item.id] = name
        self._devices = devices

    def _route(self, key: str) -> tuple | None:
        if key not in self._routes:
            item, route = self._devices.lookup(key) if self._devices else None, None
            context = None if item is None else (self._by_id.get(item.id) if self.channels is not None
                                                  else context_channel(item))
            if context in CONTEXT_CHANNELS and self._context_items.setdefault(context, item.id) == item.id:
                route = (context, context_factor(context, item), item)      # the first path's, where there are two
            elif item is not None and item.category == "SAMPLE" and item.scale() is not None:
                (factor, unit), name, q = item.scale(), item.channel, quantity_of_channel(item.channel)
                if self.channels is not None:
                    name = self._by_id.get(item.id)
                elif q is not None and SI_UNITS[q] != unit:     # as the import: not the canonical quantity
                    name = f"{name}_{snake_case(key)}"
                route = (name, factor, item) if name else None
            self._routes[key] = route
        return self._routes[key]

    def _points(self, obs: Observation) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(channel, times [us], SI values) of one observation; empty for events and unmapped items."""
        route = self._route(obs.key) if obs.kind in ("SAMPLE", "TIME_SERIES", "EVENT") else None
        if route is None:
            return []
        name, factor, item = route
        t = np.array([obs.time_us], dtype=np.int64)
        if name in CONTEXT_CHANNELS:                    # a state, a program, a block, an override: held, coded
            try:
                value = np.nan if obs.value is None else context_value(name, obs.value) * factor
            except InvalidSignalError:
                self.ignored.add(f"{name}={obs.value!r}")
                return []
            return [(name, t, np.array([value]))]
        if obs.kind == "EVENT" or isinstance(obs.value, str):
            return []
        if obs.kind == "TIME_SERIES" and obs.value is not None:
            rate, n = obs.extra.get("sample_rate") or (item.sample_rate if item else None), obs.value.size
            if not rate:
                return []
            t = obs.time_us - np.round((n - 1 - np.arange(n)) * 1e6 / rate).astype(np.int64)
            return [(name, t, np.asarray(obs.value, float) * factor)]
        if isinstance(obs.value, tuple):
            subs = ("x", "y", "z") if len(obs.value) == 3 else [str(i) for i in range(len(obs.value))]
            return [(f"{name}_{s}", t, np.array([v * factor])) for s, v in zip(subs, obs.value)]
        return [(name, t, np.array([np.nan if obs.value is None else float(obs.value) * factor]))]

    def _take(self, observations: list[Observation]) -> None:
        for obs in observations:
            for name, t, v in self._points(obs):
                if self.names is not None and name not in self.names:
                    self.ignored.add(name)
                    continue
                ok = np.isfinite(v)                      # UNAVAILABLE: bridged, as in the import
                t, v = t[ok], v[ok]
                if t.size and name in self._anchor:
                    late = (t - self._start_us) * 1e-6 <= self._anchor[name][0]
                    if late.any():
                        self.late += int(late.sum())
                        if int(t[late][-1]) >= self._newest[name]:
                            self._anchor[name] = (self._anchor[name][0], float(v[late][-1]))
                        t, v = t[~late], v[~late]
                if t.size:
                    self._pending.setdefault(name, []).append((t, v))
                    self._newest[name] = max(self._newest.get(name, int(t[-1])), int(t.max()))

    def _emit(self) -> list[Chunk]:
        if self.names is None and self._pending:
            self.names = sorted(self._pending)
        if self.names is None or any(n not in self._pending and n not in self._anchor for n in self.names):
            for n, parts in self._pending.items():       # a channel not reported yet: the others' last reports
                self._pending[n] = [(parts[-1][0][-1:], parts[-1][1][-1:])]   # will anchor the grid's start
            return []
        if self._start_us is None:
            self._start_us = max(min(int(t.min()) for t, _ in self._pending[n]) for n in self.names)
        fs, start = self.fs, self._start_us
        last = int(math.floor((max(self._newest[n] for n in self.names) - start) * 1e-6 * fs + 1e-9))
        if last < self._k:
            return []
        if (last - self._k) / fs > MAX_FILL_S:         # nothing reported for long: skip to the new reports
            first_new = min(int(p[0].min()) for n in self.names for p in self._pending.get(n, []))
            jump = max(self._k, int(math.ceil((first_new - start) * 1e-6 * fs - 1e-9)))
            self.skipped_s, self._k = self.skipped_s + (jump - self._k) / fs, jump
        grid = np.arange(self._k, last + 1) / fs
        arrays = {}
        for n in self.names:
            parts = self._pending.pop(n, [])
            t_abs = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
            v_abs = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
            rel = (t_abs - start) * 1e-6
            anchor = [self._anchor[n]] if n in self._anchor else []
            t_all = np.concatenate([[a[0] for a in anchor], rel])
            v_all = np.concatenate([[a[1] for a in anchor], v_abs])
            order = np.argsort(t_all, kind="stable")[::-1]
            rt, idx = np.unique(t_all[order], return_index=True)      # the last report wins at equal times
            rv = v_all[order][idx]
            arrays[n] = np.interp(grid, rt, rv) if self.method == "linear" and n not in CONTEXT_CHANNELS else \
                rv[np.clip(np.searchsorted(rt, grid, side="right") - 1, 0, None)]
            self._anchor[n] = (float(grid[-1]), float(arrays[n][-1]))
            if (rel > grid[-1]).any():
                self._pending[n] = [(t_abs[rel > grid[-1]], v_abs[rel > grid[-1]])]
        step = max(1, int(math.ceil(fs)))               # at most 1 s per chunk
        chunks = [Chunk(self.machine, self._seq + i, (self._k + lo) / fs, fs,
                        {n: a[lo:lo + step].copy() for n, a in arrays.items()})
                  for i, lo in enumerate(range(0, grid.size, step))]
        self._seq, self._k = self._seq + len(chunks), last + 1
        return chunks

    def poll(self) -> tuple[list[Chunk], Exception | None]:
        """One poll (blocking; :meth:`run` runs it in a worker thread): the new chunks, and the error that
        stopped the poll early or None (what was read before it is in the chunks)."""
        with self._lock:
            observations: list[Observation] = []
            log, error, lost_seen, first = StreamLog(), None, 0, True
            try:
                if self._devices is None:
                    self._probe()
                if self._next is None:
                    doc = self.client.current()
                    self.requests += 1
                    self._instance, self._next = doc.header.get("instance_id"), doc.header.get("next_sequence")
                    self._take(doc.observations)
                    self.names = self.names or sorted(self._pending) or None   # default: what /current reports
                for doc in self.client.stream(start=self._next, count=self.count, max_requests=self.max_requests,
                                              log=log):
                    head, inst = doc.header, doc.header.get("instance_id")
                    if first and not log.restarts and None not in (inst, self._instance) and inst != self._instance:
                        # the agent restarted while we were away: NEXT means nothing in the new buffer
                        self.restarts += 1
                        self._instance, self._next, self._devices = inst, head.get("first_sequence"), None
                        break
                    first, self._instance = False, inst if inst is not None else self._instance
                    observations.extend(doc.observations)
                    self._next = head.get("next_sequence", self._next)
                    lost_seen = len(log.lost)
            except Exception as exc:                 # noqa: BLE001 - handed to run(), after the data read so far
                error = exc
            self.requests += log.requests
            self.lost += sum(b - a + 1 for a, b in log.lost)
            for _, b in log.lost[lost_seen:]:        # skipped after the last answer: not counted again
                self._next = max(self._next or 0, b + 1)
            self._behind = log.requests >= self.max_requests
            self._take(observations)
            if log.restarts:
                self.restarts += len(log.restarts)
                self._devices = None                 # probe the restarted agent again
            return self._emit(), error

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Poll and hand on the chunks until stopped; an unreadable answer is handed on (``put(error)``), an
        unreachable agent raises (see :class:`Source`).

        Parameters
        ----------
        put : callable
            ``await put(chunk_or_exception)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        loop = asyncio.get_running_loop()
        try:
            while not stop.is_set():
                began = loop.time()
                chunks, error = await asyncio.to_thread(self.poll)
                self.connected = error is None or isinstance(error, InvalidSignalError)
                for item in chunks + ([error] if self.connected and error else []):
                    await put(item)
                if not self.connected:
                    raise error
                if not self._behind:
                    await _sleep(stop, began + self.interval_s - loop.time())
        finally:
            self.connected = False


class OPCUASource(Source):
    """Variables of an OPC UA server, sampled and held on a uniform grid.

    Each run subscribes (publishing interval ``chunk_s``, a monitored item per node) and every ``chunk_s``
    emits the grid's samples up to ``now - latency_s`` (wall clock), each taking per channel the latest value
    reported no later than half a sample after it (sample-and-hold of the data changes at their source
    timestamps, or their arrival if earlier).  A variable holding arrays (a trace buffer: the samples since
    the last publish) is a block channel: its elements are consecutive samples at ``fs``, passed on in order
    (exactly, if every channel is one; else a short block is held, one over 1 s ahead trimmed).  A lost
    connection makes :meth:`run` raise; the next run goes on (``seq``, ``t0`` continuing, the outage not filled).

    Parameters
    ----------
    machine : str
        Machine id.
    url : str
        ``opc.tcp://host:port[/path]``.
    nodes : dict of str to str
        Channel name -> node id (``"ns=2;s=X.Current"``).
    fs : float
        Output sample rate [Hz].
    units : dict of str to str, optional
        Channel -> unit of the server's values (``"mA"``, ``"rpm"``, ``"deg"``...); default SI.
    chunk_s : float
        Publishing interval and chunk length [s].
    sampling_ms : float, optional
        Sampling interval the server is asked for [ms]; default ``1000 / fs``.
    timeout : float
        Connection and request timeout [s].
    latency_s : float, optional
        Lag of the grid behind the wall clock, so late notifications find their sample [s]; ``2 chunk_s + 0.05``.
    """

    kind = "opcua"

    def __init__(self, machine: str, url: str, nodes: Mapping[str, str], *, fs: float,
                 units: Mapping[str, str] | None = None, chunk_s: float = 0.05, sampling_ms: float | None = None,
                 timeout: float = 4.0, latency_s: float | None = None) -> None:
        super().__init__(machine)
        if not isinstance(url, str) or not url.startswith("opc.tcp://"):
            raise ConfigError(f"source url must look like opc.tcp://HOST:PORT, got {url!r}")
        self.url, self.nodes, self.units = url, _str_map(nodes, "nodes"), _str_map(units or {}, "units")
        if not self.nodes or set(self.units) - set(self.nodes):
            raise ConfigError(f"source nodes must name at least one channel, units only channels with a node: "
                              f"nodes {sorted(self.nodes)}, units {sorted(self.units)}")
        for name, nid in self.nodes.items():
            if not re.fullmatch(r"(ns=\d+;|nsu=[^;]+;)?[isgb]=.+", nid):
                raise ConfigError(f"source nodes: {name} = {nid!r} is not an OPC UA node id (ns=2;s=X.Current)")
            if name not in self.units and quantity_of_channel(name) is None:
                raise ConfigError(f"source nodes: {name!r} is not a drivesense channel name; give its unit in units")
            try:
                to_si(np.zeros(1), self.units.get(name) or SI_UNITS[quantity_of_channel(name)],
                      quantity=quantity_of_channel(name), name=name)
            except ValueError as exc:
                raise ConfigError(f"source units: {exc}") from None
        self.fs, self.chunk_s = _positive(fs, "fs [Hz]"), _positive(chunk_s, "chunk_s [s]")
        self.sampling_ms = 1000.0 / self.fs if sampling_ms is None else _positive(sampling_ms, "sampling_ms [ms]")
        self.timeout = _positive(timeout, "timeout [s]")
        self.latency_s = 2 * self.chunk_s + 0.05 if latency_s is None else _positive(latency_s, "latency_s [s]")
        self.connects = self.notifications = self.bad = self.underruns = self.overruns = self._k0 = self._k = 0
        self.connected, self.outage_s, self._seq = False, 0.0, 0
        self._by_node: dict[str, str] = {}             # node id -> channel
        self._block: dict[str, bool] = {}              # channel -> publishes arrays of samples
        self._points = {n: [] for n in self.nodes}     # channel -> [(wall time [s], SI value)] not yet sampled
        self._fifo = {n: np.zeros(0) for n in self.nodes}   # block channel -> samples not yet emitted
        self._held: dict[str, float] = {}
        self._fresh: set[str] = set()                  # channels with a value in this run
        self._wall0 = self._lost_at = None             # wall time [s] of sample k0 of this run; of the last loss

    def describe(self) -> dict:
        """Kind, server, channels, connection state and counters."""
        return {"kind": self.kind, "url": self.url, "fs": self.fs, "channels": sorted(self.nodes),
                "connected": self.connected, "connects": self.connects, "notifications": self.notifications,
                "bad_values": self.bad, "samples": self._k, "chunks": self._seq, "outage_s": round(self.outage_s, 3),
                "block_channels": sorted(c for c, b in self._block.items() if b), "underruns": self.underruns,
                "overruns": self.overruns}

    def notify(self, node_id: str, value: Any, stamp: datetime | None = None) -> None:
        """Take one data change (the subscription handler calls it in the event loop).

        Parameters
        ----------
        node_id : str
            The node's id as a string.
        value : Any
            A number or a list/array of consecutive samples [the channel's unit in ``units``]; for an NC
            context channel also a state's or a program's name (:func:`~drivesense.nc_context.context_value`).
        stamp : datetime, optional
            Its source timestamp (UTC).
        """
        name, arrival = self._by_node.get(node_id), time.time()
        if name is None:
            return
        self.notifications += 1
        try:
            if name in CONTEXT_CHANNELS and not isinstance(value, (list, tuple, np.ndarray)):
                value = context_value(name, getattr(value, "Text", value))   # a state's name, a LocalizedText
            arr = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
            if not arr.size or not np.all(np.isfinite(arr)):
                raise ValueError
            if name in self.units:
                arr = to_si(arr, self.units[name], quantity=quantity_of_channel(name), name=name)[0]
        except (TypeError, ValueError, InvalidSignalError):
            self.bad += 1                             # None (bad status), text, NaN: the last value holds
            return
        self._fresh.add(name)
        if self._block.setdefault(name, isinstance(value, (list, tuple, np.ndarray))):
            fifo = np.concatenate([self._fifo[name], arr])
            cap = int(MAX_FILL_S * self.fs)            # bounded: a channel that stops never piles up the others
            if fifo.size > cap:
                self.overruns += 1
                fifo = fifo[-cap:]
            self._fifo[name] = fifo
            return
        if stamp is not None:
            stamp = stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)
        t = arrival if stamp is None else min(stamp.timestamp(), arrival)
        times = t - (arr.size - 1 - np.arange(arr.size)) / self.fs
        self._points[name].extend(zip(times.tolist(), arr.tolist()))

    def _emit(self, now: float) -> list[Chunk]:
        if self._wall0 is None:
            if self._fresh != set(self.nodes):
                return []                             # every channel's first value of this run not there yet
            self._wall0, self._k0 = now, self._k
            self.outage_s += 0.0 if self._lost_at is None else now - self._lost_at
        timed = [c for c in self.nodes if not self._block[c]]
        n = self._k0 + int(math.floor((now - self.latency_s - self._wall0) * self.fs)) + 1 - self._k if timed \
            else min(self._fifo[c].size for c in self.nodes)
        if n <= 0:
            return []
        arrays = {}
        grid = self._wall0 + (np.arange(self._k, self._k + n) - self._k0 + 0.5) / self.fs
        for c in self.nodes:
            if self._block[c]:
                out, rest = self._fifo[c][:n], self._fifo[c][n:]
                if out.size < n:
                    self.underruns += 1
                    out = np.concatenate([out, np.full(n - out.size, out[-1] if out.size else self._held[c])])
                if timed and rest.size > self.fs:
                    self.overruns += 1
                    rest = rest[-int(self.fs):]
                self._fifo[c] = rest
            else:
                pts = sorted(self._points[c], key=lambda p: p[0])
                t, v = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
                idx = np.searchsorted(t, grid, side="right") - 1
                out = np.where(idx >= 0, v[np.clip(idx, 0, None)] if v.size else 0.0, self._held.get(c, np.nan))
                self._points[c] = [p for p in pts if p[0] > grid[-1]]
            arrays[c] = np.asarray(out, dtype=float)
            self._held[c] = float(arrays[c][-1])
        chunk = Chunk(self.machine, self._seq, self._k / self.fs, self.fs, arrays)
        self._seq, self._k = self._seq + 1, self._k + n
        return [chunk]

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Subscribe and hand on chunks every ``chunk_s`` until stopped (see :class:`Source`); ConnectionError,
        OSError, TimeoutError: the server unreachable or lost; ConfigError: it refuses a node.

        Parameters
        ----------
        put : callable
            ``await put(chunk)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        from asyncua import Client

        client = Client(self.url, timeout=self.timeout)
        self._wall0, self._fresh = None, set()
        try:
            await client.connect()
            self.connected, self.connects = True, self.connects + 1
            def on_change(node: Any, val: Any, data: Any) -> None:
                dv = getattr(data.monitored_item, "Value", None)
                self.notify(node.nodeid.to_string(), val, getattr(dv, "SourceTimestamp", None)
                            or getattr(dv, "ServerTimestamp", None))

            handler = SimpleNamespace(datachange_notification=on_change,     # a lost connection: check_connection
                                      status_change_notification=lambda status: None)
            sub = await client.create_subscription(self.chunk_s * 1000.0, handler)
            nodes = [client.get_node(nid) for nid in self.nodes.values()]
            self._by_node = {node.nodeid.to_string(): name for node, name in zip(nodes, self.nodes)}
            queue = min(65535, max(1, int(math.ceil(2 * self.chunk_s * 1000.0 / self.sampling_ms))))
            handles = await sub.subscribe_data_change(nodes, queuesize=queue, sampling_interval=self.sampling_ms)
            refused = [f"{nid} ({h})" for nid, h in zip(self.nodes.values(), handles) if not isinstance(h, int)]
            if refused:
                raise ConfigError(f"opcua source {self.url}: the server refused node(s) {', '.join(refused)}")
            while not stop.is_set():
                await client.check_connection()       # ConnectionError once asyncua's watchdog saw the loss
                for chunk in self._emit(time.time()):
                    await put(chunk)
                await _sleep(stop, self.chunk_s)
        finally:
            self._lost_at = time.time() if self.connected and not stop.is_set() else self._lost_at
            self.connected = False
            try:
                await asyncio.wait_for(client.disconnect(), 2.0)
            except Exception:                         # noqa: BLE001 - the connection is gone already
                pass
