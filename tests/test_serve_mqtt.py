"""The monitor against a real broker (Debian's mosquitto, started per test on a free loopback port).

An edge device publishes drive-signal chunks; the service estimates, detects and publishes alarms and stop
requests; the test listens like a controller integration would.  Garbage on the topic, and a broker restart
in the middle of the run, must cost nothing but the refused messages.  With CI=true these tests never skip.
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

import numpy as np
import pytest

from drivesense.serve import MachineSpec, MonitorService, MQTTSource, encode_chunk

pytest.importorskip("paho.mqtt.client") if os.environ.get("CI") != "true" else None
import paho.mqtt.client as mqtt  # noqa: E402


class Listener:
    """A paho subscriber on ``+/alarm`` and ``+/stop`` (resubscribing after a broker restart)."""

    def __init__(self, url_port: int) -> None:
        self.messages: list[tuple[str, dict, float]] = []
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"listener-{time.time_ns()}",
                                  clean_session=False)
        self.client.reconnect_delay_set(0.1, 1.0)
        self.client.on_connect = lambda c, u, f, r, p=None: (c.subscribe("+/alarm", qos=1),
                                                             c.subscribe("+/stop", qos=1))
        self.client.on_message = lambda c, u, m: self.messages.append((m.topic, json.loads(m.payload), time.time()))
        self.client.connect("127.0.0.1", url_port)
        self.client.loop_start()

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


def _cuts():
    from drivesense.serve.sources import SimulatedSource
    from drivesense.sim.process_events import ProcessEvent, simulate_event_cut
    from drivesense.sim.scenarios import ScenarioSettings
    from dataclasses import replace

    src = SimulatedSource("m", cut_s=4.0)
    clean, broken = src.simulate_cut(0), src.simulate_cut(1)
    settings = replace(ScenarioSettings(), duration=4.0, t_contact=0.8)
    from drivesense.serve.sources import demo_condition

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
    from drivesense.serve.demo import demo_monitor

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
        deadline = time.time() + 20
        while not source.connected and time.time() < deadline:
            time.sleep(0.05)
        assert source.connected
        time.sleep(0.3)                                        # the subscription is in place
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
        deadline = time.time() + 30
        while not source.connected and time.time() < deadline:
            time.sleep(0.05)
        assert source.connected, "the source did not reconnect after the broker restart"
        time.sleep(0.5)
        _publish(edge, collision, seq0=seq, t_offset=8.0)
        hit = listener.wait("alarm", "collision")
        assert 9.99 < hit["time_s"] < 10.01, svc.machine_status("m")
        listener.wait("stop", "collision")
        deadline = time.time() + 10
        while (svc.machine("m").monitor.samples + 500 * svc.machine("m").monitor.gaps < 3 * 40_000
               and time.time() < deadline):
            time.sleep(0.05)
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


def test_config_with_an_mqtt_source_fed_by_drivesense_publish(mosquitto, tmp_path):
    """What a new user does: a CONFIG.toml with an mqtt source, 'drivesense monitor', 'drivesense publish'."""
    from dataclasses import replace

    from typer.testing import CliRunner

    from drivesense.cli import app
    from drivesense.io import write_recording
    from drivesense.serve.sources import demo_condition
    from drivesense.sim.scenarios import ScenarioSettings, simulate_idle

    _, broken, _ = _cuts()
    write_recording(broken, tmp_path / "cut.nc")
    for i, r in enumerate(simulate_idle(demo_condition(), replace(ScenarioSettings(), duration=6.0), seed=5000)):
        write_recording(r, tmp_path / f"idle{i}.nc")
    assert CliRunner().invoke(app, ["axis", "--out", str(tmp_path / "axis.toml")]).exit_code == 0
    (tmp_path / "monitor.toml").write_text(f"""
[service]
events = "events.jsonl"
mqtt = "{mosquitto.url}"

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
    session = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=MQTTSource("vmc1", mosquitto.url).client_id,
                          clean_session=False)
    session.connect("127.0.0.1", mosquitto.port)
    session.loop_start()
    session.subscribe("plant/vmc1/drive", qos=1)[1]
    time.sleep(0.3)
    session.disconnect()
    session.loop_stop()
    cli = [sys.executable, "-c", "from drivesense.cli import main; main()"]
    service = subprocess.Popen([*cli, "monitor", str(tmp_path / "monitor.toml"), "--json", str(tmp_path / "s.json")],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert service.poll() is None, service.stdout.read()
        alarms = []
        for _ in range(2):                 # the second run: the edge device restarted (seq and clock from 0)
            pub = subprocess.run([*cli, "publish", str(tmp_path / "cut.nc"), "--mqtt", mosquitto.url, "--machine",
                                  "vmc1", "--topic", "plant/vmc1/drive", "--speed", "0"], capture_output=True,
                                 text=True, timeout=120)
            assert pub.returncode == 0, pub.stdout + pub.stderr
            assert "published 80 chunk(s), 40000 samples" in pub.stdout and "(session " in pub.stdout
            deadline = time.time() + 60
            while len(listener.kinds("alarm", "breakage")) <= len(alarms) and time.time() < deadline:
                time.sleep(0.05)
            alarms = listener.kinds("alarm", "breakage")
            assert alarms and alarms[-1]["machine"] == "vmc1"
        time.sleep(3.0)                                        # the rest of the cut (the service runs on)
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
