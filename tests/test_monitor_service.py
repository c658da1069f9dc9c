"""The live monitor's core: the wire format, one machine's pipeline, the event log, the service and its CLI.

The signals are the simulator's ball-screw cuts with a known flute breakage; the detectors' own accuracy is
tested elsewhere (test_events_detectors.py): here the service must deliver the same events a batch run finds,
once each, whatever the chunking, the bad messages or a restart.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.monitor import (Chunk, MachineSpec, MonitorService, ReplaySource, WireError,
                              decode_chunk, encode_chunk)
from drivesense.monitor.machine import FeedSpeedStream, Ring
from drivesense.monitor.outputs import EventLog


@pytest.fixture(scope="module")
def breakage_cut():
    """A 4 s demo cut whose flute breaks at about 2.16 s (the demo's second cut)."""
    from drivesense.monitor.sources import SimulatedSource

    rec = SimulatedSource("m", cut_s=4.0).simulate_cut(1)
    assert [e["kind"] for e in rec.meta["truth"]["events"]] == ["breakage"]
    return rec


@pytest.fixture(scope="module")
def files(tmp_path_factory, breakage_cut):
    """cut.nc, three idle runs and AXIS.toml in one folder (what a user has for --replay)."""
    from dataclasses import replace

    from typer.testing import CliRunner

    from drivesense.cli import app
    from drivesense.io import write_recording
    from drivesense.monitor.sources import demo_condition
    from drivesense.sim.scenarios import ScenarioSettings, simulate_idle

    folder = tmp_path_factory.mktemp("monitor")
    write_recording(breakage_cut, folder / "cut.nc")
    for i, r in enumerate(simulate_idle(demo_condition(), replace(ScenarioSettings(), duration=6.0), seed=5000)):
        write_recording(r, folder / f"idle{i}.nc")
    assert CliRunner().invoke(app, ["axis", "--out", str(folder / "axis.toml")]).exit_code == 0
    return folder


def _chunks(rec, machine="m", n=500):
    return [Chunk(machine, k, rec.t0 + i / rec.fs, rec.fs, {c: rec[c][i:i + n] for c in rec.channels})
            for k, i in enumerate(range(0, rec.n_samples, n))]


# ----------------------------------------------------------------------------------------------- wire
def test_wire_round_trip_converts_units_to_si():
    arrays = {"x_table_position": np.array([1.0, 2.0, 3.0]), "x_current": np.array([0.5, 0.25, 0.0])}
    msg = encode_chunk("vmc1", 7, 1.5, 1000.0, arrays, {"x_table_position": "mm"}, sent=10.0)
    chunk = decode_chunk(msg, arrival=11.0)
    assert (chunk.machine, chunk.seq, chunk.t0, chunk.fs, chunk.n, chunk.sent) == ("vmc1", 7, 1.5, 1000.0, 3, 10.0)
    np.testing.assert_allclose(chunk.arrays["x_table_position"], [1e-3, 2e-3, 3e-3])
    np.testing.assert_array_equal(chunk.arrays["x_current"], arrays["x_current"])


@pytest.mark.parametrize("mutate, words", [
    (lambda m: b"XXXX" + m[4:], "magic"),
    (lambda m: m[:8] + b"{not json" + m[17:], "header"),
    (lambda m: m[:-8], "data bytes"),
    (lambda m: m[:-8] + np.array([np.nan]).tobytes(), "NaN"),
    (lambda m: b"DSC1", "magic"),
])
def test_wire_refuses_garbage_naming_the_problem(mutate, words):
    msg = encode_chunk("vmc1", 0, 0.0, 1000.0, {"x_current": np.arange(4.0)})
    with pytest.raises(WireError, match=words):
        decode_chunk(mutate(msg))
    with pytest.raises(ValueError):                          # the hierarchy subclasses the built-ins
        decode_chunk(mutate(msg))


def test_wire_refuses_a_unit_that_does_not_fit_the_channel():
    msg = encode_chunk("vmc1", 0, 0.0, 1000.0, {"x_table_position": np.arange(4.0)}, {"x_table_position": "A"})
    with pytest.raises(WireError, match="x_table_position"):
        decode_chunk(msg)


# ----------------------------------------------------------------------------------------------- pieces
def test_ring_keeps_the_newest_samples_in_fixed_memory():
    ring = Ring(5)
    for k in range(4):
        ring.extend(np.arange(3.0) + 3 * k)
    np.testing.assert_array_equal(ring.last(5), [7, 8, 9, 10, 11])
    np.testing.assert_array_equal(ring.last(2), [10, 11])
    ring.extend(np.arange(100.0))
    np.testing.assert_array_equal(ring.last(5), [95, 96, 97, 98, 99])
    assert ring.written == 112


def test_feed_speed_stream_is_chunking_invariant_and_right_on_a_ramp():
    fs = 1000.0
    p = 0.002 * np.arange(2000) / fs                          # 2 mm/s
    whole = FeedSpeedStream(fs).push({"x_table_position": p})
    stream = FeedSpeedStream(fs)
    parts = np.concatenate([stream.push({"x_table_position": p[i:i + 37]}) for i in range(0, p.size, 37)])
    np.testing.assert_allclose(parts, whole, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(whole[100:], 0.002, rtol=1e-9)


# ----------------------------------------------------------------------------------------------- one machine
def test_machine_finds_the_breakage_and_survives_bad_chunks(breakage_cut):
    from drivesense.monitor.demo import demo_monitor

    truth = breakage_cut.meta["truth"]["events"][0]["time_s"]
    clean = demo_monitor("m")
    records = [r for c in _chunks(breakage_cut) for r in clean.process(c)]
    assert [r["kind"] for r in records] == ["breakage"]
    rev = 60.0 / 6000.0
    assert 0 <= records[0]["time_s"] - truth <= 2 * rev
    assert records[0]["id"] == f"m/breakage/x/{int(round(records[0]['time_s'] * 1e6))}"

    noisy = demo_monitor("m")
    chunks = _chunks(breakage_cut)
    bad_nan = Chunk("m", 5, 0.0, 1e4, {c: np.full(500, np.nan) for c in breakage_cut.channels})
    out = []
    for k, c in enumerate(chunks):
        if k == 5:
            out += noisy.process(bad_nan)                      # NaN: refused, the seq stays free
        out += noisy.process(c)
        if k == 10:
            out += noisy.process(c)                            # repeated
            out += noisy.process(chunks[3])                    # out of order
            out += noisy.process(Chunk("other", 99, 0.0, 1e4, c.arrays))
            out += noisy.process(Chunk("m", 98, 0.0, 5e3, c.arrays))      # another rate
    assert [r["id"] for r in out] == [r["id"] for r in records]
    st = noisy.status()
    assert st["rejected"] == 5 and st["gaps"] == 0 and st["samples"] == breakage_cut.n_samples
    assert "rate" in st["last_error"] or "Hz" in st["last_error"]


def test_machine_counts_a_gap_and_keeps_going(breakage_cut):
    from drivesense.monitor.demo import demo_monitor

    mon = demo_monitor("m")
    chunks = _chunks(breakage_cut)
    for c in chunks[:10] + chunks[12:]:
        mon.process(c)
    assert mon.gaps == 2 and mon.rejected == 0
    hist = mon.force_history(1.0, max_points=200)
    assert len(hist["t"]) == len(hist["force_x"]) <= 200 and all(math.isfinite(v) for v in hist["force_x"])
    spec = mon.spectrum("x")
    peak = spec["f"][int(np.argmax(spec["amplitude"][1:])) + 1]
    assert abs(peak / 100.0 - round(peak / 100.0)) < 0.05      # spindle harmonics (6000 min^-1 = 100 Hz; a flute
    assert round(peak / 100.0) >= 1                            # is broken: the once-per-revolution line)


def test_segments_hold_the_signal_around_each_event(breakage_cut):
    from drivesense.monitor.demo import demo_monitor

    mon = demo_monitor("m")
    for c in _chunks(breakage_cut):
        mon.process(c)
    [(record, segment)] = mon.take_segments()
    seg = segment.recording()
    assert seg.meta["event_id"] == record["id"]
    assert seg.t0 <= record["time_s"] - 0.99 and seg.t0 + seg.duration >= record["time_s"] + 0.49
    assert {"force_x", "x_current_ref", "spindle_speed"} <= set(seg.channels)
    start = int(round((seg.t0 - breakage_cut.t0) * breakage_cut.fs))
    np.testing.assert_array_equal(seg["x_current_ref"], breakage_cut["x_current_ref"][start:start + seg.n_samples])


def test_force_limit_changes_while_running():
    from drivesense.monitor.demo import demo_monitor

    mon = demo_monitor("m")
    mon.set_force_limit("x", 123.0)
    assert mon.limits() == {"x": 123.0}
    with pytest.raises(ConfigError, match="axis 'q'"):
        mon.set_force_limit("q", 1.0)
    with pytest.raises(ConfigError, match="positive"):
        mon.set_force_limit("x", float("nan"))


# ----------------------------------------------------------------------------------------------- event log
def test_event_log_fsyncs_recovers_a_torn_line_and_refuses_repeats(tmp_path):
    path = tmp_path / "ev.jsonl"
    log = EventLog(path)
    a = log.append({"id": "m/b/x/1", "machine": "m", "kind": "breakage"})
    assert a["seq"] == 1 and log.append({"id": "m/b/x/1", "machine": "m", "kind": "breakage"}) is None
    log.acknowledge("m/b/x/1", "op")
    log.close()
    with open(path, "ab") as fh:
        fh.write(b'{"id": "m/b/x/2", "mach')                    # a kill in the middle of a write
    again = EventLog(path)
    assert again.recovered == 1 and again.seq == 1
    assert again.since(0)[0]["acknowledged"] is True
    b = again.append({"id": "m/b/x/2", "machine": "m", "kind": "breakage"})
    assert b["seq"] == 2
    again.close()
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    assert [x.get("id", x.get("ack")) for x in lines] == ["m/b/x/1", "m/b/x/1", "m/b/x/2"]
    with pytest.raises(KeyError, match="no event"):
        EventLog(path).acknowledge("nope")



def test_event_log_line_is_readable_at_once_and_synced_by_the_syncer(tmp_path):
    path = tmp_path / "ev.jsonl"
    log = EventLog(path)
    for k in range(50):
        log.append({"id": f"m/b/x/{k}", "machine": "m", "kind": "breakage"})
        assert path.read_bytes().count(b"\n") == k + 1        # written before append returns (kill -9 safe)
    assert log.sync(timeout=10.0) and log.synced == log.written == 50
    log.close()
    log.close()                                                  # twice is harmless
    assert len(EventLog(path).ids) == 50


def test_warm_up_leaves_the_machine_untouched():
    from drivesense.monitor.demo import demo_monitor

    mon = demo_monitor("m")
    mon.warm_up()
    assert mon.fs is None and mon.samples == mon.chunks == mon.rejected == 0 and mon.last_seq is None

# ----------------------------------------------------------------------------------------------- service
def _replay_service(rec, tmp_path, **kw):
    from drivesense.monitor.demo import demo_monitor

    spec = MachineSpec("m", ReplaySource("m", rec, speed=0), demo_monitor("m"))
    return MonitorService([spec], events_path=tmp_path / "ev.jsonl", archive=tmp_path / "a.sqlite", **kw)


def test_service_logs_archives_and_never_doubles_after_a_restart(breakage_cut, tmp_path):
    from drivesense.archive import open_archive

    svc = _replay_service(breakage_cut, tmp_path)
    asyncio.run(asyncio.wait_for(svc.run(until_finished=True), 120))
    first = svc.events()
    assert [e["kind"] for e in first] == ["breakage"]
    again = _replay_service(breakage_cut, tmp_path)           # the same samples again: the same event id
    asyncio.run(asyncio.wait_for(again.run(until_finished=True), 120))
    assert [e["id"] for e in again.events()] == [e["id"] for e in first]
    assert again.counts["events_repeated"] == 1
    with open_archive(tmp_path / "a.sqlite") as store:
        archived = store.events()
        assert [e["id"] for e in archived] == [first[0]["id"]]
        seg = store.load(archived[0]["experiment"]).recordings[0]
        assert "force_x" in seg.channels and seg.duration > 1.0
    metrics = again.metrics()
    assert 'drivesense_samples_total{machine="m"} 40000' in metrics
    assert "drivesense_events_total" in metrics


def test_one_failing_source_never_stops_the_others(breakage_cut, tmp_path):
    from drivesense.monitor.demo import demo_monitor
    from drivesense.monitor.sources import Source

    class Broken(Source):
        kind = "broken"
        calls = 0

        async def run(self, put, stop):
            Broken.calls += 1
            raise ConnectionError("controller unreachable")

    good = MachineSpec("m", ReplaySource("m", breakage_cut, speed=0), demo_monitor("m"))
    bad = MachineSpec("bad", Broken("bad"), demo_monitor("bad"))
    svc = MonitorService([good, bad])

    async def main():
        stop = asyncio.Event()
        task = asyncio.create_task(svc.run(stop))
        while not good.source.finished or good.monitor.chunks < 80:
            await asyncio.sleep(0.05)
        await asyncio.sleep(1.2)
        stop.set()
        await task

    asyncio.run(asyncio.wait_for(main(), 120))
    assert [e["kind"] for e in svc.events()] == ["breakage"]
    st = svc.machine_status("bad")
    assert st["restarts"] >= 2 and "controller unreachable" in st["source_error"]


def test_config_errors_name_the_machine_and_the_key(files, tmp_path):
    from drivesense.monitor.config import load_config

    def config(text):
        p = tmp_path / "c.toml"
        p.write_text(text)
        return p

    with pytest.raises(ConfigError, match=r"no \[\[machine\]\]"):
        load_config(config("[service]\n"))
    with pytest.raises(ConfigError, match=r"machine 'a' source: unknown key\(s\) sped"):
        load_config(config('[[machine]]\nid = "a"\nsource = {kind = "simulated", sped = 3}\n'))
    with pytest.raises(ConfigError, match="unknown kind 'ftp'"):
        load_config(config('[[machine]]\nid = "a"\nsource = {kind = "ftp"}\n'))
    with pytest.raises(ConfigError, match=r"machine 'a' axis 'x'.*idle"):
        load_config(config(f'[[machine]]\nid = "a"\nsource = {{kind = "replay", path = "{files}/cut.nc"}}\n'
                           f'[[machine.axis]]\nname = "x"\naxis_file = "{files}/axis.toml"\n'))
    with pytest.raises(ConfigError, match="'force_limit' must be a positive number"):
        load_config(config(f'[[machine]]\nid = "a"\nsource = {{kind = "replay", path = "{files}/cut.nc"}}\n'
                           f'[[machine.axis]]\nname = "x"\naxis_file = "{files}/axis.toml"\n'
                           f'idle = ["{files}/idle0.nc"]\nforce_limit = -3\n'))
    cfg = load_config(config(f'[service]\nevents = "ev.jsonl"\n[[machine]]\nid = "a"\nteeth = 2\n'
                             f'source = {{kind = "replay", path = "{files}/cut.nc", speed = 0}}\n'
                             f'[[machine.axis]]\nname = "x"\naxis_file = "{files}/axis.toml"\n'
                             f'idle = ["{files}/idle0.nc", "{files}/idle1.nc"]\nforce_limit = 400\n'))
    assert cfg.events == tmp_path / "ev.jsonl"
    assert [d.name for d in cfg.machines[0].monitor.axes[0].detectors] == ["breakage", "chatter", "overload"]


# ----------------------------------------------------------------------------------------------- CLI, kill -9
def _monitor_cmd(files, tmp_path, speed):
    return [sys.executable, "-c", "from drivesense.cli import main; main()", "monitor", "--replay",
            str(files / "cut.nc"), "--axis", str(files / "axis.toml"), "--idle", str(files / "idle0.nc"),
            "--idle", str(files / "idle1.nc"), "--force-limit", "400", "--speed", str(speed),
            "--events", str(tmp_path / "ev.jsonl"), "--archive", str(tmp_path / "a.sqlite")]


def test_kill_9_mid_run_loses_no_event_and_doubles_none(files, tmp_path):
    from drivesense.archive import open_archive

    proc = subprocess.Popen(_monitor_cmd(files, tmp_path, 1.0), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    log = tmp_path / "ev.jsonl"
    deadline = time.time() + 90
    while time.time() < deadline and not (log.exists() and log.read_text().strip()):
        time.sleep(0.05)
    assert log.read_text().strip(), proc.communicate()[0].decode()[-2000:]
    os.kill(proc.pid, signal.SIGKILL)                          # right after the breakage was logged
    proc.wait()
    before = [json.loads(x)["id"] for x in log.read_text().splitlines()]
    done = subprocess.run(_monitor_cmd(files, tmp_path, 0), capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 event(s) from before, kept" in done.stdout
    after = [json.loads(x)["id"] for x in log.read_text().splitlines()]
    assert after == before and len(before) == 1
    with open_archive(tmp_path / "a.sqlite") as store:
        assert [e["id"] for e in store.events()] == before


def test_monitor_cli_refuses_what_it_cannot_run(files, tmp_path):
    from typer.testing import CliRunner

    from drivesense.cli import app

    runner = CliRunner()
    res = runner.invoke(app, ["monitor"])
    assert res.exit_code == 2 and "CONFIG.toml, --replay TRACE or --demo" in res.output
    res = runner.invoke(app, ["monitor", "--replay", str(files / "cut.nc"), "--axis", str(files / "axis.toml")])
    assert res.exit_code == 2 and "--idle" in res.output
    res = runner.invoke(app, ["monitor", "--demo", "--http", "localhost"])
    assert res.exit_code == 2 and "HOST:PORT" in res.output


def test_webhook_posts_each_event_and_counts_failures(breakage_cut, tmp_path):
    import http.server
    import threading

    got = []

    class Hook(http.server.BaseHTTPRequestHandler):
        def do_POST(self):
            got.append(json.loads(self.rfile.read(int(self.headers["Content-Length"]))))
            self.send_response(204)
            self.end_headers()

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        svc = _replay_service(breakage_cut, tmp_path, webhook=f"http://127.0.0.1:{server.server_port}/hook")
        asyncio.run(asyncio.wait_for(svc.run(until_finished=True), 120))
        assert [g["kind"] for g in got] == ["breakage"] and got[0]["id"] == svc.events()[0]["id"]
        assert svc.webhook.failed == 0
    finally:
        server.shutdown()
    from drivesense.monitor.outputs import Webhook

    dead = Webhook(f"http://127.0.0.1:{server.server_port}/hook", timeout=0.5)
    dead.offer({"id": "x"})
    dead.close()
    assert dead.failed == 1 and dead.last_error
    with pytest.raises(ConfigError, match="webhook"):
        Webhook("ftp://x")
