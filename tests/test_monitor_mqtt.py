"""The monitor against a real broker (Debian's mosquitto, started per test on a free loopback port).

An edge device publishes drive-signal chunks; the service estimates, detects and publishes alarms and stop
requests; the test listens like a controller integration would.  Garbage on the topic, and a broker restart
in the middle of the run, must cost nothing but the refused messages; stopping the service must cost nothing.
The tests wait for what they need (a subscription acknowledged, the service's count of samples), never a fixed
time: on a busy machine everything takes longer.  With CI=true these tests never skip.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request

import numpy as np
import pytest

from drivesense.monitor import MachineSpec, MonitorService, MQTTSource, encode_chunk

pytest.importorskip("paho.mqtt.client") if os.environ.get("CI") != "true" else None
import paho.mqtt.client as mqtt  # noqa: E402


class Listener:
    """A paho subscriber on ``+/alarm`` and ``+/stop`` (resubscribing after a broker restart); listening once
    built (the broker acknowledged both subscriptions)."""

    def __init__(self, url_port: int) -> None:
        self.messages: list[tuple[str, dict, float]] = []
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"listener-{time.time_ns()}",
                                  clean_session=False)
        self.client.reconnect_delay_set(0.1, 1.0)
        subscribed: list = []
        self.client.on_connect = lambda c, u, f, r, p=None: (c.subscribe("+/alarm", qos=1),
                                                             c.subscribe("+/stop", qos=1))
        self.client.on_subscribe = lambda *args: subscribed.append(args)
        self.client.on_message = lambda c, u, m: self.messages.append((m.topic, json.loads(m.payload), time.time()))
        self.client.connect("127.0.0.1", url_port)
        self.client.loop_start()
        _until(lambda: len(subscribed) >= 2, 60, "the listener's subscriptions")

    def wait(self, topic_end: str, kind: str, timeout: float = 60.0) -> dict:
        deadline = time.time() + timeout
        while time.time() < deadline:
            for topic, body, _ in self.messages:
                if topic.endswith(topic_end) and body.get("kind") == kind:
                    return body
            time.sleep(0.05)
        raise AssertionError(f"no {kind} on */{topic_end} within {timeout} s; got {self.messages}")

    def kinds(self, topic_end: str, kind: str) -> list[dict]:
        return [body for topic, body, _ in list(self.messages) if topic.endswith(topic_end) and body.get("kind") == kind]

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def _until(cond, timeout: float, what: str, service: subprocess.Popen | None = None) -> None:
    """Wait until ``cond()`` holds; fail after ``timeout`` [s] (a guard only), or at once when ``service`` ends."""
    deadline = time.monotonic() + timeout
    while not cond():
        if service is not None and service.poll() is not None:
            raise AssertionError(f"the service ended while waiting for {what}: {service.stdout.read()}")
        assert time.monotonic() < deadline, f"{what}: not within {timeout} s"
        time.sleep(0.05)


def _machine_status(port: int) -> dict:
    """The status of a monitor's one machine (``GET /api/machines``); empty while it does not answer."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/machines", timeout=5) as answer:
            return json.loads(answer.read())[0]
    except (OSError, ValueError, IndexError):
        return {}


def _subscribe_session(port: int, client_id: str, topic: str) -> None:
    """Create a client's persistent session subscribed to ``topic`` (the broker acknowledged it), then leave."""
    subscribed = threading.Event()
    session = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
    session.on_subscribe = lambda *args: subscribed.set()
    session.connect("127.0.0.1", port)
    session.loop_start()
    session.subscribe(topic, qos=1)
    try:
        assert subscribed.wait(60), f"the broker did not acknowledge the subscription of {client_id} to {topic}"
    finally:
        session.disconnect()
        session.loop_stop()


def _cuts():
    from drivesense.monitor.sources import SimulatedSource
    from drivesense.sim.process_events import ProcessEvent, simulate_event_cut
    from drivesense.sim.scenarios import ScenarioSettings
    from dataclasses import replace

    src = SimulatedSource("m", cut_s=4.0)
    clean, broken = src.simulate_cut(0), src.simulate_cut(1)
    settings = replace(ScenarioSettings(), duration=4.0, t_contact=0.8)
    from drivesense.monitor.sources import demo_condition

    collision = simulate_event_cut(demo_condition(), settings=settings, seed=77,
                                   events=(ProcessEvent("collision", 2.0, force_n=800.0, rise_s=5e-4, hold_s=0.2),))
    return clean, broken, collision


def _publish(client, rec, *, seq0: int, t_offset: float, n: int = 500) -> int:
    infos = []
    for k, i in enumerate(range(0, rec.n_samples, n)):
        arrays = {c: rec[c][i:i + n] for c in rec.channels}
        infos.append(client.publish("m/drive", encode_chunk("m", seq0 + k, t_offset + i / rec.fs, rec.fs, arrays),
                                    qos=1))
    for info in infos:
        info.wait_for_publish(30)
    return seq0 + len(infos)


def test_alarms_and_stop_requests_survive_garbage_and_a_broker_restart(mosquitto):
    from drivesense.monitor.demo import demo_monitor

    clean, broken, collision = _cuts()
    source = MQTTSource("m", mosquitto.url)
    svc = MonitorService([MachineSpec("m", source, demo_monitor("m"))], alarm_url=mosquitto.url)
    loop = asyncio.new_event_loop()
    stop_holder: dict = {}

    def serve():
        asyncio.set_event_loop(loop)
        stop_holder["stop"] = asyncio.Event()
        loop.run_until_complete(svc.run(stop_holder["stop"]))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    listener = Listener(mosquitto.port)
    edge = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="edge", clean_session=False)
    edge.reconnect_delay_set(0.1, 1.0)
    edge.connect("127.0.0.1", mosquitto.port)
    edge.loop_start()
    try:
        _until(lambda: source.connected, 60, "the source's connection")

        def probed() -> bool:              # the subscription is in place: a message on the topic arrives (refused)
            edge.publish("m/drive", b"probe", qos=1).wait_for_publish(10)
            return svc.machine("m").monitor.rejected > 0

        _until(probed, 60, "the service's subscription")
        good = encode_chunk("m", 0, 0.0, clean.fs, {c: clean[c][:500] for c in clean.channels})
        nan = encode_chunk("m", 10_000, 0.0, clean.fs, {c: np.full(500, np.nan) for c in clean.channels})
        garbage = [b"hello", b"DSC1\x05\x00\x00\x00{bad}", good[:-8], nan,
                   encode_chunk("other", 0, 0.0, clean.fs, {"x_current": np.zeros(3)})]
        for g in garbage:
            edge.publish("m/drive", g, qos=1).wait_for_publish(10)
        seq = _publish(edge, clean, seq0=0, t_offset=0.0)
        edge.publish("m/drive", good, qos=1).wait_for_publish(10)           # seq 0 again: out of order
        seq = _publish(edge, broken, seq0=seq, t_offset=4.0)
        alarm = listener.wait("alarm", "breakage")
        stop = listener.wait("stop", "breakage")
        assert alarm["machine"] == "m" and stop["event_id"] == alarm["id"]
        assert 6.0 < alarm["time_s"] < 6.4                    # the flute breaks at 4 + 2.16 s

        mosquitto.restart(down_s=1.0)
        _until(lambda: source.connected, 60, "the source's reconnection after the broker restart")
        _until(edge.is_connected, 60, "the edge device's reconnection")
        _publish(edge, collision, seq0=seq, t_offset=8.0)        # (the restored session holds the subscription)
        hit = listener.wait("alarm", "collision")
        assert 9.99 < hit["time_s"] < 10.01, svc.machine_status("m")
        listener.wait("stop", "collision")
        monitor = svc.machine("m").monitor
        _until(lambda: monitor.samples + 500 * monitor.gaps >= 3 * 40_000, 60, "every chunk")
        st = svc.machine_status("m")
        # the five bad messages and the repeated seq 0 are refused, and so is any chunk the restarted broker
        # delivers a second time (QoS 1 is at-least-once); the broker's persistence keeps what it had queued:
        # no chunk is lost
        assert st["rejected"] >= len(garbage) + 1
        assert st["samples"] == 3 * 40_000 and st["gaps"] == 0
        ids = [e["id"] for e in svc.events()]
        assert len(ids) == len(set(ids)) and {e["kind"] for e in svc.events()} == {"breakage", "collision"}
        assert svc.alarms.published == len(ids)
    finally:
        loop.call_soon_threadsafe(stop_holder["stop"].set)
        thread.join(30)
        edge.disconnect()
        edge.loop_stop()
        listener.close()


def test_a_stopping_service_processes_every_chunk_the_broker_handed_over(mosquitto):
    """Stopped while the broker floods it: the chunks paho has acknowledged are processed before the service
    ends, the others stay in its session for the next run; none is lost in between."""
    from drivesense.monitor.demo import demo_monitor
    from drivesense.monitor.wire import decode_chunk

    clean, broken, _ = _cuts()
    handed: list[int] = []

    class NotingSource(MQTTSource):            # (slow: the broker fills its inbox meanwhile)
        async def run(self, put, stop):
            async def note(item):
                handed.append(getattr(item, "seq", -1))
                await asyncio.sleep(0.01)
                await put(item)

            await super().run(note, stop)

    source = NotingSource("m", mosquitto.url)
    _subscribe_session(mosquitto.port, source.client_id, "m/drive")
    edge = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="edge")
    edge.connect("127.0.0.1", mosquitto.port)
    edge.loop_start()
    try:                                   # 160 chunks wait in the session before the service starts
        total = _publish(edge, broken, seq0=_publish(edge, clean, seq0=0, t_offset=0.0), t_offset=4.0)
    finally:
        edge.disconnect()
        edge.loop_stop()
    svc = MonitorService([MachineSpec("m", source, demo_monitor("m"))])
    loop = asyncio.new_event_loop()
    stop = asyncio.Event()

    def serve():
        asyncio.set_event_loop(loop)
        loop.run_until_complete(svc.run(stop))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        monitor = svc.machine("m").monitor
        _until(lambda: monitor.chunks > 0, 120, "the first chunk processed")
    finally:
        loop.call_soon_threadsafe(stop.set)            # while the broker still delivers
        thread.join(60)
    assert not thread.is_alive()
    assert 0 < monitor.chunks < total and monitor.chunks + monitor.rejected == len(handed)   # all handed on: done
    kept: list[int] = []
    late = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=source.client_id, clean_session=False)
    late.on_message = lambda c, u, m: kept.append(decode_chunk(m.payload).seq)
    late.connect("127.0.0.1", mosquitto.port)
    late.loop_start()
    try:
        _until(lambda: set(range(total)) <= set(handed) | set(kept), 60, "every chunk processed or kept")
    finally:
        late.disconnect()
        late.loop_stop()


def test_config_with_an_mqtt_source_fed_by_drivesense_publish(mosquitto, tmp_path):
    """What a new user does: a CONFIG.toml with an mqtt source, 'drivesense monitor', 'drivesense publish'."""
    from dataclasses import replace

    from typer.testing import CliRunner

    from drivesense.cli import app
    from drivesense.io import write_recording
    from drivesense.monitor.sources import demo_condition
    from drivesense.sim.scenarios import ScenarioSettings, simulate_idle

    _, broken, _ = _cuts()
    write_recording(broken, tmp_path / "cut.nc")
    for i, r in enumerate(simulate_idle(demo_condition(), replace(ScenarioSettings(), duration=6.0), seed=5000)):
        write_recording(r, tmp_path / f"idle{i}.nc")
    assert CliRunner().invoke(app, ["axis", "--out", str(tmp_path / "axis.toml")]).exit_code == 0
    from servers import free_port

    http = free_port()                     # the dashboard's API: how far the service is
    (tmp_path / "monitor.toml").write_text(f"""
[service]
events = "events.jsonl"
mqtt = "{mosquitto.url}"
http = "127.0.0.1:{http}"

[[machine]]
id = "vmc1"
teeth = 2
source = {{ kind = "mqtt", url = "{mosquitto.url}", topic = "plant/vmc1/drive" }}

[[machine.axis]]
name = "x"
method = "vibration"
axis_file = "axis.toml"
idle = ["idle0.nc", "idle1.nc", "idle2.nc"]
force_limit = 400
""")
    listener = Listener(mosquitto.port)
    # the service's persistent session (its client id) exists before it starts, as after any earlier
    # run: the broker keeps what is published meanwhile, so no chunk is lost however slowly the service starts
    _subscribe_session(mosquitto.port, MQTTSource("vmc1", mosquitto.url).client_id, "plant/vmc1/drive")
    cli = [sys.executable, "-c", "from drivesense.cli import main; main()"]
    service = subprocess.Popen([*cli, "monitor", str(tmp_path / "monitor.toml"), "--json", str(tmp_path / "s.json")],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert service.poll() is None, service.stdout.read()
        alarms = []
        for run in range(2):               # the second run: the edge device restarted (seq and clock from 0)
            pub = subprocess.run([*cli, "publish", str(tmp_path / "cut.nc"), "--mqtt", mosquitto.url, "--machine",
                                  "vmc1", "--topic", "plant/vmc1/drive", "--speed", "0"], capture_output=True,
                                 text=True, timeout=120)
            assert pub.returncode == 0, pub.stdout + pub.stderr
            assert "published 80 chunk(s), 40000 samples" in pub.stdout and "(session " in pub.stdout
            if run == 0:                   # its start (the axis identified on the idle runs) is slow on a busy machine
                _until(lambda: _machine_status(http).get("source", {}).get("connected"), 300, "the service's start",
                       service)
            _until(lambda: len(listener.kinds("alarm", "breakage")) > len(alarms), 60, "the breakage alarm", service)
            alarms = listener.kinds("alarm", "breakage")
            assert alarms[-1]["machine"] == "vmc1"
        # the rest of the cut: the service runs on until it has every chunk published
        _until(lambda: _machine_status(http).get("samples", 0) >= 80_000, 60, "all 80000 samples", service)
    finally:
        service.send_signal(signal.SIGTERM)
        out, _ = service.communicate(timeout=60)
        listener.close()
    assert service.returncode == 0, out
    summary = json.loads((tmp_path / "s.json").read_text())
    st = summary["machines"]["vmc1"]
    assert (st["samples"], st["rejected"], st["publisher_restarts"]) == (80_000, 0, 1), st
    lines = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    logged = [r for r in lines if "id" in r]
    assert {r["alarmed"] for r in lines if "alarmed" in r} == {r["id"] for r in logged}   # the broker had both
    assert [e["kind"] for e in logged] == ["breakage", "breakage"] and [e["id"] for e in logged] == [
        a["id"] for a in alarms]
    assert logged[0]["time_s"] == logged[1]["time_s"] and logged[0]["session"] != logged[1]["session"]


def test_publish_names_an_unreachable_broker(tmp_path):
    from typer.testing import CliRunner

    from drivesense.cli import app
    from drivesense.io import write_recording
    from drivesense.recording import Recording

    write_recording(Recording.from_arrays({"x_current": np.zeros(100)}, fs=1000.0), tmp_path / "t.nc")
    from servers import free_port

    res = CliRunner().invoke(app, ["publish", str(tmp_path / "t.nc"), "--mqtt", f"mqtt://127.0.0.1:{free_port()}"])
    assert res.exit_code == 2 and "cannot reach the broker" in res.output and "--mqtt" in res.output
    res = CliRunner().invoke(app, ["publish", str(tmp_path / "t.nc"), "--mqtt", "http://x"])
    assert res.exit_code == 2 and "mqtt://HOST" in res.output
