"""The ``mqtt`` source: chunks an edge device publishes to a broker (format: :mod:`~drivesense.serve.wire`).

Every ``mqtt`` source of one service on one broker shares one connection (:class:`BrokerLink`): one paho
network thread, one persistent session (QoS 1; the broker keeps what arrives while the service is away
and delivers it on reconnection), one subscription per machine's topic.  The network thread does as
little as it can -- it stamps each message's arrival, routes it by topic and wakes the event loop once
per batch -- because every moment it holds the GIL delays the loop, and so the alarms.  Decoding happens
in the loop.  Each machine holds at most ``max_pending`` undelivered messages; past that the network
thread waits (backpressure reaches the broker, never memory).
"""

from __future__ import annotations

import asyncio
import hashlib
import threading
import time
import urllib.parse
from collections import deque
from typing import Any

from drivesense.errors import ConfigError
from drivesense.serve.sources import Put, Source
from drivesense.serve.wire import WireError, decode_chunk

__all__ = ["MQTTSource", "BrokerLink", "parse_mqtt_url"]


def parse_mqtt_url(url: str) -> tuple[str, int]:
    """Host and port of ``mqtt://HOST[:PORT]`` (default port 1883).

    Parameters
    ----------
    url : str
        Broker URL.

    Raises
    ------
    ConfigError
        Another scheme or a bad port.
    """
    parts = urllib.parse.urlsplit(str(url))
    if parts.scheme != "mqtt" or not parts.hostname:
        raise ConfigError(f"broker URL must look like mqtt://HOST[:PORT], got {url!r}")
    try:
        port = parts.port or 1883
    except ValueError:
        raise ConfigError(f"broker URL {url!r}: bad port") from None
    return parts.hostname, port


class _Route:
    """One machine's share of a link: its inbox, its slots and its wake-up."""

    def __init__(self, max_pending: int) -> None:
        self.inbox: deque = deque()
        self.slots = threading.Semaphore(max_pending)
        self.ready = asyncio.Event()


class BrokerLink:
    """One paho connection serving every ``mqtt`` source of a service on one broker.

    Parameters
    ----------
    loop : asyncio.AbstractEventLoop
        The service's loop.
    host : str
        Broker host.
    port : int
        Broker port.
    client_id : str
        MQTT client id (its persistent session).
    """

    _links: dict = {}

    def __init__(self, loop: asyncio.AbstractEventLoop, host: str, port: int, client_id: str) -> None:
        import paho.mqtt.client as mqtt

        self.loop = loop
        self.routes: dict[str, _Route] = {}
        self.connected = False
        self.closing = False
        self.users = 0
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
        self.client.reconnect_delay_set(0.2, 2.0)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.connect_async(host, port, keepalive=10)
        self.client.loop_start()

    @classmethod
    def shared(cls, host: str, port: int, client_id: str) -> "BrokerLink":
        """The running loop's link to ``host:port`` (created on first use).

        Parameters
        ----------
        host : str
            Broker host.
        port : int
            Broker port.
        client_id : str
            Client id of a new link.
        """
        loop = asyncio.get_running_loop()
        key = (id(loop), host, port)
        link = cls._links.get(key)
        if link is None or link.closing:
            link = cls._links[key] = cls(loop, host, port, client_id)
        return link

    def _on_connect(self, client, userdata, flags, reason, props=None) -> None:
        if not reason.is_failure:
            self.connected = True
            for topic in list(self.routes):
                client.subscribe(topic, qos=1)

    def _on_disconnect(self, client, userdata, flags, reason, props=None) -> None:
        self.connected = False

    def _on_message(self, client, userdata, msg) -> None:
        arrival = time.time()
        route = self.routes.get(msg.topic)
        if route is None:
            return
        while not route.slots.acquire(timeout=0.5):
            if self.closing:
                return
        route.inbox.append((msg.topic, msg.payload, arrival))
        if len(route.inbox) == 1:                 # wake the loop once per batch, not per message
            self.loop.call_soon_threadsafe(route.ready.set)

    def add(self, topic: str, max_pending: int) -> _Route:
        """Subscribe a machine's topic; its route.

        Parameters
        ----------
        topic : str
            The topic.
        max_pending : int
            Undelivered messages before the network thread waits.
        """
        if topic in self.routes:
            raise ConfigError(f"two mqtt sources subscribe topic {topic!r}: give each machine its own topic")
        route = self.routes[topic] = _Route(max_pending)
        self.users += 1
        if self.connected:
            self.client.subscribe(topic, qos=1)
        return route

    def remove(self, topic: str) -> None:
        """Forget a machine's topic; the last one closes the connection.

        Parameters
        ----------
        topic : str
            The topic.
        """
        route = self.routes.pop(topic, None)
        if route is not None:
            self.users -= 1
            for _ in range(len(route.inbox) + 1):
                route.slots.release()             # a network thread waiting on this route goes on
        if self.users <= 0:
            self.closing = True
            self.client.disconnect()
            self.client.loop_stop()


class MQTTSource(Source):
    """Chunks an edge device publishes to an MQTT broker, one topic per machine.

    Parameters
    ----------
    machine : str
        Machine id (messages for another machine are refused).
    url : str
        ``mqtt://HOST[:PORT]``.
    topic : str
        Topic the edge device publishes to (default ``{machine}/drive``).
    client_id : str, optional
        MQTT client id of the service's connection to this broker (default: ``drivesense-`` and a hash of
        the broker, so a restarted service finds its session again).
    max_pending : int
        Messages received and not yet taken by the service before the network thread waits.
    """

    kind = "mqtt"

    def __init__(self, machine: str, url: str, topic: str | None = None, *, client_id: str | None = None,
                 max_pending: int = 64) -> None:
        super().__init__(machine)
        self.host, self.port = parse_mqtt_url(url)
        self.url = url
        self.topic = topic or f"{machine}/drive"
        digest = hashlib.sha1(f"{self.host}:{self.port}".encode()).hexdigest()[:10]
        self.client_id = client_id or f"drivesense-{digest}"
        self.max_pending = int(max_pending)
        self.messages = 0
        self._link: BrokerLink | None = None

    @property
    def connected(self) -> bool:
        """Whether the shared connection is up."""
        return bool(self._link and self._link.connected)

    def describe(self) -> dict:
        """Kind, broker, topic, connection state."""
        return {"kind": self.kind, "url": self.url, "topic": self.topic, "connected": self.connected,
                "messages": self.messages}

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Subscribe and hand on every message until stopped (see :class:`~drivesense.serve.sources.Source`).

        Parameters
        ----------
        put : callable
            ``await put(chunk_or_exception)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        self._link = link = BrokerLink.shared(self.host, self.port, self.client_id)
        route = link.add(self.topic, self.max_pending)
        waiter = asyncio.ensure_future(stop.wait())
        waiter.add_done_callback(lambda _: route.ready.set())     # stopping wakes the wait below
        try:
            while not stop.is_set():
                if not route.inbox:
                    route.ready.clear()
                    await route.ready.wait()              # one future per wake-up, nothing else
                    continue
                topic, payload, arrival = route.inbox.popleft()
                route.slots.release()
                self.messages += 1
                try:
                    item: Any = decode_chunk(payload, arrival=arrival)
                    if item.machine != self.machine:
                        item = WireError(f"topic {topic}: a chunk of machine '{item.machine}', expected "
                                         f"'{self.machine}'")
                except WireError as exc:
                    item = exc
                await put(item)
        finally:
            waiter.cancel()
            link.remove(self.topic)
