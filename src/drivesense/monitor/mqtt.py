"""The ``mqtt`` source: chunks an edge device publishes to a broker (format: :mod:`~drivesense.monitor.wire`).

Every ``mqtt`` source of one service on one broker shares one connection (:class:`BrokerLink`): one paho
network thread, one persistent session (QoS 1; the broker keeps what arrives while the service is away
and delivers it on reconnection), one subscription per machine's topic.  The network thread does as
little as it can -- it stamps each message's arrival, routes it by topic and wakes the event loop once
per batch -- because every moment it holds the GIL delays the loop, and so the alarms.  Decoding happens
in the loop.  Each machine holds at most ``max_pending`` undelivered messages; past that the network
thread waits (backpressure reaches the broker, never memory).  paho acknowledges each message as it
takes it, and the broker forgets it then; so no message may arrive without a route (the connection opens
once the sources started together have added their topics), and when the service stops, the connection
closes before the sources return, each handing on what its inbox holds.  What the broker had not delivered
it keeps for the next run: nothing is lost.

A machine shared by a fleet of workers (:mod:`~drivesense.monitor.fleet`) has a session of its own instead
(``hold_s`` given): MQTT 5, client id per machine, so the broker lets one worker at a time hold it and
keeps the stream for the next holder.  Its chunks are acknowledged by hand, only once they are processed,
their events logged and the claim's mark written, and only ``hold_s`` of signal after that: a worker that
dies leaves the last seconds unacknowledged, and the broker hands them to the next holder, which re-primes
its estimators on them.
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
from drivesense.monitor.sources import Put, Source
from drivesense.monitor.wire import StreamCursor, WireError, decode_chunk

__all__ = ["MQTTSource", "BrokerLink", "parse_mqtt_url", "RECEIVE_MAXIMUM", "SESSION_EXPIRY_S", "MAX_HOLD_S"]

#: Unacknowledged messages the broker may send a hand-acknowledging link (MQTT 5 receive maximum).
RECEIVE_MAXIMUM = 2000
#: How long the broker keeps a hand-acknowledging link's session after it is gone [s] (one day).
SESSION_EXPIRY_S = 86400
#: Longest signal a hand-acknowledging source keeps unacknowledged for a detector's long memory [s].
MAX_HOLD_S = 60.0


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
    manual_ack : bool
        Acknowledge messages by hand (:meth:`ack`); the link speaks MQTT 5 then, with a receive maximum
        of :data:`RECEIVE_MAXIMUM` (unacknowledged messages the broker may send) and a session that
        outlives the connection by :data:`SESSION_EXPIRY_S`.
    """

    _links: dict = {}

    def __init__(self, loop: asyncio.AbstractEventLoop, host: str, port: int, client_id: str, *,
                 manual_ack: bool = False) -> None:
        import paho.mqtt.client as mqtt

        self.loop = loop
        self.routes: dict[str, _Route] = {}
        self.connected = False
        self.closing = False
        self.users = 0
        self.manual_ack = manual_ack
        self.client_id = client_id
        self.stopping: set[str] = set()        # topics whose source has stopped taking messages
        self.closed = asyncio.Event()          # set once release() has closed the connection
        self._shutting = False                 # the connection is being closed, or is closed
        self._closer: asyncio.Task | None = None
        self._disconnect_queued = threading.Event()
        if manual_ack:
            from paho.mqtt.packettypes import PacketTypes
            from paho.mqtt.properties import Properties

            self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5,
                                      manual_ack=True)
            props = Properties(PacketTypes.CONNECT)
            props.SessionExpiryInterval = SESSION_EXPIRY_S
            props.ReceiveMaximum = RECEIVE_MAXIMUM
            connect = {"clean_start": False, "properties": props}
        else:
            self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
            connect = {}
        self.client.reconnect_delay_set(0.2, 2.0)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.connect_async(host, port, keepalive=10, **connect)
        # connected once the sources started with this one have added their topics: the broker delivers what
        # it kept for the session at once, and a message for a topic without a route is lost (acknowledged)
        loop.call_soon(self._start)

    def _start(self) -> None:
        if not self._shutting:
            self.client.loop_start()

    @classmethod
    def shared(cls, host: str, port: int, client_id: str, *, manual_ack: bool = False) -> "BrokerLink":
        """The running loop's link to ``host:port`` as ``client_id`` (created on first use).

        Parameters
        ----------
        host : str
            Broker host.
        port : int
            Broker port.
        client_id : str
            Client id of the link.
        manual_ack : bool
            A new link acknowledges by hand (see the class).
        """
        loop = asyncio.get_running_loop()
        key = (id(loop), host, port, client_id)
        link = cls._links.get(key)
        if link is None or link.closing:
            link = cls._links[key] = cls(loop, host, port, client_id, manual_ack=manual_ack)
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
        route = None if self.closing else self.routes.get(msg.topic)
        if route is None:
            self._leave()
            return
        while not route.slots.acquire(timeout=0.5):
            if self.closing:
                self._leave()
                return
        route.inbox.append((msg.topic, msg.payload, arrival, msg.mid if self.manual_ack else None))
        if len(route.inbox) == 1:                 # wake the loop once per batch, not per message
            self.loop.call_soon_threadsafe(route.ready.set)

    def _leave(self) -> None:
        """Leave a message to the broker (the link closing, or no machine's topic).

        paho acknowledges a message (QoS 1) as soon as :meth:`_on_message` returns, unless the link acknowledges
        by hand; an acknowledgement queued after the DISCONNECT is never sent.  So a closing link returns only once
        its DISCONNECT is queued (:meth:`_shut`): the broker keeps the message for the next run.
        """
        if self.closing and not self.manual_ack:
            self._disconnect_queued.wait(10.0)

    def _barrier(self, timeout: float = 2.0) -> None:
        """Wait until the broker has taken every acknowledgement sent so far (a hand-acknowledging link).

        Mosquitto can drop the acknowledgements that arrive together with a DISCONNECT (measured: one
        hand-over in three got chunks again that had been acknowledged).  A QoS 1 message on a topic nobody
        reads comes back acknowledged only after the broker has handled what was sent before it.
        """
        try:
            self.client.publish(f"drivesense/barrier/{self.client_id}", b"", qos=1).wait_for_publish(timeout)
        except (RuntimeError, ValueError):        # the connection went meanwhile: the broker keeps what it has
            pass

    def ack(self, mid: int) -> None:
        """Acknowledge a message (links with ``manual_ack``; nothing once the link is closing).

        Parameters
        ----------
        mid : int
            The message's packet id, as :meth:`_on_message` stored it.
        """
        if not self.closing:
            self.client.ack(mid, 1)

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

    def release(self, topic: str) -> None:
        """A machine's source has stopped; once every source of the link has, the connection closes.

        The routes stay until :meth:`remove`: what arrives meanwhile is queued in their inboxes as before, and
        each source hands on its inbox until :attr:`closed` is set and the inbox is empty.

        Parameters
        ----------
        topic : str
            The topic.
        """
        self.stopping.add(topic)
        self._close_when_all_stopped()

    def _close_when_all_stopped(self) -> None:
        if not self._shutting and self.routes and set(self.routes) <= self.stopping:
            self._shutting = True
            self._closer = asyncio.ensure_future(self._close())

    async def _close(self) -> None:
        await asyncio.to_thread(self._shut)       # (paho's network thread is joined: not on the loop)
        self.closed.set()
        for route in self.routes.values():
            route.ready.set()

    def _shut(self) -> None:
        """Close the connection and join paho's network thread (blocking); from now on every message is left
        to the broker (:meth:`_leave`)."""
        self.closing = True
        if self.manual_ack and self.connected:
            self._barrier()
        self.client.disconnect()
        self._disconnect_queued.set()
        self.client.loop_stop()

    def remove(self, topic: str) -> None:
        """Forget a machine's topic; the last one closes the connection (if :meth:`release` has not).

        Parameters
        ----------
        topic : str
            The topic.
        """
        route = self.routes.pop(topic, None)
        self.stopping.discard(topic)
        if route is not None:
            self.users -= 1
        if self.users <= 0 and not self._shutting:
            self._shutting = True
            self._shut()                          # (first: a network thread waiting on the route leaves it)
        if route is not None:
            for _ in range(len(route.inbox) + 1):
                route.slots.release()             # a network thread waiting on this route goes on
        if self.users > 0:
            self._close_when_all_stopped()


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
    hold_s : float, optional
        Acknowledge by hand and keep the last ``hold_s`` [s] of processed signal unacknowledged (a fleet
        worker's machine, see the module).  The service reports with :meth:`processed` and :meth:`settle`.
        None (default): paho acknowledges each message as it arrives.
    """

    kind = "mqtt"
    drains = True

    def __init__(self, machine: str, url: str, topic: str | None = None, *, client_id: str | None = None,
                 max_pending: int = 64, hold_s: float | None = None) -> None:
        super().__init__(machine)
        self.host, self.port = parse_mqtt_url(url)
        self.url = url
        self.topic = topic or f"{machine}/drive"
        digest = hashlib.sha1(f"{self.host}:{self.port}".encode()).hexdigest()[:10]
        self.client_id = client_id or f"drivesense-{digest}"
        self.max_pending = int(max_pending)
        self.hold_s = None if hold_s is None else float(hold_s)
        self.messages = 0
        self.redelivered = 0
        self._link: BrokerLink | None = None
        self._unacked: deque = deque()         # (link, mid, publisher run, seq, t_end) per message handed on
        self._held: set = set()                # (link, mid) of those
        self._processed = 0                    # how many of those the service has finished with
        self._newest_done: float | None = None  # last sample time of the newest processed chunk [s]
        self._cursor = StreamCursor()           # the newest chunk handed on

    @property
    def connected(self) -> bool:
        """Whether the shared connection is up."""
        return bool(self._link and self._link.connected)

    def describe(self) -> dict:
        """Kind, broker, topic, connection state."""
        return {"kind": self.kind, "url": self.url, "topic": self.topic, "connected": self.connected,
                "messages": self.messages}

    async def run(self, put: Put, stop: asyncio.Event) -> None:
        """Subscribe and hand on every message until stopped (see :class:`~drivesense.monitor.sources.Source`).

        Once stopped, a source that paho acknowledges for (no ``hold_s``) goes on handing on its inbox until the
        link's connection is closed (every source of the link stopped) and the inbox is empty: the broker
        has those messages no more.  What it has not delivered it keeps for the next run.

        Parameters
        ----------
        put : callable
            ``await put(chunk_or_exception)``.
        stop : asyncio.Event
            Set when the service shuts down.
        """
        self._link = link = BrokerLink.shared(self.host, self.port, self.client_id,
                                              manual_ack=self.hold_s is not None)
        route = link.add(self.topic, self.max_pending)
        waiter = asyncio.ensure_future(stop.wait())
        waiter.add_done_callback(lambda _: route.ready.set())     # stopping wakes the wait below
        try:
            while not stop.is_set():
                if not route.inbox:
                    route.ready.clear()
                    await route.ready.wait()              # one future per wake-up, nothing else
                    continue
                item = self._take(link, route)
                if item is not None:
                    await put(item)
            if not link.manual_ack:
                link.release(self.topic)
                while route.inbox or not link.closed.is_set():
                    if not route.inbox:
                        route.ready.clear()
                        await route.ready.wait()          # a message, or the connection closed
                        continue
                    item = self._take(link, route)
                    if item is not None:
                        await put(item)
        finally:
            waiter.cancel()
            link.remove(self.topic)

    def _take(self, link: BrokerLink, route: _Route) -> Any:
        """The oldest message of the inbox: a chunk, the error that refuses it, or None (not to hand on)."""
        topic, payload, arrival, mid = route.inbox.popleft()
        route.slots.release()
        self.messages += 1
        try:
            item: Any = decode_chunk(payload, arrival=arrival)
            if item.machine != self.machine:
                item = WireError(f"topic {topic}: a chunk of machine '{item.machine}', expected '{self.machine}'")
        except WireError as exc:
            item = exc
        if mid is not None and not self._hold(link, mid, item):
            return None
        return item

    def _hold(self, link: BrokerLink, mid: int, item: Any) -> bool:
        """Keep a hand-acknowledged message for :meth:`settle`; False for a chunk handed on before (dropped)."""
        if isinstance(item, Exception):
            entry = (link, mid, None, None, None)
        elif self._cursor.place(item) == "old":
            self.redelivered += 1                 # the broker sent it again after a reconnection
            if (link, mid) not in self._held:     # (still held: acknowledged in its turn, not twice)
                link.ack(mid)
            return False
        else:
            self._cursor.advance(item)
            entry = (link, mid, self._cursor.restarts, item.seq, item.t0 + (item.n - 1) / item.fs)
        self._unacked.append(entry)
        self._held.add((link, mid))
        return True

    def processed(self) -> None:
        """The service is done with the oldest message handed on and not reported yet (hand-acknowledged only)."""
        if self.hold_s is not None and self._processed < len(self._unacked):
            t_end = self._unacked[self._processed][4]
            if t_end is not None:
                self._newest_done = t_end
            self._processed += 1

    def settle(self, marked_seq: int | None, keep_from: float | None = None) -> int:
        """Acknowledge the processed messages the broker need not keep; how many were acknowledged.

        A chunk is acknowledged once its seq is at most ``marked_seq`` (the claim's mark: everything up to it
        is processed and its events logged) and its last sample lies ``hold_s`` or more before the newest
        processed one, and before ``keep_from`` -- but never more than :data:`MAX_HOLD_S` or half the
        receive maximum of messages are kept.  Messages that could not be read go with their neighbours, and
        chunks of a publisher's run that has ended (a restart came after them) go as soon as they are
        processed: the next holder would not replay them.

        Parameters
        ----------
        marked_seq : int or None
            The highest chunk seq the machine's claim has marked as done (None: nothing yet).
        keep_from : float, optional
            Keep the signal from this time on [s, the machine's clock] (a detector's long memory).
        """
        if self.hold_s is None or marked_seq is None or self._newest_done is None:
            return 0
        cutoff = self._newest_done - self.hold_s
        if keep_from is not None:
            cutoff = min(cutoff, max(keep_from, self._newest_done - MAX_HOLD_S))
        done = 0
        while self._processed:
            link, mid, run, seq, t_end = self._unacked[0]
            crowded = len(self._unacked) > RECEIVE_MAXIMUM // 2
            if seq is not None and run == self._cursor.restarts and (seq > marked_seq or (t_end > cutoff
                                                                                          and not crowded)):
                break                             # (never past the mark; past the cut-off only when too many wait)
            link.ack(mid)
            self._unacked.popleft()
            self._held.discard((link, mid))
            self._processed -= 1
            done += 1
        return done
