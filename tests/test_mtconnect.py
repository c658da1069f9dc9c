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
from drivesense.io.mtconnect import (AgentError, MTConnectWarning, parse_devices, parse_shdr, parse_streams,
                                     parse_timestamp)
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
    with pytest.raises(ConfigError, match="--method must be linear or hold"):
        read_mtconnect(DATA / "streams.xml", devices, method="cubic")
    with pytest.raises(ConfigError, match="--fs must be a positive number of Hz"):
        read_mtconnect(DATA / "streams.xml", devices, fs=-1.0)


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


def test_shdr_assets_are_kept_with_their_times_and_unknown_commands_warn_once(devices):
    """An adapter's tool table: multi-line and one-line CuttingTool assets, out-of-order asset times,
    removals, an update and two unknown commands (one warning, naming the first line)."""
    with pytest.warns(MTConnectWarning) as caught:
        rec = read_mtconnect(DATA / "tool_assets.shdr", devices)
    assert len(caught) == 1
    assert str(caught[0].message) == ("tool_assets.shdr, line 33: unknown SHDR command '@SET_TOOL_OFFSET@' skipped "
                                      "(2 unknown command lines in all)")
    assert rec.meta["start_time_utc"] == "2024-03-05T10:00:00.000000Z"   # asset times do not move the grid
    assert rec.channels == ["x_table_position", "x_load", "spindle_speed"] and rec.fs == 20.0
    np.testing.assert_allclose(rec["x_table_position"], 0.1 + 0.005 * rec.time, atol=1e-12)
    mtc = rec.meta["mtconnect"]
    assets = mtc["assets"]
    assert [(a["asset_id"], a["tool_id"], a["serial_number"], a["time_utc"]) for a in assets] == [
        ("T12.SN4711", "T12", "SN4711", "2024-03-05T09:12:30.000000Z"),      # sent after the removal, older
        ("T7.SN0815", "T7", "SN0815", "2024-03-05T09:58:10.250000Z"),
        ("T7.SN0816", "T7", "SN0816", "2024-03-05T10:00:00.320000Z")]       # the one-line form
    t12 = assets[0]
    assert t12["t"] == -2850.0 and t12["type"] == "CuttingTool" and t12["status"] == ["USED", "AVAILABLE"]
    assert t12["program_tool_number"] == "12" and t12["program_tool_group"] == "10"
    assert t12["tool_life"] == [
        {"type": "MINUTES", "count_direction": "UP", "value": 12.5, "limit": 30.0, "initial": 0.0, "warning": 25.0},
        {"type": "PART_COUNT", "count_direction": "DOWN", "value": 143.0, "limit": 0.0, "initial": 200.0,
         "warning": None}]
    assert assets[1]["status"] == ["EXPIRED"] and assets[1]["tool_life"][0]["value"] == 45.0
    assert [(r["asset_id"], r["all"], r["type"], r["t"]) for r in mtc["asset_removals"]] == [
        (None, True, "CuttingTool", 0.0001), ("T7.SN0815", False, None, 0.31)]
    assert mtc["asset_updates"] == [{"t": 0.26, "time_utc": "2024-03-05T10:00:00.260000Z", "asset_id": "T12.SN4711",
                                     "changes": {"ToolLife": "12.6"}}]
    assert mtc["events"]["execution"] == [[0.0, "ACTIVE"], [0.4, "READY"]]
    json.dumps(rec.meta, allow_nan=False)


OKUMA_LIKE = """\
2022-08-08T13:51:34.7167146Z|avail|AVAILABLE|X1actw|1039.897|p1CurrentTool|2206
2022-08-08T13:51:34.7237196Z|@REMOVE_ALL_ASSETS@|CuttingTool
2022-08-08T13:43:36.0810790Z|@ASSET@|123456.2201|CuttingTool|--multiline--ABCD
<CuttingTool toolId="123456" serialNumber="2201" assetId="123456.2201"><Description /><CuttingToolLifeCycle>\
<ToolLife type="PART_COUNT" countDirection="UP" initial="0" limit="0">0</ToolLife>\
<ToolLife type="MINUTES" countDirection="UP" initial="0" limit="0">160</ToolLife>\
<CutterStatus><Status>AVAILABLE</Status></CutterStatus><ProgramToolNumber>2201</ProgramToolNumber>\
</CuttingToolLifeCycle></CuttingTool>
--multiline--ABCD
2022-08-08T10:33:04.9702571Z|@ASSET@|123456.20|CuttingTool|--multiline--ABCD
<CuttingTool toolId="123456" serialNumber="20" assetId="123456.20"><CuttingToolLifeCycle>
<ToolLife type="PART_COUNT" countDirection="UP" initial="3" limit="0">3</ToolLife>
</CuttingToolLifeCycle></CuttingTool>
--multiline--ABCD
2022-08-08T13:51:37.2515150Z|X1actw|1040.5
2022-08-08T13:51:41.4582058Z|@REMOVE_ASSET@|123456.20
"""


def test_shdr_okuma_style_assets_without_namespace():
    """The shape of the MTConnect reference agent's Okuma demo log, which stopped at its first asset's XML."""
    obs = parse_shdr("okuma.txt", text=OKUMA_LIKE)
    assert [(o.kind, o.key) for o in obs] == [
        ("EVENT", "avail"), ("SAMPLE", "X1actw"), ("SAMPLE", "p1CurrentTool"), ("ASSET_REMOVED", "*"),
        ("ASSET", "123456.2201"), ("ASSET", "123456.20"), ("SAMPLE", "X1actw"), ("ASSET_REMOVED", "123456.20")]
    tool = obs[4].value
    assert (tool["tool_id"], tool["serial_number"], tool["status"]) == ("123456", "2201", ["AVAILABLE"])
    assert [(life["type"], life["value"]) for life in tool["tool_life"]] == [("PART_COUNT", 0.0), ("MINUTES", 160.0)]
    assert obs[5].time_us < obs[4].time_us < obs[3].time_us          # asset times run backwards: kept as sent
    rec = to_recording(obs, source="okuma.txt", fs=1.0)
    assert [a["serial_number"] for a in rec.meta["mtconnect"]["assets"]] == ["2201", "20"]


def test_shdr_broken_or_unclosed_assets():
    broken = "2024-03-05T10:00:00Z|@ASSET@|T1.1|CuttingTool|<CuttingTool toolId='T1'><oops></CuttingTool>\n"
    with pytest.warns(MTConnectWarning, match=r"log.shdr, line 1 \(CuttingTool XML\).*kept without its XML fields"):
        obs = parse_shdr("log.shdr", text=broken + "2024-03-05T10:00:00Z|Xact|1.0\n")
    assert obs[0].value["asset_id"] == "T1.1" and "error" in obs[0].value and obs[1].value == 1.0
    unclosed = "2024-03-05T10:00:00Z|Xact|1.0\n2024-03-05T10:00:01Z|@ASSET@|T1.1|CuttingTool|--multiline--X1\n<Cutt"
    with pytest.raises(InvalidSignalError, match=r"log.shdr, line 2: asset 'T1.1'.* not closed by '--multiline--X1'"):
        parse_shdr("log.shdr", text=unclosed)
    doctype = ("2024-03-05T10:00:00Z|@ASSET@|T1.1|CuttingTool|--multiline--X1\n<!DOCTYPE x [<!ENTITY a 'b'>]>\n"
               "<CuttingTool toolId='T1'/>\n--multiline--X1\n")
    with pytest.warns(MTConnectWarning, match="DOCTYPE"):                # the hardened parser refuses entities
        assert parse_shdr("log.shdr", text=doctype)[0].value["type"] == "CuttingTool"


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


def test_cli_import_keeps_tool_assets_and_warns_once(tmp_path):
    out = tmp_path / "tools.nc"
    res = runner.invoke(app, ["mtconnect", "import", str(DATA / "tool_assets.shdr"), "--devices",
                              str(DATA / "devices.xml"), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert res.output.count("warning:") == 1 and "line 33: unknown SHDR command '@SET_TOOL_OFFSET@'" in res.output
    assert "assets: 3 sent (3 CuttingTool), 2 removal(s), 1 update(s)" in res.output
    back = read_recording(out).meta["mtconnect"]
    assert [a["serial_number"] for a in back["assets"]] == ["SN4711", "SN0815", "SN0816"]


@pytest.mark.parametrize("args", [["probe", "ftp://host/x"], ["import", "ftp://host/x", "--out", "x.nc"],
                                  ["import", str(DATA / "adapter.shdr"), "--devices", "file:///tmp/devices.xml",
                                   "--out", "x.nc"]])
def test_cli_refuses_unsupported_url_schemes_by_name(args):
    res = runner.invoke(app, ["mtconnect", *args])
    scheme = "file" if "file://" in " ".join(args) else "ftp"
    assert res.exit_code == 2 and res.output.count("\n") == 1
    assert f"unsupported URL scheme '{scheme}' (use http://, https:// or a file path)" in res.output
    assert "file not found" not in res.output
