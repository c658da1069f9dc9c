"""``drivesense publish``: a recording sent to an MQTT broker in the chunk format of :mod:`drivesense.monitor.wire`.

What an edge device next to a controller runs (or a test feeding the monitor): the trace is cut into
chunks, each published with QoS 1 on ``{machine}/drive`` at real time (or faster), sequence numbers and time
continuing across repeats.  Each run names a new session, so a service that saw an earlier run takes this one
for a restart of the publisher, not for old chunks.
"""

from __future__ import annotations

import asyncio
import secrets
import time

from drivesense.errors import ConfigError
from drivesense.recording import Recording
from drivesense.monitor.mqtt import parse_mqtt_url
from drivesense.monitor.sources import ReplaySource
from drivesense.monitor.wire import encode_chunk

__all__ = ["publish_recording"]


def publish_recording(recording: Recording, url: str, *, machine: str, topic: str | None = None,
                      speed: float = 1.0, chunk_s: float = 0.05, repeat: int = 1, connect_timeout: float = 10.0,
                      client_id: str | None = None, session: str | None = None) -> dict:
    """Publish a recording chunk by chunk; returns what was sent.

    Parameters
    ----------
    recording : Recording
        The trace (SI channels).
    url : str
        Broker, ``mqtt://HOST[:PORT]``.
    machine : str
        Machine id in the messages.
    topic : str, optional
        Topic (default ``{machine}/drive``).
    speed : float
        Rate [-]: 1 real time, 0 as fast as the broker takes it.
    chunk_s : float
        Chunk length [s].
    repeat : int
        Times the recording is sent.
    connect_timeout : float
        How long to wait for the broker [s].
    client_id : str, optional
        MQTT client id.
    session : str, optional
        The run's session on the wire (default: a new random one, so that a service tells this run from the
        last and starts the machine's stream afresh).

    Returns
    -------
    dict
        ``chunks``, ``samples``, ``topic``, ``session``, ``wall_s`` [s].

    Raises
    ------
    ConfigError
        The broker cannot be reached (named in the message).
    """
    import paho.mqtt.client as mqtt

    host, port = parse_mqtt_url(url)
    topic = topic or f"{machine}/drive"
    session = session or secrets.token_hex(6)
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id or f"drivesense-publish-{machine}")
    client.max_inflight_messages_set(100)
    try:
        client.connect(host, port, keepalive=30)
    except OSError as exc:
        raise ConfigError(f"cannot reach the broker at {url} (--mqtt): {exc}") from None
    client.loop_start()
    sent = {"chunks": 0, "samples": 0}
    infos = []

    async def put(chunk) -> None:
        info = client.publish(topic, encode_chunk(machine, chunk.seq, chunk.t0, chunk.fs, chunk.arrays,
                                                 session=session), qos=1)
        infos.append(info)
        sent["chunks"] += 1
        sent["samples"] += chunk.n
        if len(infos) >= 200:                 # bounded: wait for the oldest acknowledgements
            for i in infos[:100]:
                i.wait_for_publish(connect_timeout)
            del infos[:100]

    began = time.time()
    try:
        source = ReplaySource(machine, recording, speed=speed, chunk_s=chunk_s, loop=repeat)
        asyncio.run(source.run(put, asyncio.Event()))
        for i in infos:
            i.wait_for_publish(connect_timeout)
    finally:
        client.disconnect()
        client.loop_stop()
    return {**sent, "topic": topic, "session": session, "wall_s": time.time() - began}
