"""An MTConnect adapter read directly: the SHDR stream (``timestamp|key|value|...`` lines over TCP).

An MTConnect adapter is what sits on the controller; an agent collects its
stream and serves it over HTTP (:class:`~drivesense.monitor.controllers.MTConnectSource`).
Where no agent runs, the monitor can be the adapter's client itself:
:class:`SHDRSource` connects to the adapter's port (7878 by convention), answers
its heartbeat (``* PING`` -> ``* PONG <ms>``), parses the lines as
``drivesense mtconnect import`` does (:func:`~drivesense.io.mtconnect.parse_shdr`)
and resamples them onto the uniform grid of the agent source (linear or
held; the NC's context channels always held, their states and program names
coded: :mod:`drivesense.nc_context`).

An adapter reports keys of its own choosing in its own (native) units, so
the source needs the map ``key -> channel`` and, for channels not in SI, the
unit (``units``).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
import urllib.parse
from collections.abc import Mapping

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.io.mtconnect import Observation, parse_shdr
from drivesense.monitor.controllers import MTConnectSource
from drivesense.monitor.sources import Put
from drivesense.units import quantity_of_channel, unit_info

__all__ = ["SHDRSource"]

#: How often the source asks the adapter for its heartbeat [s] (the adapter answers with its own period).
PING_S = 5.0


class SHDRSource(MTConnectSource):
    """An MTConnect adapter's SHDR lines over TCP, resampled live onto a uniform grid.

    Parameters
    ----------
    machine : str
        Machine id.
    url : str
        ``shdr://host:port``.
    fs : float
        Output sample rate [Hz].
    channels : dict of str to str
        Adapter key -> drivesense channel; only these are emitted (a key the adapter reports beside them is
        listed in ``describe()["ignored"]``).
    units : dict of str to str, optional
        Channel -> the unit the adapter reports it in (``"mm"``, ``"rpm"``, ``"%"``...); default SI.
    interval_s : float
        Time between emitted chunks [s].
    timeout : float
        Connect timeout, and the longest silence (no line, no heartbeat) before the connection counts as
        lost [s].
    method : {"linear", "hold"}
        Interpolation between reports of the numeric channels.
    """

    kind = "shdr"

    def __init__(self, machine: str, url: str, *, fs: float, channels: Mapping[str, str],
                 units: Mapping[str, str] | None = None, interval_s: float = 0.1, timeout: float = 10.0,
                 method: str = "linear") -> None:
        parsed = urllib.parse.urlsplit(url) if isinstance(url, str) else None
        if parsed is None or parsed.scheme != "shdr" or not parsed.hostname or not parsed.port:
            raise ConfigError(f"source url must be shdr://host:port (the adapter's), got {url!r}")
        if not isinstance(channels, Mapping) or not channels:
            raise ConfigError("an shdr source needs 'channels': the adapter's keys -> drivesense channels")
        super().__init__(machine, f"http://{parsed.hostname}:{parsed.port}", fs=fs, channels=channels,
                         interval_s=interval_s, timeout=timeout, method=method)
        self.url, self.host, self.port = url, parsed.hostname, parsed.port
        self.timeout = float(timeout)
        self.units = {}
        for name, unit in dict(units or {}).items():
            if name not in self.channels.values():
                raise ConfigError(f"source units: {name!r} is not one of the channels "
                                  f"({', '.join(sorted(self.channels.values()))})")
            try:
                self.units[name] = unit_info(unit, quantity=quantity_of_channel(name), name=name).factor
            except Exception as exc:          # noqa: BLE001 - a UnitError names channel, unit and quantity
                raise ConfigError(f"source units: {exc}") from None
        self.lines = self.bad_lines = self.connects = 0
        self.last_line: float | None = None

    def describe(self) -> dict:
        """Kind, adapter, channels, lines read and refused, connections, and the grid's figures."""
        out = super().describe()
        out.update({"kind": self.kind, "url": self.url, "lines": self.lines, "bad_lines": self.bad_lines,
                    "connects": self.connects})
        for key in ("next_sequence", "instance_id", "requests", "lost", "restarts"):
            out.pop(key, None)
        return out

    def _route(self, key: str) -> tuple | None:
        if key not in self._routes:
            name = self.channels.get(key)
            self._routes[key] = None if name is None else (name, self.units.get(name, 1.0), None)
        return self._routes[key]

    def take_line(self, line: str) -> None:
        """Parse one SHDR line and keep its observations for the grid (a line it cannot read is counted).

        Parameters
        ----------
        line : str
            ``timestamp|key|value|...`` as the adapter sent it (a ``*`` protocol line is skipped).
        """
        line = line.strip()
        if not line or line.startswith("*"):
            return
        try:
            observations: list[Observation] = parse_shdr(self.url, text=line)
        except InvalidSignalError:
            self.bad_lines += 1
            return
        self.lines += 1
        for obs in observations:
            if obs.key not in self.channels:
                self.ignored.add(obs.key)
        self._take([o for o in observations if o.key in self.channels])

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Read the adapter's lines and hand on chunks every ``interval_s`` until stopped; a lost or silent
        connection raises ConnectionError (the service runs the source again; the grid goes on).

        Parameters
        ----------
        put : callable
            ``await put(chunk_or_exception)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        try:
            reader, writer = await asyncio.wait_for(asyncio.open_connection(self.host, self.port), self.timeout)
        except (OSError, asyncio.TimeoutError) as exc:
            raise ConnectionError(f"cannot reach the SHDR adapter at {self.url}: {exc}") from None
        self.connects += 1
        self.connected = True
        loop = asyncio.get_running_loop()
        last_emit = last_ping = loop.time()
        self.last_line = time.time()
        try:
            writer.write(b"* PING\n")
            await writer.drain()
            while not stop.is_set():
                wait = max(0.0, min(self.interval_s - (loop.time() - last_emit), 0.05))
                try:
                    raw = await asyncio.wait_for(reader.readline(), wait or 0.001)
                except asyncio.TimeoutError:
                    raw = None
                if raw == b"":
                    raise ConnectionError(f"the SHDR adapter at {self.url} closed the connection")
                if raw:
                    self.last_line = time.time()
                    self.take_line(raw.decode("utf-8", errors="replace"))
                elif time.time() - self.last_line > self.timeout:
                    raise ConnectionError(f"the SHDR adapter at {self.url} was silent for {self.timeout:g} s")
                now = loop.time()
                if now - last_ping >= PING_S:
                    writer.write(b"* PING\n")
                    await writer.drain()
                    last_ping = now
                if now - last_emit >= self.interval_s:
                    last_emit = now
                    for chunk in self._emit():
                        await put(chunk)
        finally:
            self.connected = False
            writer.close()
            with contextlib.suppress(OSError, ConnectionError):     # closing a connection already gone
                await writer.wait_closed()
