"""The monitor's HTTP API and WebSocket (drivesense.monitor.web) against a service that has processed cuts.

The demo machine (the second cut breaks a flute) is played as fast as the
service takes it for four cuts of 3 s; the machine keeps its buffers after the
service stops, so the app is then queried with Starlette's TestClient.  The
WebSocket test feeds the subscriber through the test client's event loop.
"""

from __future__ import annotations

import asyncio
import json

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from fastapi.testclient import TestClient  # noqa: E402

from drivesense.monitor.demo import DEMO_FORCE_LIMIT_N, demo_machine  # noqa: E402
from drivesense.monitor.service import MonitorService  # noqa: E402
from drivesense.monitor.web import create_app  # noqa: E402
from servers import run_until_cuts  # noqa: E402

TOKEN = "test-token-5d1f"


def strict(text: str):
    """json.loads refusing NaN, Infinity and -Infinity."""
    def refuse(const):
        raise ValueError(f"non-strict JSON constant {const}")
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    spec = demo_machine(speed=0, cut_s=3.0)
    svc = MonitorService([spec], events_path=tmp_path_factory.mktemp("web") / "events.jsonl", token=TOKEN)
    run_until_cuts(svc, spec, 4)
    return svc


@pytest.fixture(scope="module")
def client(service):
    with TestClient(create_app(service)) as c:
        yield c


def get(client, url, status=200):
    r = client.get(url)
    assert r.status_code == status, (url, r.status_code, r.text)
    return strict(r.text)


def test_dashboard_page_and_static_files_are_packaged(client):
    r = client.get("/")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert "<title>drivesense monitor</title>" in r.text and 'id="events"' in r.text
    for name, kind in (("dashboard.js", "javascript"), ("dashboard.css", "text/css")):
        s = client.get(f"/static/{name}")
        assert s.status_code == 200 and kind in s.headers["content-type"] and len(s.text) > 1000
    for page in (r.text, client.get("/static/dashboard.js").text, client.get("/static/dashboard.css").text):
        assert "http://" not in page and "https://" not in page and "//cdn" not in page
    for sneaky in ("/static/%2e%2e", "/static/..%2Fweb.py", "/static/__init__.py"):
        assert client.get(sneaky).status_code == 404, sneaky
    assert strict(client.get("/static/nothing.js").text)["parameter"] == "file"


def test_machines_lists_the_status_of_each_machine(client):
    machines = get(client, "/api/machines")
    assert [m["machine"] for m in machines] == ["demo"]
    m = machines[0]
    for key in ("state", "source", "samples", "chunks", "rejected", "gaps", "lag_s", "queue", "queue_max",
                "limits", "statistics", "axes", "fs", "restarts"):
        assert key in m, key
    assert m["samples"] >= 4 * 3.0 * m["fs"] * 0.99 and m["rejected"] == 0
    assert m["source"]["kind"] == "simulated" and m["axes"] == ["x"]
    assert {s["detector"] for s in m["statistics"]} >= {"breakage", "overload"}


def test_events_hold_the_breakage_with_a_seq_and_since_filters(client, service):
    events = get(client, "/api/events")
    kinds = [e["kind"] for e in events]
    assert "breakage" in kinds, kinds
    brk = events[kinds.index("breakage")]
    truth = service.machine("demo").source.truth[1]["events"][0]
    assert brk["machine"] == "demo" and brk["axis"] == "x" and isinstance(brk["seq"], int)
    assert abs(brk["time_s"] - truth["time_s"]) < 0.1
    assert [e["seq"] for e in events] == sorted(e["seq"] for e in events)
    last = events[-1]["seq"]
    assert get(client, f"/api/events?since={last}") == []
    assert [e["seq"] for e in get(client, f"/api/events?since={brk['seq'] - 1}")][0] == brk["seq"]
    assert len(get(client, "/api/events?limit=1")) == 1
    assert get(client, "/api/events?since=-1", 400)["parameter"] == "since"
    assert get(client, "/api/events?limit=0", 400)["parameter"] == "limit"
    assert get(client, "/api/events?since=x", 422)["parameter"] == "since"


def test_force_history_shape_and_its_errors(client):
    f = get(client, "/api/machines/demo/force?seconds=1.5")
    assert set(f) == {"t", "force_x"} and len(f["t"]) == len(f["force_x"]) > 100
    assert f["t"] == sorted(f["t"]) and 1.3 < f["t"][-1] - f["t"][0] <= 1.5
    assert max(abs(v) for v in f["force_x"]) > 1.0
    err = get(client, "/api/machines/nope/force?seconds=1", 404)
    assert "nope" in err["error"] and "demo" in err["error"]
    for bad in ("0", "-1", "1e6", "nan", "inf"):
        r = client.get(f"/api/machines/demo/force?seconds={bad}")
        assert r.status_code in (400, 422), (bad, r.status_code)
        assert strict(r.text)["parameter"] == "seconds" and "seconds" in strict(r.text)["error"]
    assert get(client, "/api/machines/demo/force?seconds=abc", 422)["parameter"] == "seconds"


def test_spectrum(client):
    s = get(client, "/api/machines/demo/spectrum?axis=x")
    assert s["axis"] == "x" and len(s["f"]) == len(s["amplitude"]) > 100
    assert max(s["amplitude"]) > 0
    assert get(client, "/api/machines/demo/spectrum?axis=q", 400)["parameter"] == "axis"
    assert "nope" in get(client, "/api/machines/nope/spectrum", 404)["error"]


def test_metrics_are_prometheus_text(client):
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain; version=0.0.4")
    assert 'drivesense_samples_total{machine="demo"}' in r.text
    # as many as the log holds (the service may have begun the next cut, with an event of its own, when stopped)
    logged = sum(e["kind"] == "breakage" for e in get(client, "/api/events"))
    assert logged >= 1
    assert f'drivesense_events_total{{kind="breakage"}} {logged}' in r.text


def test_writes_need_the_token(client, service, monkeypatch):
    brk = next(e for e in get(client, "/api/events") if e["kind"] == "breakage")
    ack = f"/api/events/{brk['id']}/ack"
    limits = "/api/machines/demo/limits"
    body = {"axis": "x", "force_limit_n": 555}
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": TOKEN}, {"Authorization": "Basic x"}):
        for r in (client.post(ack, headers=headers), client.put(limits, json=body, headers=headers)):
            assert r.status_code == 403, (headers, r.text)
            assert "[service] token" in strict(r.text)["error"]
    monkeypatch.setattr(service, "token", None)          # no token configured: read-only, even with a header
    r = client.put(limits, json=body, headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 403 and "[service] token" in strict(r.text)["error"]
    monkeypatch.undo()
    assert get(client, "/api/machines")[0]["limits"]["x"] == DEMO_FORCE_LIMIT_N
    assert not next(e for e in get(client, "/api/events") if e["id"] == brk["id"])["acknowledged"]


def test_right_token_acknowledges_and_changes_limits(client):
    auth = {"Authorization": f"Bearer {TOKEN}"}
    brk = next(e for e in get(client, "/api/events") if e["kind"] == "breakage")
    r = client.post(f"/api/events/{brk['id']}/ack", headers=auth, json={"by": "pytest"})
    assert r.status_code == 200, r.text
    assert strict(r.text)["acknowledged"] == brk["id"]
    assert next(e for e in get(client, "/api/events") if e["id"] == brk["id"])["acknowledged"] is True
    assert client.post("/api/events/demo/breakage/x/1/ack", headers=auth).status_code == 404

    r = client.put("/api/machines/demo/limits", headers=auth, json={"axis": "x", "force_limit_n": 500})
    assert r.status_code == 200, r.text
    assert strict(r.text)["limits"] == {"x": 500.0}
    assert get(client, "/api/machines")[0]["limits"]["x"] == 500.0
    for bad, param in (({"axis": "x", "force_limit_n": -5}, "force_limit_n"), ({"axis": "x", "force_limit_n": "a"},
                       "force_limit_n"), ({"axis": "q", "force_limit_n": 5}, "axis"), ({"force_limit_n": 5}, "axis")):
        r = client.put("/api/machines/demo/limits", headers=auth, json=bad)
        assert r.status_code == 400, (bad, r.text)
        assert strict(r.text)["parameter"] == param
    assert "force_limit_n must be a positive number" in strict(
        client.put("/api/machines/demo/limits", headers=auth, json={"axis": "x", "force_limit_n": 0}).text)["error"]
    r = client.put("/api/machines/demo/limits", headers=auth, content=b'{"axis": "x", "force_limit_n": NaN}')
    assert r.status_code == 400 and strict(r.text)["parameter"] == "body"
    r = client.put("/api/machines/nope/limits", headers=auth, json={"axis": "x", "force_limit_n": 5})
    assert r.status_code == 404 and "nope" in strict(r.text)["error"]
    assert get(client, "/api/machines")[0]["limits"]["x"] == 500.0


def test_every_answer_is_strict_json(client):
    for url in ("/api/machines", "/api/events", "/api/service", "/api/machines/demo/force?seconds=10",
                "/api/machines/demo/spectrum?axis=x", "/api/machines/nope/force"):
        r = client.get(url)
        assert "NaN" not in r.text and "Infinity" not in r.text
        strict(r.text)


def test_websocket_hello_frames_events_and_resync(client, service):
    frame = {"type": "frame", "time": 1.0, "machines": {"demo": {"force": {"t": [0.0], "force_x": [float("nan")]}}}}
    with client.websocket_connect("/ws") as ws:
        hello = strict(ws.receive_text())
        assert hello["type"] == "hello" and [m["machine"] for m in hello["machines"]] == ["demo"]
        assert any(e["kind"] == "breakage" for e in hello["events"])
        assert len(service.subscribers) == 1
        sub = next(iter(service.subscribers))
        ws.portal.call(sub.offer_frame, frame)
        got = strict(ws.receive_text())
        assert got["type"] == "frame" and got["machines"]["demo"]["force"]["force_x"] == [None]
        record = {**hello["events"][0], "seq": 99}
        ws.portal.call(sub.offer_event, record)
        assert strict(ws.receive_text()) == {"type": "event", "event": record}

        def overflow():
            sub.overflow = True
            sub.offer_event(record)
        ws.portal.call(overflow)
        assert strict(ws.receive_text())["type"] == "event"
        assert strict(ws.receive_text()) == {"type": "resync"}
        assert sub.overflow is False
    for _ in range(100):
        if not service.subscribers:
            break
        asyncio.run(asyncio.sleep(0.01))
    assert not service.subscribers


def test_serve_http_runs_beside_the_service_and_stops_with_clients_connected():
    websockets = pytest.importorskip("websockets")
    import socket
    import time

    from drivesense.errors import ConfigError
    from drivesense.monitor.web import serve_http

    svc = MonitorService([demo_machine(speed=1.0, cut_s=3.0)])
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    async def main():
        stop = asyncio.Event()
        both = asyncio.gather(svc.run(stop), serve_http(svc, "127.0.0.1", port, stop))
        for _ in range(200):
            try:
                ws = await websockets.connect(f"ws://127.0.0.1:{port}/ws")
                break
            except OSError:
                await asyncio.sleep(0.05)
        hello = strict(await asyncio.wait_for(ws.recv(), 10))
        frame = strict(await asyncio.wait_for(ws.recv(), 10))
        assert hello["type"] == "hello" and frame["type"] == "frame" and "demo" in frame["machines"]
        assert set(frame["machines"]["demo"]["force"]) == {"t", "force_x"}
        with pytest.raises(ConfigError, match="--http 127.0.0.1:.*cannot listen"):        # the port is taken: named, and it stops
            await serve_http(svc, "127.0.0.1", port, asyncio.Event())
        began = time.monotonic()
        stop.set()                                                      # a client is still connected
        await asyncio.wait_for(both, 15)
        await ws.close()
        return time.monotonic() - began

    took = asyncio.run(main())
    assert took < 5, f"shutdown took {took:.1f} s"
    assert not svc.running and not svc.subscribers
