"""Alarms reach the broker at least once, across a kill: the log records which ones the broker acknowledged.

Before this, an event logged by a service killed in the moment before the broker had its alarm was in the
log but never alarmed: the restarted service (or the fleet worker taking the machine over) read the event
back, and an event already logged is not announced again.  Against a real mosquitto.
"""

from __future__ import annotations

import json
import os
import time

import pytest

from drivesense.monitor.outputs import REALARM_S, AlarmPublisher, EventLog

pytest.importorskip("paho.mqtt.client") if os.environ.get("CI") != "true" else None


def _event(i: int, detected: float | None = None, kind: str = "breakage") -> dict:
    return {"id": f"m/breakage/x/{i}", "machine": "m", "kind": kind, "axis": "x", "time_s": i * 1e-6,
            "detected": time.time() if detected is None else detected}


def _subscriber(url_port: int) -> tuple:
    import paho.mqtt.client as mqtt

    got: list = []
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"sub-{time.time_ns()}")
    client.on_connect = lambda c, u, f, r, p=None: (c.subscribe("+/alarm", qos=1), c.subscribe("+/stop", qos=1))
    client.on_message = lambda c, u, m: got.append((m.topic, json.loads(m.payload)))
    client.connect("127.0.0.1", url_port)
    client.loop_start()
    time.sleep(0.4)
    return client, got


def _wait(cond, timeout: float = 10.0) -> None:
    deadline = time.time() + timeout
    while not cond() and time.time() < deadline:
        time.sleep(0.02)


def test_the_log_keeps_which_alarms_the_broker_acknowledged(tmp_path):
    log = EventLog(tmp_path / "events.jsonl")
    for r in (_event(1), _event(2), _event(3, detected=time.time() - REALARM_S - 60)):
        log.append(r)
    assert log.mark_alarmed("m/breakage/x/1")
    with pytest.raises(ValueError, match="alarmed"):
        log.note({"alarmed": "x"})
    log.close()
    assert not log.mark_alarmed("m/breakage/x/2")                 # closed: nothing written, no error
    again = EventLog(tmp_path / "events.jsonl")
    assert again.alarmed == {"m/breakage/x/1"} and again.recovered == 3
    assert [r["id"] for r in again.unalarmed()] == ["m/breakage/x/2"]   # x/3: older than REALARM_S
    again.close()


def test_a_restart_alarms_again_what_the_broker_never_had_and_only_that(mosquitto, tmp_path):
    log = EventLog(tmp_path / "events.jsonl")
    for i in range(1, 4):
        log.append(_event(i))
    log.mark_alarmed("m/breakage/x/1")                           # delivered before the "kill"
    log.close()
    sub, got = _subscriber(mosquitto.port)
    log = EventLog(tmp_path / "events.jsonl")                    # the restarted service
    alarms = AlarmPublisher(mosquitto.url, client_id="t-restart")
    try:
        assert alarms.republish(log) == 2
        _wait(lambda: len(got) >= 2 and not alarms.undelivered())
        time.sleep(0.3)
        assert sorted(b["id"] for t, b in got) == ["m/breakage/x/2", "m/breakage/x/3"]
        assert all(t == "m/alarm" and b["republished"] for t, b in got)      # no late stop request
        assert alarms.delivered == 2 and alarms.republish(log) == 0
    finally:
        alarms.close()
        log.close()
        sub.loop_stop()
    assert EventLog(tmp_path / "events.jsonl").unalarmed() == []


def test_close_waits_for_the_acknowledgements_and_a_broker_away_leaves_them_to_the_next_start(mosquitto, tmp_path):
    log = EventLog(tmp_path / "events.jsonl")
    alarms = AlarmPublisher(mosquitto.url, client_id="t-close")
    _wait(lambda: alarms.connected)
    for i in range(50):
        alarms.publish(log.append(_event(i)), (log,))
    alarms.close()                                               # waits for the 50 PUBACKs
    log.close()
    assert EventLog(tmp_path / "events.jsonl").alarmed == {f"m/breakage/x/{i}" for i in range(50)}

    mosquitto.stop()
    log = EventLog(tmp_path / "events.jsonl")
    alarms = AlarmPublisher(mosquitto.url, client_id="t-away")
    alarms.publish(log.append(_event(99)), (log,))
    time.sleep(0.3)
    assert alarms.undelivered(log) == 1
    alarms.close(timeout=0.5)
    log.close()
    assert [r["id"] for r in EventLog(tmp_path / "events.jsonl").unalarmed()] == ["m/breakage/x/99"]
