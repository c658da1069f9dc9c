"""Monitor workers sharing machines through a real mosquitto: ownership, claims, held acknowledgements.

The whole failover (3 worker processes, one killed with SIGKILL, events checked against an uninterrupted
reference) runs in ``tests/test_bench_fleet.py`` through the quick bench.  Here: the pieces it rests on,
each against the real thing (a broker, file locks, the CLI).  With CI=true nothing here skips.
"""

from __future__ import annotations

import asyncio
import json
import os
import time

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.monitor.fleet import FleetWorker, MachineClaim, Membership, owner_of
from drivesense.monitor.mqtt import MQTTSource
from drivesense.monitor.outputs import EventLog
from drivesense.monitor.wire import encode_chunk

pytest.importorskip("paho.mqtt.client") if os.environ.get("CI") != "true" else None


def test_every_machine_has_one_owner_and_a_leaving_worker_moves_only_its_own():
    machines = [f"m{i:03d}" for i in range(300)]
    three = {m: owner_of(m, ["w1", "w2", "w3"]) for m in machines}
    assert set(three.values()) == {"w1", "w2", "w3"}
    assert min(list(three.values()).count(w) for w in ("w1", "w2", "w3")) > 60      # spread, not piled up
    assert three == {m: owner_of(m, ["w3", "w1", "w2"]) for m in machines}          # order of the list: none
    two = {m: owner_of(m, ["w1", "w3"]) for m in machines}
    assert all(two[m] == three[m] for m in machines if three[m] != "w2")            # only w2's machines move
    assert owner_of("m000", []) is None


def test_a_claim_is_exclusive_and_hands_over_its_mark(tmp_path):
    async def main():
        a = MachineClaim(tmp_path, "vmc/1", "a")
        await a.acquire()
        assert a.prime_through is None and a.previous is None
        a.log.append({"id": "vmc/1/breakage/x/1", "machine": "vmc/1", "kind": "breakage"})
        a.mark(41)
        b = MachineClaim(tmp_path, "vmc/1", "b")
        with pytest.raises(asyncio.TimeoutError):
            await asyncio.wait_for(b.acquire(), 0.3)                # a holds the lock
        a.release(57)                                               # the newest chunk handled: marked
        await asyncio.wait_for(b.acquire(), 5.0)
        assert (b.prime_through, b.previous) == (57, "a")
        assert b.log.ids == {"vmc/1/breakage/x/1"}                  # the audit lines are no events
        assert b.log.append({"id": "vmc/1/breakage/x/1", "machine": "vmc/1", "kind": "breakage"}) is None
        b.release(None)
    asyncio.run(main())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["vmc%2F1.claim", "vmc%2F1.jsonl"]
    lines = [json.loads(x) for x in (tmp_path / "vmc%2F1.jsonl").read_text().splitlines()]
    assert [next(k for k in ("claim", "released", "id") if k in x) for x in lines] == [
        "claim", "id", "released", "claim", "released"]
    assert EventLog(tmp_path / "vmc%2F1.jsonl").recovered == 1


def _chunk(seq: int) -> bytes:
    return encode_chunk("m1", seq, seq * 0.05, 1e4, {"x_current": np.zeros(500)})


def test_held_chunks_go_to_the_next_holder_of_the_session(mosquitto):
    """Processed chunks stay unacknowledged for hold_s of signal; the next holder of the machine's session gets
    them again (the re-priming), then what was never delivered."""
    import paho.mqtt.client as mqtt

    async def consume(n: int, hold_s: float, marked: int) -> tuple[list, MQTTSource]:
        src = MQTTSource("m1", mosquitto.url, client_id="drivesense-m-test-m1", hold_s=hold_s)
        got, stop = [], asyncio.Event()

        async def put(item) -> None:
            got.append(item.seq)
            src.processed()
            src.settle(min(item.seq, marked))
            if len(got) >= n:
                stop.set()
        await asyncio.wait_for(src.run(put, stop), 30.0)
        return got, src

    async def first_connect() -> None:                        # the session exists before anything is sent
        src = MQTTSource("m1", mosquitto.url, client_id="drivesense-m-test-m1", hold_s=1.0)
        stop = asyncio.Event()
        task = asyncio.create_task(src.run(lambda item: None, stop))
        for _ in range(100):
            if src.connected:
                break
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.3)
        stop.set()
        await task
    asyncio.run(first_connect())
    pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-pub")
    pub.connect("127.0.0.1", mosquitto.port)
    pub.loop_start()
    for seq in range(60):                                     # 3 s of signal
        pub.publish("m1/drive", _chunk(seq), qos=1).wait_for_publish(5)
    got, src = asyncio.run(consume(40, hold_s=1.0, marked=35))
    assert got == list(range(40))
    # acknowledged: up to the mark (35) and 1 s of signal before the newest processed (39 -> seq <= 19)
    time.sleep(0.3)
    again, _ = asyncio.run(consume(40, hold_s=1.0, marked=10**6))
    assert again == list(range(20, 60))                       # the held 20..39, then the 20 never delivered
    pub.loop_stop()
    pub.disconnect()


def test_workers_see_each_other_and_a_name_in_use_is_refused(mosquitto):
    async def main():
        loop = asyncio.get_running_loop()
        a = Membership(loop, mosquitto.url, "t", "w1")
        b = Membership(loop, mosquitto.url, "t", "w2")
        for _ in range(100):
            if a.live() == {"w1", "w2"} == b.live():
                break
            await asyncio.sleep(0.05)
        assert a.live() == {"w1", "w2"} == b.live()
        b.close()                                              # leaving clears its presence
        for _ in range(100):
            if a.live() == {"w1"}:
                break
            await asyncio.sleep(0.05)
        assert a.live() == {"w1"}
        twin = Membership(loop, mosquitto.url, "t", "w1")      # a second worker named w1
        for _ in range(100):
            if a.conflict or twin.conflict:
                break
            await asyncio.sleep(0.05)
        assert "worker name 'w1' is in use" in (a.conflict or twin.conflict)
        a.close()
        twin.close()
    asyncio.run(main())


def test_fleet_worker_refuses_what_it_cannot_share(tmp_path):
    from drivesense.monitor import MachineSpec, MonitorService
    from drivesense.monitor.sources import SimulatedSource

    with pytest.raises(ConfigError, match="--worker"):
        FleetWorker("w/1", tmp_path)
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="must be a folder"):
        FleetWorker("w1", tmp_path / "file")
    from drivesense.monitor.demo import demo_machine

    spec = demo_machine(speed=0.0)
    assert isinstance(spec.source, SimulatedSource)
    with pytest.raises(ConfigError, match=f"machine '{spec.id}' has a simulated source"):
        MonitorService([spec], fleet=FleetWorker("w1", tmp_path / "events"))
    two = [MachineSpec(f"m{i}", MQTTSource(f"m{i}", f"mqtt://127.0.0.1:{1883 + i}"), spec.monitor) for i in (0, 1)]
    with pytest.raises(ConfigError, match="2 brokers"):
        MonitorService(two, fleet=FleetWorker("w1", tmp_path / "events"))


def test_monitor_cli_worker_needs_an_events_folder(tmp_path):
    from typer.testing import CliRunner

    from drivesense.cli import app

    runner = CliRunner()
    assert runner.invoke(app, ["axis", "--out", str(tmp_path / "AXIS.toml")]).exit_code == 0
    cfg = tmp_path / "plant.toml"
    cfg.write_text('[[machine]]\nid = "m1"\nsource = { kind = "mqtt", url = "mqtt://127.0.0.1:1" }\n'
                   '[[machine.axis]]\nname = "x"\nmethod = "rigid"\naxis_file = "AXIS.toml"\n')
    res = runner.invoke(app, ["monitor", str(cfg), "--worker", "w1"])
    assert res.exit_code == 2 and "--worker needs --events FOLDER" in res.output, res.output
    res = runner.invoke(app, ["monitor", "--demo", "--worker", "w1", "--events", str(tmp_path / "ev")])
    assert res.exit_code == 2 and "has a simulated source; workers share only machines on mqtt" in res.output


def test_a_machine_taken_over_mid_stream_raises_the_uninterrupted_runs_events():
    """The re-priming rule itself, without a broker: a fresh monitor replays from HOLD_S before the last
    worker's mark (or from where a detector's memory begins, the breakage detector's cut start), quietly up
    to the mark; from there on its events are the uninterrupted run's, id for id."""
    from drivesense.monitor.demo import demo_machine
    from drivesense.monitor.fleet import HOLD_S
    from drivesense.monitor.machine import MachineMonitor
    from drivesense.monitor.sources import SimulatedSource
    from drivesense.monitor.wire import Chunk

    axes = demo_machine(speed=0.0).monitor.axes
    sim = SimulatedSource("m1", seed=11, cut_s=4.0, event_share=1.0)     # cuts with breakage, chipping, collision
    cuts = [sim.simulate_cut(k) for k in range(5)]
    chans = [c for c in cuts[0].channels if not c.startswith("force_")]
    signal = {c: np.concatenate([r[c] for r in cuts]) for c in chans}
    n, fs = 500, cuts[0].fs
    chunks = [Chunk("m1", k, k * n / fs, fs, {c: v[k * n:(k + 1) * n] for c, v in signal.items()})
              for k in range(len(signal[chans[0]]) // n)]
    ref, ref_ids, keep = MachineMonitor("m1", axes), [], []
    for c in chunks:
        ref_ids.append([r["id"] for r in ref.process(c)])
        keep.append(ref.replay_from())
    assert sum(map(len, ref_ids)) >= 4
    for mark in range(30, len(chunks) - 20, 23):
        start = mark - int(HOLD_S * fs / n) + 1
        if keep[mark] is not None:                       # in a cut: from before its start
            start = min(start, int(keep[mark] * fs / n))
        fresh = MachineMonitor("m1", axes)
        got = [r["id"] for k in range(max(0, start), len(chunks)) for r in fresh.process(chunks[k], emit=k > mark)]
        assert got == [i for k in range(mark + 1, len(chunks)) for i in ref_ids[k]], mark


def test_the_breakage_detector_replayed_from_before_a_cut_gives_the_same_statistic():
    """Exactly 100 samples per revolution (6000 min^-1 at 10 kHz): a spindle angle counted from the start of
    the stream put the revolution boundaries on a knife's edge of rounding, so a stream started later (a worker
    that took the machine over) drifted from the uninterrupted one.  Counted from each cut's start, a stream
    started anywhere before the cut gives the same statistic, sample for sample."""
    from drivesense.events.breakage import BreakageDetector

    fs, w = 1e4, 2 * np.pi * 100.0
    t = np.arange(int(22 * fs)) / fs
    cutting = (t % 11.0) > 3.0                                   # 3 s air, 8 s cut; twice
    rng = np.random.default_rng(3)
    force = cutting * (40 + 25 * np.sin(2 * w * t) + 6 * np.sin(w * t + 0.4) + rng.normal(0, 0.5, t.size))
    arrays = {"force_x": force, "spindle_speed": np.full(t.size, w), "feed_speed": np.full(t.size, 0.01)}
    det = BreakageDetector("x", teeth=2, spindle_rpm=6000.0)

    def run(start: int) -> np.ndarray:
        stream, out = det.stream(fs, t0=start / fs), []
        for k in range(start, t.size, 500):
            out.append(stream.push_arrays({c: v[k:k + 500] for c, v in arrays.items()}).statistic)
        return np.concatenate(out)
    whole = run(0)
    second_cut = slice(int(14.5 * fs), t.size)                 # the second cut, after its first revolutions
    for start in (int(12.0 * fs), int(13.2 * fs)):              # started in the air before it
        late = run(start)
        a, b = whole[second_cut], late[second_cut.start - start:]
        assert np.isfinite(a).sum() > 1000
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12, equal_nan=True)


def test_a_claim_that_cannot_read_the_machines_log_is_shown_and_retried(tmp_path, monkeypatch):
    import drivesense.monitor.fleet as fleet
    from drivesense.monitor import MachineSpec

    monkeypatch.setattr(fleet, "CLAIM_RETRY_S", 0.05)
    (tmp_path / "m1.jsonl").write_text("not json\n")               # a log that is no drivesense event log
    worker = FleetWorker("w1", tmp_path)
    spec = MachineSpec("m1", MQTTSource("m1", "mqtt://127.0.0.1:1"), None)

    async def main():
        task = asyncio.create_task(worker._hold(None, spec))
        for _ in range(100):
            if spec.state == "error":
                break
            await asyncio.sleep(0.02)
        assert spec.state == "error" and "claim failed: ConfigError" in spec.source_error, spec.source_error
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        assert spec.state == "standby"
        b = MachineClaim(tmp_path, "m1", "w2")                       # the lock was let go
        with pytest.raises(ConfigError, match="not a JSON record"):
            await asyncio.wait_for(b.acquire(), 2.0)
    asyncio.run(main())
