"""The controller sources of the monitor service against real servers on loopback.

MTConnect: a small live agent (``/probe`` from ``tests/data/mtconnect/devices.xml``, ``/current``,
``/sample?from=&count=`` over a bounded buffer) that reports X position [mm], X current [A] and spindle
speed [rpm] every 10 ms of its own clock and advances that clock by 30 ms after every ``/sample``; it can
restart (new instanceId, sequences from 1, its clock continuing or going back), lose its oldest
observations to a burst (``OUT_OF_RANGE``) and go offline.  OPC UA: an asyncua server on a free port
whose variables a task keeps writing; it is stopped and started again (same port, same address space).
"""

from __future__ import annotations

import asyncio
import http.server
import math
import threading
import urllib.parse
from pathlib import Path

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.nc_context import program_code
from drivesense.monitor.controllers import MTConnectSource, OPCUASource
from drivesense.monitor.wire import Chunk

DATA = Path(__file__).parent / "data" / "mtconnect"
NS = "urn:mtconnect.org:MTConnectStreams:1.3"
BASE_US = 1_709_629_200_000_000            # 2024-03-05T09:00:00Z
STEP_US = 10_000                           # one report per item every 10 ms
ITEMS = {"Xact": ("Position", lambda t: 100.0 + 5.0 * t),                      # mm, a ramp
         "Xamp": ("Amperage", lambda t: 2.0 + math.sin(2 * math.pi * 3.0 * t)),  # A
         "Sspeed": ("RotaryVelocity", lambda t: 6000.0 + 100.0 * t)}           # rpm
SI = {"x_table_position": lambda t: (100.0 + 5.0 * t) * 1e-3, "x_current": lambda t: 2.0 + np.sin(6 * np.pi * t),
      "spindle_speed": lambda t: (6000.0 + 100.0 * t) * 2 * math.pi / 60}


def _iso(us: int) -> str:
    s, frac = divmod(us, 1_000_000)
    import datetime as dt
    return dt.datetime.fromtimestamp(s, dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S") + f".{frac:06d}Z"


class LiveAgent:
    """A live agent's buffer: three items reported every 10 ms, a line event every 100 ms."""

    def __init__(self, size: int = 1000, per_request: int = 3) -> None:
        self.size, self.per_request = size, per_request
        self.lock = threading.RLock()
        self.instance, self.seq, self.clock = 1, 1, 0
        self.obs: list[tuple[int, int, str, str]] = []       # (sequence, time [us], key, value text)
        self.served: dict[str, set[int]] = {k: set() for k in ITEMS}
        self.burst = 0
        self.produce(5)

    @property
    def first(self) -> int:
        return self.obs[0][0] if self.obs else self.seq

    def produce(self, reports: int) -> None:
        for _ in range(reports):
            t = BASE_US + self.clock * STEP_US
            for key, (_, f) in ITEMS.items():
                self.obs.append((self.seq, t, key, repr(f((t - BASE_US) * 1e-6))))
                self.seq += 1
            if self.clock % 10 == 0:
                self.obs.append((self.seq, t, "line", str(self.clock // 10)))
                self.seq += 1
            self.clock += 1
        del self.obs[:-self.size]

    def restart(self, back_reports: int = 0) -> None:
        with self.lock:
            self.instance += 1
            self.seq, self.obs = 1, []
            self.clock -= back_reports
            self.produce(2)

    def doc(self, picked, next_seq: int, sample: bool = True) -> bytes:
        rows = []
        for seq, t, key, value in picked:
            tag = "Line" if key == "line" else ITEMS[key][0]
            rows.append(f'<{tag} dataItemId="{key}" timestamp="{_iso(t)}" sequence="{seq}">{value}</{tag}>')
            if sample and key in self.served:          # /sample answers (the client uses /current's header)
                self.served[key].add(t)
        samples = "".join(r for r in rows if "Line" not in r)
        events = "".join(r for r in rows if "Line" in r)
        return (f'<MTConnectStreams xmlns="{NS}"><Header creationTime="{_iso(BASE_US)}" instanceId="{self.instance}" '
                f'bufferSize="{self.size}" firstSequence="{self.first}" lastSequence="{self.seq - 1}" '
                f'nextSequence="{next_seq}"/><Streams><DeviceStream name="VMC-3Axis" uuid="vmc-3axis-0042">'
                f'<ComponentStream component="Linear" name="X" componentId="x"><Samples>{samples}</Samples>'
                f'<Events>{events}</Events></ComponentStream></DeviceStream></Streams></MTConnectStreams>'
                ).encode()

    def answer(self, path: str) -> tuple[int, bytes]:
        url = urllib.parse.urlsplit(path)
        query = dict(urllib.parse.parse_qsl(url.query))
        with self.lock:
            if url.path == "/probe":
                return 200, (DATA / "devices.xml").read_bytes()
            if url.path == "/current":
                latest = {}
                for o in self.obs:
                    latest[o[2]] = o
                return 200, self.doc(sorted(latest.values()), self.seq, sample=False)
            if url.path != "/sample":
                return 404, b"not found"
            start, count = int(query.get("from", self.first)), int(query.get("count", 100))
            if not self.first <= start <= self.seq:
                return 400, (DATA / "error_out_of_range.xml").read_bytes()
            picked = [o for o in self.obs if start <= o[0] < start + count]
            body = self.doc(picked, min(start + count, self.seq))
            self.produce(self.per_request + self.burst)       # the agent's clock goes on after each answer
            self.burst = 0
            return 200, body


class AgentServer:
    """Serves a LiveAgent on 127.0.0.1; stop() and start() again keep the port."""

    def __init__(self, agent: LiveAgent) -> None:
        self.agent, self.port, self.srv = agent, 0, None
        self.start()

    def start(self) -> None:
        fake = self.agent

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

        self.srv = http.server.ThreadingHTTPServer(("127.0.0.1", self.port), Handler)
        self.port = self.srv.server_address[1]
        threading.Thread(target=self.srv.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True).start()

    def stop(self) -> None:
        self.srv.shutdown()
        self.srv.server_close()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"


@pytest.fixture
def live_agent():
    server = AgentServer(LiveAgent())
    yield server
    server.stop()


async def _until(cond, timeout: float = 5.0) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not cond():
        assert loop.time() < end, "timed out"
        await asyncio.sleep(0.01)


def _check_stream(chunks: list[Chunk], channels: set[str], fs: float) -> dict[str, np.ndarray]:
    """Continuing seq and t0, exactly the channels, float64, finite, equal lengths; the joined arrays."""
    assert [c.seq for c in chunks] == list(range(len(chunks)))
    for a, b in zip(chunks, chunks[1:]):
        assert b.t0 == pytest.approx(a.t0 + a.n / fs, abs=1e-9)
    for c in chunks:
        assert c.fs == fs and set(c.arrays) == channels and c.n > 0
        for arr in c.arrays.values():
            assert arr.dtype == np.float64 and arr.ndim == 1 and arr.size == c.n and np.all(np.isfinite(arr))
    return {ch: np.concatenate([c.arrays[ch] for c in chunks]) for ch in channels}


def test_mtconnect_source_streams_restarts_and_recovers(live_agent):
    agent = live_agent.agent
    src = MTConnectSource("m1", live_agent.url, fs=100.0, interval_s=0.02, count=500, timeout=5)
    got: list = []

    async def put(item):
        got.append(item)

    def samples() -> int:
        return sum(c.n for c in got if isinstance(c, Chunk))

    async def main():
        stop = asyncio.Event()
        task = asyncio.create_task(src.run(put, stop))
        await _until(lambda: samples() >= 50)
        agent.restart()                                  # the agent restarts, its clock goes on
        await _until(lambda: src.restarts == 1 and samples() >= 120)
        agent.restart(back_reports=30)                   # ... and once with its clock 0.3 s back
        await _until(lambda: src.restarts == 2 and src.late > 0 and samples() >= 250)
        agent.burst = 600                                # 6 s of reports at once: the buffer overruns
        await _until(lambda: src.lost > 0 and samples() >= 900)
        live_agent.stop()                                # offline: run() raises, the service restarts it
        with pytest.raises(ConfigError, match="cannot reach the MTConnect agent"):
            await asyncio.wait_for(task, 5)
        assert src.describe()["connected"] is False
        with agent.lock:                                 # meanwhile the agent restarted and its new buffer
            agent.restart()                              # has passed the source's next sequence number:
            while agent.seq <= src._next + 20:           # only the instanceId tells
                agent.produce(1)
        assert agent.first <= src._next < agent.seq
        before = len(got)
        live_agent.start()
        task = asyncio.create_task(src.run(put, stop))
        await _until(lambda: len(got) > before + 3)
        stop.set()
        await asyncio.wait_for(task, 5)

    asyncio.run(main())
    assert not [e for e in got if isinstance(e, Exception)]
    chunks = [c for c in got if isinstance(c, Chunk)]
    arrays = _check_stream(chunks, set(SI) | {"block_number"}, 100.0)
    info = src.describe()
    assert info["channels"] == sorted([*SI, "block_number"]) and info["restarts"] == 3 and info["lost"] > 500
    assert info["samples"] == arrays["x_current"].size and info["chunks"] == len(chunks)
    t = (src._start_us - BASE_US) * 1e-6 + np.arange(arrays["x_current"].size) / 100.0
    # the ramps are linear: interpolation across restarts and lost stretches is exact
    for ch in ("x_table_position", "spindle_speed"):
        np.testing.assert_allclose(arrays[ch], SI[ch](t), rtol=1e-12, atol=1e-12)
    # the current is exact wherever the agent served a report (everything else is interpolated)
    served = np.isin(BASE_US + np.round(t * 1e6).astype(np.int64), list(agent.served["Xamp"]))
    assert served.sum() > 300 and (~served).sum() > 200      # the burst's lost stretch
    np.testing.assert_allclose(arrays["x_current"][served], SI["x_current"](t[served]), atol=1e-12)
    assert chunks[-1].t0 + chunks[-1].n / 100.0 < (agent.clock * STEP_US) * 1e-6   # never ahead of the agent
    # the NC's context by default: the path's LINE event as block_number, held between reports (not
    # interpolated): before the first restart, the line reported every 100 ms, i.e. floor(10 t)
    block = arrays["block_number"]
    assert np.array_equal(block, np.round(block))
    first = slice(0, 50)
    np.testing.assert_array_equal(block[first], np.floor(t[first] * 10.0 + 1e-9))


def test_mtconnect_source_channel_mapping_and_hold(live_agent):
    src = MTConnectSource("m1", live_agent.url, fs=50.0, interval_s=0.02, method="hold",
                          channels={"Xamp": "x_current", "Sspeed": "spindle_speed"})
    got: list = []

    async def main():
        stop = asyncio.Event()

        async def put(item):
            got.append(item)
            if sum(c.n for c in got) >= 40:
                stop.set()

        await asyncio.wait_for(src.run(put, stop), 10)

    asyncio.run(main())
    arrays = _check_stream(got, {"x_current", "spindle_speed"}, 50.0)
    t = (src._start_us - BASE_US) * 1e-6 + np.arange(arrays["x_current"].size) / 50.0
    np.testing.assert_allclose(arrays["x_current"], SI["x_current"](t), atol=1e-12)   # on report times
    assert "line" not in " ".join(src.describe()["ignored"])
    for channels, message in (({"Nope": "x_current"}, "data item 'Nope' is not in the agent's /probe"),
                              ({"Xact": "x_current"}, "channel 'x_current' needs a current unit")):
        chunks, error = MTConnectSource("m1", live_agent.url, fs=50.0, channels=channels).poll()
        assert chunks == [] and isinstance(error, ConfigError) and message in str(error)
    with pytest.raises(ConfigError, match="must be http"):
        MTConnectSource("m1", "opc.tcp://x", fs=50.0)
    with pytest.raises(ConfigError, match="fs"):
        MTConnectSource("m1", live_agent.url, fs=0)


# ---------------------------------------------------------------------- OPC UA
NODES = {"x_current": "X.Current", "x_current_ref": "X.CurrentRef", "x_motor_angle": "X.MotorAngle",
         "spindle_speed": "Spindle.Speed"}
UNITS = {"x_current": "mA", "x_motor_angle": "deg", "spindle_speed": "rpm"}


async def _opcua_server(port: int):
    from asyncua import Server, ua

    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/ds/")
    idx = await server.register_namespace("urn:drivesense:test")
    machine = await server.nodes.objects.add_object(idx, "Machine")
    variables = {}
    for name in [*NODES.values(), "X.CurrentBlock"]:
        initial = [0.0] * 10 if name.endswith("Block") else 0.0
        variables[name] = await machine.add_variable(ua.NodeId(name, idx), name, initial)
    await server.start()
    return server, idx, variables


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _distinct_writes(chunks: list[Chunk]) -> int:
    """How many of the writer's counter values the X current [A] of these chunks holds."""
    cur = [c.arrays["x_current"] for c in chunks]
    return np.unique(np.round((np.concatenate(cur) - 1.0) * 1000)).size if cur else 0


def _block_samples(chunks: list[Chunk]) -> int:
    """How many written (non-zero) samples of the block channel these chunks pass on."""
    return sum(int(np.count_nonzero(c.arrays["x_current"] > 0)) for c in chunks)


def test_opcua_source_samples_holds_reconnects_and_passes_blocks():
    pytest.importorskip("asyncua")
    port = _free_port()
    url = f"opc.tcp://127.0.0.1:{port}/ds/"
    written: list[int] = []
    got: list = []
    blocks: list = []

    async def writer(variables):
        k = 0
        while True:                                       # the server's address space lives on while it is down
            await variables["X.Current"].write_value(1000.0 + k)          # mA
            await variables["X.CurrentRef"].write_value(1.0 + k / 1000)   # A
            await variables["X.MotorAngle"].write_value(float(k))         # deg
            await variables["Spindle.Speed"].write_value(6000.0)          # rpm
            if k % 2 == 0:                                                # 10 samples per 20 ms at 500 Hz
                await variables["X.CurrentBlock"].write_value([float(5 * k + i) for i in range(10)])
            written.append(k)
            k += 1
            await asyncio.sleep(0.01)

    async def main():
        server, idx, variables = await _opcua_server(port)   # ~5-10 s: asyncua builds its standard address space
        nodes = {ch: f"ns={idx};s={name}" for ch, name in NODES.items()}
        src = OPCUASource("m1", url, nodes, fs=200.0, units=UNITS, chunk_s=0.05)
        block_src = OPCUASource("m1", url, {"x_current": f"ns={idx};s=X.CurrentBlock"}, fs=500.0, chunk_s=0.05)
        write = asyncio.create_task(writer(variables))
        stop = asyncio.Event()

        async def put(item):
            got.append(item)

        async def put_block(item):
            blocks.append(item)

        task = asyncio.create_task(src.run(put, stop))
        block_task = asyncio.create_task(block_src.run(put_block, stop))
        # the first run goes on until it has sampled many writes and passed many block samples (as long as
        # that takes on a busy machine: the writer and the source share the loop)
        await _until(lambda: len(got) >= 15 and _distinct_writes(got) > 50 and _block_samples(blocks) >= 300, 60)
        last_written = written[-1]                         # the second run samples only later writes
        await server.stop()                                # the server goes away: run() raises
        with pytest.raises((ConnectionError, OSError, asyncio.TimeoutError)):
            await asyncio.wait_for(task, 8)
        with pytest.raises((ConnectionError, OSError, asyncio.TimeoutError)):
            await asyncio.wait_for(block_task, 8)
        n_first = len(got)                                 # the first run's chunks: it emits until it sees the loss
        assert not src.describe()["connected"] and src.describe()["connects"] == 1
        await asyncio.sleep(0.2)
        await server.start()                               # back on the same port
        task = asyncio.create_task(src.run(put, stop))
        await _until(lambda: len(got) >= n_first + 5, 60)
        stop.set()
        await asyncio.wait_for(task, 60)
        write.cancel()
        await server.stop()
        assert src.describe()["connects"] == 2 and src.describe()["outage_s"] > 0.2
        return n_first, last_written

    n_first, last_written = asyncio.run(main())
    assert n_first >= 15
    arrays = _check_stream(got, set(NODES), 200.0)     # seq and t0 continue across the reconnection
    cur = arrays["x_current"]
    k = np.round((cur - 1.0) * 1000).astype(int)       # mA -> A: back to the counter written
    np.testing.assert_allclose(cur, 1.0 + k / 1000, atol=1e-9)
    assert set(k) <= set(written)
    first_run = k[:sum(c.n for c in got[:n_first])]
    assert np.all(np.diff(first_run) >= 0) and first_run[-1] >= last_written - 40   # tracks the writes
    assert len(set(first_run)) > 50                    # many distinct writes, held between them
    assert np.all(k[first_run.size:] >= last_written) and np.all(np.diff(k[first_run.size:]) >= 0)
    np.testing.assert_allclose(arrays["x_current_ref"], 1.0 + k / 1000, atol=2e-3)   # sampled alike (+-1 write)
    np.testing.assert_allclose(arrays["spindle_speed"][-100:], 6000 * 2 * np.pi / 60)
    deg = np.degrees(arrays["x_motor_angle"])
    assert np.all(np.abs(deg - k) <= 2)
    # the block channel: its samples passed on exactly, in order, none twice
    block = _check_stream(blocks, {"x_current"}, 500.0)["x_current"]
    nz = block[block > 0]
    assert nz.size >= 300 and np.all(np.diff(nz) == 1)


def test_opcua_source_refuses_bad_configs():
    with pytest.raises(ConfigError, match="opc.tcp"):
        OPCUASource("m1", "http://x", {"x_current": "ns=2;s=X"}, fs=100.0)
    with pytest.raises(ConfigError, match="expects a current unit"):
        OPCUASource("m1", "opc.tcp://h:4840", {"x_current": "ns=2;s=X"}, fs=100.0, units={"x_current": "mm"})
    with pytest.raises(ConfigError, match="units only channels with a node"):
        OPCUASource("m1", "opc.tcp://h:4840", {"x_current": "ns=2;s=X"}, fs=100.0, units={"y_current": "A"})
    with pytest.raises(ConfigError, match="not a drivesense channel"):
        OPCUASource("m1", "opc.tcp://h:4840", {"temperature": "ns=2;s=T"}, fs=100.0)
    with pytest.raises(ConfigError, match="fs"):
        OPCUASource("m1", "opc.tcp://h:4840", {"x_current": "ns=2;s=X"}, fs=-1)


def test_opcua_source_codes_the_nc_context():
    """A controller's execution state by name (or a LocalizedText), its feed override in percent, a program name."""
    src = OPCUASource("m1", "opc.tcp://127.0.0.1:4840", {"execution": "ns=2;s=E", "feed_override": "ns=2;s=F",
                                                          "program_number": "ns=2;s=P"},
                      fs=100.0, units={"feed_override": "%"})
    src._by_node = {"ns=2;s=E": "execution", "ns=2;s=F": "feed_override", "ns=2;s=P": "program_number"}
    src.notify("ns=2;s=E", "FEED_HOLD")
    src.notify("ns=2;s=E", type("LocalizedText", (), {"Text": "ACTIVE"})())
    src.notify("ns=2;s=F", 80.0)
    src.notify("ns=2;s=P", "PART_A.MPF")
    src.notify("ns=2;s=E", "RUNNING")                  # not a state: counted as bad, the last value holds
    values = {c: [v for _, v in pts] for c, pts in src._points.items()}
    assert values["execution"] == [3.0, 1.0] and values["feed_override"] == [0.8]
    assert values["program_number"] == [program_code("PART_A.MPF")] and src.bad == 1


# ---------------------------------------------------------------------- SHDR (an adapter, no agent)
class Adapter:
    """An MTConnect adapter on loopback: X current [A], the path's execution state, line and feed override [%]
    every 10 ms of its clock; answers ``* PING`` with ``* PONG``."""

    def __init__(self) -> None:
        self.k, self.pings, self.server, self.writers = 0, 0, None, []

    def line(self) -> bytes:
        t = BASE_US + self.k * STEP_US
        state = "FEED_HOLD" if 120 <= self.k < 150 else "ACTIVE"
        text = (f"{_iso(t)}|Xamp|{2.0 + 0.001 * self.k!r}|exec|{state}|line|{10 + self.k // 50}"
                f"|Fovr|{100 if self.k < 200 else 80}|spare|1.5\n")
        self.k += 1
        return text.encode()

    async def handle(self, reader, writer):
        self.writers.append(writer)

        async def answer():
            while line := await reader.readline():
                if line.strip() == b"* PING":
                    self.pings += 1
                    writer.write(b"* PONG 10000\n")
        task = asyncio.create_task(answer())
        try:
            while True:
                writer.write(b"".join(self.line() for _ in range(3)))   # 30 ms of the adapter's clock
                await writer.drain()
                await asyncio.sleep(0.01)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            task.cancel()


def test_shdr_source_reads_an_adapter_with_the_nc_context():
    from drivesense.monitor.shdr import SHDRSource

    port = _free_port()
    got: list = []
    adapter = Adapter()

    async def main():
        server = await asyncio.start_server(adapter.handle, "127.0.0.1", port)
        src = SHDRSource("m1", f"shdr://127.0.0.1:{port}", fs=100.0, interval_s=0.05,
                         channels={"Xamp": "x_current", "exec": "execution", "line": "block_number",
                                   "Fovr": "feed_override"}, units={"feed_override": "%"})
        stop = asyncio.Event()

        async def put(item):
            got.append(item)
            if sum(c.n for c in got if isinstance(c, Chunk)) >= 300:
                stop.set()

        await asyncio.wait_for(src.run(put, stop), 30)
        server.close()
        return src

    src = asyncio.run(main())
    arrays = _check_stream([c for c in got if isinstance(c, Chunk)], {"x_current", "execution", "block_number",
                                                                       "feed_override"}, 100.0)
    k = np.round((arrays["x_current"] - 2.0) * 1000).astype(int)       # the adapter's report counter
    np.testing.assert_allclose(arrays["x_current"], 2.0 + 0.001 * k, atol=1e-9)
    np.testing.assert_array_equal(arrays["block_number"], 10 + k // 50)          # held, never interpolated
    np.testing.assert_array_equal(arrays["execution"], np.where((k >= 120) & (k < 150), 3.0, 1.0))
    np.testing.assert_allclose(arrays["feed_override"], np.where(k < 200, 1.0, 0.8))
    info = src.describe()
    assert info["kind"] == "shdr" and info["connects"] == 1 and info["bad_lines"] == 0 and "spare" in info["ignored"]
    assert adapter.pings >= 1


def test_shdr_source_refuses_bad_configs():
    from drivesense.monitor.shdr import SHDRSource

    with pytest.raises(ConfigError, match="shdr://host:port"):
        SHDRSource("m1", "http://h:7878", fs=100.0, channels={"a": "x_current"})
    with pytest.raises(ConfigError, match="needs 'channels'"):
        SHDRSource("m1", "shdr://h:7878", fs=100.0, channels={})
    with pytest.raises(ConfigError, match="expects a current unit|current"):
        SHDRSource("m1", "shdr://h:7878", fs=100.0, channels={"a": "x_current"}, units={"x_current": "mm"})
