"""MTConnect ingest: Devices mapping, Streams and SHDR into Recordings, and the agent client.

The client is tested against a small agent on 127.0.0.1 that serves the recorded documents of
``tests/data/mtconnect`` (``/probe``, ``/current``, windows of the recorded buffer for
``/sample?from=&count=``) and can drop the oldest part of its buffer or restart, like a real
agent; it answers with the recorded ``OUT_OF_RANGE`` error document.  The server stops by itself.
"""

from __future__ import annotations

import http.server
import json
import math
import threading
import time
import urllib.parse
from pathlib import Path

import numpy as np
import pytest
from lxml import etree
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.io.mtconnect import AgentError, parse_devices, parse_shdr, parse_streams, parse_timestamp
from drivesense.io.mtconnect_client import MTConnectClient, StreamLog
from drivesense.io.mtconnect_resample import read_mtconnect, to_recording
from drivesense.io import read_recording

DATA = Path(__file__).parent / "data" / "mtconnect"
runner = CliRunner()


@pytest.fixture(scope="module")
def devices():
    return parse_devices(DATA / "devices.xml")


@pytest.fixture(scope="module")
def from_streams(devices):
    return read_mtconnect(DATA / "streams.xml", devices)


# ------------------------------------------------------------------ documents
def test_devices_map_to_canonical_channels_and_si(devices):
    by_id = {i.id: i for i in devices.items}
    expected = {"Xact": "x_table_position", "Xcom": "x_position_commanded", "Xfrt": "x_velocity",
                "Xamp": "x_current", "Xload": "x_load", "Yact": "y_table_position", "Sspeed": "spindle_speed",
                "Spower": "spindle_power", "Sload": "spindle_load", "pfr": "path_feedrate",
                "ppos": "path_position", "Zacc": "spindle_accelerometer_acceleration"}
    assert {k: by_id[k].channel for k in expected} == expected
    assert by_id["Xact"].scale() == (1e-3, "m") and by_id["Xfrt"].scale(native=True) == (1e-3 / 60, "m/s")
    assert by_id["Sspeed"].scale() == (2 * math.pi / 60, "rad/s") and by_id["Xload"].scale() == (0.01, "1")
    assert by_id["Stemp"].scale() is None  # CELSIUS: no SI entry in drivesense's unit table
    assert by_id["Zacc"].representation == "TIME_SERIES" and by_id["Zacc"].sample_rate == 1000.0
    assert devices.devices[0]["manufacturer"] == "Example Machine Co." and devices.lookup("execution").id == "exec"


def test_streams_resampled_explicitly_into_si(from_streams):
    rec = from_streams
    assert rec.fs == 1000.0 and rec.t0 == 0.0 and rec.meta["start_time_utc"] == "2024-03-05T09:00:00.003000Z"
    assert rec.units("x_table_position") == "m" and rec.units("spindle_speed") == "rad/s"
    t = rec.time + 0.003
    moving = t < 1.98  # after the last X report the position holds
    assert np.max(np.abs(rec["x_table_position"] - (0.1 + 0.005 * t))[moving]) < 3e-6  # 2 um ripple + interpolation
    assert np.allclose(rec["x_velocity"], 0.005, atol=5e-5)
    assert np.allclose(rec["spindle_speed"], 1000 * 2 * np.pi / 60, atol=0.25)
    acc = rec["spindle_accelerometer_acceleration"]  # a 1 kHz time series on a 1 kHz grid: the samples themselves
    assert np.max(np.abs(acc - 2.0 * np.sin(2 * np.pi * 150 * np.round(t, 6)))) < 1e-5
    assert np.all((rec["x_load"] >= 0.35) & (rec["x_load"] <= 0.45))
    mtc = rec.meta["mtconnect"]
    assert mtc["gaps"] == {"spindle_speed": [[0.997, 1.097]]}
    assert "Stemp" in mtc["skipped"] and mtc["data_items"]["x_table_position"]["mtconnect_units"] == "MILLIMETER"
    assert mtc["events"]["execution"] == [[-0.003, "ACTIVE"], [1.996, "READY"]]
    warning = [c for c in mtc["conditions"] if c["level"] == "WARNING"]
    assert warning == [{"t": 1.497, "item": "Scond", "level": "WARNING", "type": "SYSTEM", "nativeCode": "OVT",
                        "nativeSeverity": "2", "qualifier": "HIGH", "message": "Spindle temperature high"}]
    assert mtc["messages"][0]["text"] == "Tool check" and mtc["messages"][0]["nativeCode"] == "M01"
    prov = rec.meta["provenance"][-1]
    assert "resampled to a uniform grid at fs=1000 Hz" in prov and "linear interpolation" in prov
    assert "UNAVAILABLE gaps bridged in spindle_speed" in prov and "Stemp" in prov
    assert rec.meta["machine"] == "Example Machine Co. VM-500 VMC-3Axis"


def test_hold_and_given_rate(devices):
    hold = read_mtconnect(DATA / "streams.xml", devices, method="hold", fs=100.0)
    assert hold.fs == 100.0 and "zero-order hold" in hold.meta["provenance"][-1]
    reported = {round(0.35 + 0.005 * k, 4) for k in range(20)}
    assert set(np.round(hold["x_load"], 4)) <= reported  # held values are reported values
    lin = read_mtconnect(DATA / "streams.xml", devices, fs=100.0)
    assert not set(np.round(lin["x_load"], 4)) <= reported
    with pytest.raises(ConfigError, match="method must be"):
        read_mtconnect(DATA / "streams.xml", devices, method="cubic")


def test_shdr_log_with_devices_equals_the_streams(devices, from_streams):
    rec = read_mtconnect(DATA / "adapter.shdr", devices)  # native units: mm/min and kW
    assert rec.channels == from_streams.channels and rec.fs == from_streams.fs
    for ch in rec.channels:
        assert np.allclose(rec[ch], from_streams[ch], rtol=1e-9, atol=1e-12), ch
    fields = ("t", "item", "level", "message")
    assert [{k: c[k] for k in fields} for c in rec.meta["mtconnect"]["conditions"]] == \
        [{k: c[k] for k in fields} for c in from_streams.meta["mtconnect"]["conditions"]]


def test_shdr_without_devices_recognises_multi_field_items(tmp_path):
    obs = parse_shdr(DATA / "adapter.shdr")
    kinds = {(o.key, o.kind) for o in obs}
    assert {("Scond", "CONDITION"), ("msg", "MESSAGE"), ("Zacc", "TIME_SERIES"), ("Xact", "SAMPLE"),
            ("execution", "EVENT")} <= kinds
    cond = next(o for o in obs if o.key == "Scond" and o.value == "WARNING")
    assert cond.extra == {"nativeCode": "OVT", "nativeSeverity": "2", "qualifier": "HIGH",
                          "message": "Spindle temperature high"}
    series = next(o for o in obs if o.kind == "TIME_SERIES")
    assert series.value.size == 100 and series.extra["sample_rate"] == 1000.0
    rec = to_recording(obs, source="adapter.shdr")
    assert rec.units("xact") == "1" and rec.meta["mtconnect"]["data_items"]["xact"]["mtconnect_units"] == "unknown"
    bad = tmp_path / "bad.shdr"
    bad.write_text("* shdrVersion: 2\n2024-03-05T09:00:00Z|Xact|1.0\nyesterday|Xact|2.0\n")
    with pytest.raises(InvalidSignalError, match=r"bad.shdr, line 3: 'yesterday' is not an ISO 8601 timestamp"):
        parse_shdr(bad)
    bad.write_text("2024-03-05T09:00:00Z|Xact|1.0|Yact|2.0|Zact\n")
    with pytest.raises(InvalidSignalError, match=r"line 1: value item 'Zact' needs 1 field"):
        parse_shdr(bad)


def test_timestamps_and_agent_errors():
    assert parse_timestamp("2024-03-05T09:00:00.5Z") - parse_timestamp("2024-03-05T09:00:00Z") == 500_000
    assert parse_timestamp("2024-03-05T10:00:00+01:00") == parse_timestamp("2024-03-05T09:00:00")
    assert parse_timestamp("2024-03-05T09:00:00.000001Z@100.0") % 1_000_000 == 1
    with pytest.raises(AgentError, match="OUT_OF_RANGE") as err:
        parse_streams(DATA / "error_out_of_range.xml")
    assert err.value.code == "OUT_OF_RANGE"
    with pytest.raises(InvalidSignalError, match="not MTConnectStreams"):
        parse_streams(DATA / "devices.xml")


# ------------------------------------------------------------------ the agent
class FakeAgent:
    """Serves the recorded buffer; can lose its oldest data or restart after a given request."""

    def __init__(self, drop_after: int | None = None, drop: int = 0, restart_after: int | None = None):
        root = etree.parse(str(DATA / "streams.xml")).getroot()
        self.ns = etree.QName(root).namespace
        self.obs = []
        for comp in root.iter(f"{{{self.ns}}}ComponentStream"):
            for cat in comp:
                for el in cat:
                    self.obs.append((int(el.get("sequence")), dict(comp.attrib), etree.QName(cat).localname,
                                     etree.tostring(el, with_tail=False).decode()))
        self.obs.sort()
        self.first, self.next, self.instance = 1, len(self.obs) + 1, 1709629200
        self.drop_after, self.drop, self.restart_after = drop_after, drop, restart_after
        self.requests: list[str] = []

    def doc(self, selected, next_seq) -> bytes:
        parts = [f'<MTConnectStreams xmlns="{self.ns}"><Header creationTime="2024-03-05T09:00:02Z" '
                 f'instanceId="{self.instance}" bufferSize="4096" firstSequence="{self.first}" '
                 f'lastSequence="{self.next - 1}" nextSequence="{next_seq}"/><Streams>'
                 '<DeviceStream name="VMC-3Axis" uuid="vmc-3axis-0042">']
        own_ns = f' xmlns="{self.ns}"'
        for seq, comp, cat, xml in selected:
            attrs = "".join(f' {k}="{v}"' for k, v in comp.items())
            parts.append(f"<ComponentStream{attrs}><{cat}>{xml.replace(own_ns, '')}</{cat}></ComponentStream>")
        return ("".join(parts) + "</DeviceStream></Streams></MTConnectStreams>").encode()

    def answer(self, path: str) -> tuple[int, bytes]:
        url = urllib.parse.urlsplit(path)
        self.requests.append(path)
        query = dict(urllib.parse.parse_qsl(url.query))
        if url.path == "/probe":
            return 200, (DATA / "devices.xml").read_bytes()
        if url.path == "/current":
            return 200, self.doc([], self.next)
        if url.path != "/sample":
            return 404, b"not found"
        start, count = int(query.get("from", self.first)), int(query.get("count", 100))
        if not self.first <= start <= self.next:
            return 400, (DATA / "error_out_of_range.xml").read_bytes()
        picked = [o for o in self.obs if start <= o[0] < start + count]
        body = self.doc(picked, min(start + count, self.next))
        n_sample = sum(r.startswith("/sample") for r in self.requests)
        if self.drop_after == n_sample:
            self.first += self.drop
        if self.restart_after == n_sample:
            self.instance += 1
        return 200, body


@pytest.fixture
def agent():
    """Start a FakeAgent on 127.0.0.1 (bounded: stops by itself after 30 s)."""
    servers = []

    def start(**kw):
        fake = FakeAgent(**kw)

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802
                code, body = fake.answer(self.path)
                self.send_response(code)
                self.send_header("Content-Type", "application/xml")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        srv = http.server.HTTPServer(("127.0.0.1", 0), Handler)
        srv.timeout = 0.05
        stop, deadline = threading.Event(), time.monotonic() + 30

        def loop():
            while not stop.is_set() and time.monotonic() < deadline:
                srv.handle_request()

        thread = threading.Thread(target=loop, daemon=True)
        thread.start()
        servers.append((srv, stop, thread))
        return f"http://127.0.0.1:{srv.server_address[1]}", fake

    yield start
    for srv, stop, thread in servers:
        stop.set()
        thread.join(2)
        srv.server_close()


def _sequences(docs) -> list[int]:
    return [o.sequence for d in docs for o in d.observations]


def test_client_walks_the_buffer_with_sequence_continuity(agent, from_streams):
    url, fake = agent()
    client = MTConnectClient(url, timeout=5)
    log = StreamLog()
    docs = list(client.stream(count=100, log=log))
    assert _sequences(docs) == list(range(1, len(fake.obs) + 1))
    assert log.lost == [] and log.first == 1 and log.last == len(fake.obs) and log.requests == 9
    assert fake.requests[1].startswith("/sample?from=101&count=100")
    rec = client.collect(count=250)
    assert rec.channels == from_streams.channels
    assert all(np.array_equal(rec[c], from_streams[c]) for c in rec.channels)
    assert rec.meta["mtconnect"]["agent"] == url and "resampled" in rec.meta["provenance"][-1]


def test_client_recovers_from_out_of_range(agent):
    url, fake = agent(drop_after=1, drop=150)  # after the first answer the agent loses sequences 1..150
    log = StreamLog()
    docs = list(MTConnectClient(url, timeout=5).stream(count=100, log=log))
    got = _sequences(docs)
    assert got == list(range(1, 101)) + list(range(151, len(fake.obs) + 1))
    assert log.lost == [[101, 150]]
    assert [r.split("&")[0] for r in fake.requests[:4]] == ["/sample?count=100", "/sample?from=101", "/current",
                                                             "/sample?from=151"]


def test_client_notices_an_agent_restart(agent):
    url, fake = agent(restart_after=2)
    log = StreamLog()
    docs = list(MTConnectClient(url, timeout=5).stream(count=400, log=log))
    assert log.restarts == [[1709629200, 1709629201]]
    got = _sequences(docs)  # the old instance's answers, then the new instance's buffer from its start
    assert got == list(range(1, 801)) + list(range(1, len(fake.obs) + 1))


def test_client_bad_urls_limits_and_unreachable(agent):
    with pytest.raises(ConfigError, match="must be http"):
        MTConnectClient("ftp://127.0.0.1/x")
    with pytest.raises(ConfigError, match="cannot reach the MTConnect agent"):
        MTConnectClient("http://127.0.0.1:9", timeout=2).current()
    url, _ = agent()
    with pytest.raises(InvalidSignalError, match="larger than 1000 bytes"):
        MTConnectClient(url, max_bytes=1000).probe()
    with pytest.raises(InvalidSignalError):
        MTConnectClient(url + "/nothing").current()


def test_cli_probe_and_import(agent, tmp_path):
    res = runner.invoke(app, ["mtconnect", "probe", str(DATA / "devices.xml"), "--json", str(tmp_path / "p.json")])
    assert res.exit_code == 0 and "23 data item(s)" in res.output and "VMC-3Axis" in res.output
    items = {r["id"]: r for r in json.loads((tmp_path / "p.json").read_text())["data_items"]}
    assert items["Xact"]["channel"] == "x_table_position" and items["Xact"]["si_unit"] == "m"
    url, _ = agent()
    res = runner.invoke(app, ["mtconnect", "probe", url])
    assert res.exit_code == 0 and "23 data item(s)" in res.output
    out = tmp_path / "m.nc"
    res = runner.invoke(app, ["mtconnect", "import", str(DATA / "adapter.shdr"), "--devices", str(DATA / "devices.xml"),
                              "--out", str(out), "--method", "hold"])
    assert res.exit_code == 0, res.output
    assert read_recording(out).meta["mtconnect"]["gaps"]["spindle_speed"] == [[0.997, 1.097]]
    res = runner.invoke(app, ["mtconnect", "import", url, "--out", str(tmp_path / "live.nc"), "--count", "300",
                              "--fs", "500"])
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "live.nc").fs == 500.0
    res = runner.invoke(app, ["mtconnect", "import", str(DATA / "devices.xml"), "--out", str(tmp_path / "x.nc")])
    assert res.exit_code == 2 and "not MTConnectStreams" in res.output
