"""``drivesense bench monitor``: the live monitor service's throughput, alarm latency, faults and memory.

Machines are the demo's axis X (:func:`~drivesense.monitor.demo.demo_monitor`) fed simulated 10 kHz cuts (an
event per cut after a clean one).  *throughput*: N monitors on one pinned core (CPU per axis-second; baseline:
the estimator alone), then a service of machines replayed at speed 1 on one core (lag, queue, samples due).
*latency*: mosquitto, ``drivesense monitor CONFIG.toml`` with 20 mqtt machines, a real-time publisher, a
subscriber on ``+/alarm``.  *faults*: broker restart, ``kill -9`` and restart, garbage, SIGTERM under load.
*memory*: one machine replaying a 60 s trace 60 times at speed 50, RSS every second.
"""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import psutil

from drivesense.bench.rig import (CLI, close_quietly, end_process, mqtt_client, read_log_lines, run_child,
                                  setup_demo_axis, subscribe_alarms, wait_until, write_config)
from drivesense.monitor.broker import LocalBroker, find_mosquitto, free_port
from drivesense.archive import open_archive
from drivesense.io import write_recording
from drivesense.recording import Recording
from drivesense.monitor.config import load_config
from drivesense.monitor.demo import demo_estimator, demo_monitor
from drivesense.monitor.service import QUEUE_CHUNKS, MachineSpec, MonitorService
from drivesense.monitor.sources import ReplaySource, SimulatedSource
from drivesense.monitor.wire import MAGIC, Chunk, decode_chunk, encode_chunk

__all__ = ["run_monitor_bench", "publisher_traces", "TARGETS", "CUT_S"]

#: The issue's targets.
TARGETS = {"axes_per_core_min": 50, "alarm_p99_ms_max": 5.0, "memory_mb_per_signal_hour_max": 5.0}
#: Length of each simulated cut [s].
CUT_S = 4.0
_SEED = 7


def _trace(seed: int = _SEED, cuts: int = 4, *, event_share: float = 1.0, rotate: int = 0):
    """Simulated demo cuts end to end (the first clean, then events; the later ones rotated), no force channels."""
    src = SimulatedSource("bench", seed=seed, cut_s=CUT_S, event_share=event_share)
    recs = [src.simulate_cut(k) for k in range(cuts)]
    k = rotate % max(1, cuts - 1)
    recs = [recs[0], *recs[1 + k:], *recs[1:1 + k]]
    return Recording.from_arrays({c: np.concatenate([r[c] for r in recs]) for c in recs[0].channels
                                  if not c.startswith("force_")}, fs=recs[0].fs, meta={"name": f"bench seed {seed}"})


def _pin(pid: int, core: int | None) -> set | None:
    """Pin a process to one core (Linux); its former cores, or None where that cannot be done."""
    try:
        before = os.sched_getaffinity(pid)
        os.sched_setaffinity(pid, {core % (os.cpu_count() or 1)})
        return before
    except (AttributeError, OSError, TypeError):
        return None


def _stats_ms(values) -> dict:
    v = np.asarray(values, dtype=float) * 1e3
    return {"count": int(v.size), **{f"p{q}_ms": round(float(np.percentile(v, q)), 3) if v.size else None
                                     for q in (50, 99)}, "max_ms": round(float(v.max()), 3) if v.size else None}


def _cost(n_axes: int, *, chunk_s: float, warm_s: float, measure_s: float, trace) -> dict:
    """CPU [s] per second of signal and axis of N demo monitors fed round-robin (monitor i starts i cuts in), after
    ``warm_s`` [s] each (``warm_s + measure_s`` within the trace); the baseline: the estimator alone on the same
    chunks; decoding them from the wire."""
    fs, n, cn = trace.fs, trace.n_samples, max(1, int(round(chunk_s * trace.fs)))
    n_warm, n_meas = int(round(warm_s / chunk_s)), max(1, int(round(measure_s / chunk_s)))
    cut_n = int(round(CUT_S * fs))
    rolled = [{c: np.roll(trace[c], -k * cut_n) for c in trace.channels} for k in range(max(1, n // cut_n))]
    chunks = [[Chunk(f"m{i}", k, k * cn / fs, fs, {c: v[k * cn:(k + 1) * cn] for c, v in rolled[i % len(rolled)]
                                                   .items()}) for k in range(n_warm + n_meas)] for i in range(n_axes)]
    monitors, events, cpu = [demo_monitor(f"m{i}") for i in range(n_axes)], 0, 0.0
    for k in range(n_warm + n_meas):
        cpu0 = time.process_time()
        for mon, cs in zip(monitors, chunks):
            events += len(mon.process(cs[k])) * (k >= n_warm)
            mon.take_segments()
        cpu += (time.process_time() - cpu0) * (k >= n_warm)
    est, n_base, cpu_est = demo_estimator(), min(n_axes, 4), 0.0
    for i in range(n_base):
        stream = est.stream(fs)
        for k, c in enumerate(chunks[i]):
            t = time.process_time()
            stream.push_arrays(*(c.arrays[name] for name in stream.channel_names))
            cpu_est += (time.process_time() - t) * (k >= n_warm)
    wire, t = [encode_chunk(c.machine, c.seq, c.t0, c.fs, c.arrays) for c in chunks[0][n_warm:]], time.process_time()
    for payload in wire:
        decode_chunk(payload)
    sig = n_meas * cn / fs
    per, est_per, decode_per = cpu / (n_axes * sig), cpu_est / (n_base * sig), (time.process_time() - t) / sig
    return {"axes": n_axes, "chunk_ms": round(chunk_s * 1e3, 3), "signal_s_per_axis": sig, "cpu_s": round(cpu, 4),
            "cpu_s_per_axis_s": per, "axes_per_core": 1 / per, "us_per_chunk": cpu / (n_axes * n_meas) * 1e6,
            "estimator_cpu_s_per_axis_s": est_per, "monitor_over_estimator": per / est_per,
            "wire_decode_cpu_s_per_axis_s": decode_per, "axes_per_core_with_wire_decode": 1 / (per + decode_per),
            "events": events}


def _realtime_child(n: int, seconds: float, chunk_s: float, out: str, core: int | None = 0) -> None:
    """Subprocess: a MonitorService of ``n`` machines replayed at speed 1 for ``seconds``; JSON to ``out``."""
    _pin(0, core)
    traces = [_trace(rotate=r) for r in range(3)]
    _cost(1, chunk_s=chunk_s, warm_s=0.5, measure_s=0.5, trace=traces[0])          # imports, JIT caches
    lags, depth, specs, res = [], [0], [], {}
    for i in range(n):
        spec = MachineSpec(f"m{i}", ReplaySource(f"m{i}", traces[i % 3], speed=1.0, chunk_s=chunk_s, loop=100),
                           demo_monitor(f"m{i}"))

        def process(chunk, _spec=spec, _orig=spec.monitor.process, **kw):
            depth[0] = max(depth[0], _spec.queue.qsize() + 1)
            records = _orig(chunk, **kw)
            lags.append(time.time() - chunk.arrival)
            return records
        spec.monitor.process = process
        specs.append(spec)

    async def main() -> None:
        stop, service = asyncio.Event(), MonitorService(specs)
        task = asyncio.create_task(service.run(stop))
        while service.sources_started is None:        # the clock starts with the sources (after the warm-up)
            await asyncio.sleep(0.001)
        t0, c0 = time.time(), time.process_time()
        await asyncio.sleep(seconds)
        el = time.time() - t0
        res.update(elapsed_s=el, cpu_s=time.process_time() - c0, queue_max_seen=depth[0], lag=_stats_ms(lags),
                   due_samples=n * max(0, int(el / chunk_s) - 1) * specs[0].source.chunk_n,  # the last in flight
                   processed_samples=sum(s.monitor.samples for s in specs),
                   rejected=sum(s.monitor.rejected for s in specs))
        stop.set()
        await task
    asyncio.run(main())
    share, full = res["processed_samples"] / max(1, res["due_samples"]), res["queue_max_seen"] >= QUEUE_CHUNKS
    Path(out).write_text(json.dumps({**res, "machines": n, "chunk_ms": chunk_s * 1e3, "queue_chunks": QUEUE_CHUNKS,
                                     "cpu_share_of_core": res["cpu_s"] / res["elapsed_s"], "processed_share": share,
                                     "queue_never_full": not full, "keeps_up": share >= 0.99 and not full}))


def _throughput(work: Path, *, quick: bool, n_axes: int | None = None, realtime_axes: int | None = None) -> dict:
    """The throughput part: steady-state cost at 50 and 10 ms chunks on core 0, then the real-time run."""
    n, (warm, meas) = n_axes or (10 if quick else 50), ((1.0, 2.0) if quick else (2.0, 8.0))
    before = _pin(0, 0)
    try:
        trace = _trace(cuts=4)
        steady = {f"chunk_{c * 1e3:g}ms": _cost(n, chunk_s=c, warm_s=warm, measure_s=m, trace=trace)
                  for c, m in ((0.05, meas), (0.01, meas / 2))}
    finally:
        if before is not None:
            os.sched_setaffinity(0, before)
    apc = steady["chunk_50ms"]["axes_per_core"]
    rt = run_child("realtime", {"n": realtime_axes or max(1, min(50, int(apc * 0.8))),
                                "seconds": 5.0 if quick else 20.0, "chunk_s": 0.05}, work, 0, 600.0)
    return {"pinned_to_one_core": before is not None, "steady_state": steady, "axes_per_core": apc,
            "baseline": "the estimator alone on the same chunks (CPU per axis-second)",
            "monitor_over_estimator": steady["chunk_50ms"]["monitor_over_estimator"], "realtime": rt}


def publisher_traces(machines: list) -> dict:
    """The recordings the publisher plays, by machine: one simulated trace, machine i from i * 1.2 s on.

    Parameters
    ----------
    machines : list of str
        Machine ids, in the publisher's order.
    """
    base = _trace(_SEED + 1, 6)
    return {m: Recording.from_arrays({c: np.roll(base[c], -i * 12007) for c in base.channels}, fs=base.fs)
            for i, m in enumerate(machines)}


def _publish_child(url: str, machines: list, seconds: float, out: str, core: int | None = None) -> None:
    """Subprocess: each machine's event cuts published at real time in 50 ms chunks, starts spread evenly."""
    _pin(0, core)
    traces = publisher_traces(machines)
    client, sent = mqtt_client(url, "publish", None, False), dict.fromkeys(machines, 0)

    async def play(i: int, mid: str, stop: asyncio.Event) -> None:
        async def put(c) -> None:
            client.publish(f"{mid}/drive", encode_chunk(mid, c.seq, c.t0, c.fs, c.arrays), qos=1)
            sent[mid] += 1
        await asyncio.sleep(i * 0.05 / len(machines))
        await ReplaySource(mid, traces[mid], speed=1.0, chunk_s=0.05, loop=1000).run(put, stop)

    async def main() -> None:
        stop = asyncio.Event()
        tasks = [asyncio.create_task(play(i, m, stop)) for i, m in enumerate(machines)]
        await asyncio.sleep(seconds)
        stop.set()
        await asyncio.gather(*tasks)
    asyncio.run(main())
    time.sleep(0.5)
    close_quietly(client)
    Path(out).write_text(json.dumps({"sent": sent}))


class _Service:
    """``drivesense monitor CONFIG --http ... --json ...`` in a subprocess (pinned to ``core``), once it is up."""

    def __init__(self, config: Path, work: Path, tag: str, core: int | None = 0) -> None:
        self.http, self.summary, self.log_path = free_port(), work / f"summary-{tag}.json", work / f"service-{tag}.log"
        self.hung = False
        with open(self.log_path, "wb") as log:
            self.proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-c", CLI, "monitor", str(config),
                                          "--http", f"127.0.0.1:{self.http}", "--duration", "900", "--json",
                                          str(self.summary)], stdout=log, stderr=log)
        _pin(self.proc.pid, core)
        if not wait_until(self.connected, 120.0, 0.2):
            self.stop()
            raise RuntimeError("the service did not come up")

    def machines(self) -> dict:
        with urllib.request.urlopen(f"http://127.0.0.1:{self.http}/api/machines", timeout=5) as r:
            return {m["machine"]: m for m in json.loads(r.read())}

    def connected(self) -> bool:
        if self.proc.poll() is not None:
            raise RuntimeError(f"the service exited with {self.proc.returncode}: "
                               f"{self.log_path.read_text(errors='replace')[-600:]}")
        try:
            return all(m["source"].get("connected", True) for m in self.machines().values())
        except (OSError, ValueError):
            return False

    def stop(self, timeout: float = 20.0) -> dict | None:
        """SIGTERM; after ``timeout`` [s] SIGABRT (faulthandler writes the threads to the log), then kill."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.hung = not wait_until(lambda: self.proc.poll() is not None, timeout)
            if self.hung:
                self.proc.send_signal(signal.SIGABRT)
                end_process(self.proc, 5.0)
        return json.loads(self.summary.read_text()) if self.summary.exists() else None


def _read_log(path: Path) -> list:
    """Event records of a JSONL event log (acknowledgements left out, and a last line torn by a kill)."""
    return [r for r in read_log_lines(path) if "id" in r]


def _latency(broker: LocalBroker, work: Path, *, quick: bool, core: int | None = None, n_machines: int = 20) -> dict:
    """20 mqtt machines publishing at real time; alarm receive time - chunk arrival [ms]; then again on one core."""
    tag, seconds = ("latency-any" if core is None else f"latency-core{core}"), (10.0 if quick else 40.0)
    machines = [f"{tag}-{i:02d}" for i in range(n_machines)]      # new ids: no MQTT session of the run before
    cfg = write_config(work / f"{tag}.toml", {m: {"kind": "mqtt", "url": broker.url, "topic": f"{m}/drive"}
                                         for m in machines}, {"mqtt": broker.url, "events": f"{tag}-events.jsonl"})
    svc, sub = _Service(cfg, work, tag, core), None
    try:
        sub, got, _ = subscribe_alarms(broker.url)
        pub = run_child("publish", {"url": broker.url, "machines": machines, "seconds": seconds}, work, 1)
        time.sleep(5.0)                                        # the publisher starts (imports, simulates)
        (ps := psutil.Process(svc.proc.pid)).cpu_percent()    # the service's CPU from here on
        end_process(pub, seconds + 180)
        cpu, t_end, sent = ps.cpu_percent() / 100, time.time(), json.loads((work / "publish.json").read_text())["sent"]
        wait_until(lambda: sum(x["chunks"] + x["rejected"] for x in svc.machines().values()) >= sum(sent.values()),
                   60, 0.2)
        drain_s, stats = time.time() - t_end, svc.machines()
    finally:
        close_quietly(svc)
        close_quietly(sub)
    logged = _read_log(work / f"{tag}-events.jsonl")
    out = {"machines": n_machines, "publish_s": seconds, "chunk_ms": 50.0, "alarms": len(got),
           "alarm_kinds": {k: sum(r["kind"] == k for _, r in got) for k in sorted({r["kind"] for _, r in got})},
           "setup": f"service on {'any core' if core is None else f'core {core}'}, event log; publisher on core 1",
           "events_logged": len(logged), "alarms_missing": len({r["id"] for r in logged} - {r["id"] for _, r in got}),
           "receive_minus_arrival": _stats_ms([t - r["arrival"] for t, r in got]),
           "detected_minus_arrival": _stats_ms([r["detected"] - r["arrival"] for _, r in got]),
           "published_minus_detected": _stats_ms([r["published"] - r["detected"] for _, r in got]),
           "receive_minus_published": _stats_ms([t - r["published"] for t, r in got]),
           "chunks_sent": int(sum(sent.values())), **{k: int(sum(m[k] for m in stats.values())) for k in (
               "chunks", "rejected", "gaps")}, "busy_s": float(sum(m["busy_s"] for m in stats.values())),
           "service_cpu_cores_while_publishing": cpu, "backlog_drained_s_after_publishing": round(drain_s, 3)}
    return out if core is not None else {**out, "service_on_core_0": _latency(broker, work, quick=quick, core=0)}


def _garbage(url: str, machine: str, channels: list) -> list:
    """Publish malformed messages to ``{machine}/drive``; their names."""
    zeros = {c: np.zeros(500) for c in channels}
    good = encode_chunk(machine, 0, 0.0, 1e4, zeros)
    msgs = [("bad bytes", b"\x00\x01 not a chunk"), ("bad JSON header", MAGIC + struct.pack("<I", 9) + b"{not json"),
            ("header length past the end", MAGIC + struct.pack("<I", 10**6) + b"{}"),
            ("NaN data", encode_chunk(machine, 10**7, 0.0, 1e4, {**zeros, channels[0]: np.full(500, np.nan)})),
            ("data shorter than the header says", good[:-8]), ("repeated seq 0", good),
            ("out-of-order seq 1", encode_chunk(machine, 1, 0.05, 1e4, zeros)),
            ("another machine's chunk", encode_chunk("elsewhere", 10**7, 0.0, 1e4, zeros))]
    client = mqtt_client(url, "garbage")
    for _, payload in msgs:
        client.publish(f"{machine}/drive", payload, qos=1).wait_for_publish(10)
    close_quietly(client)
    return [name for name, _ in msgs]


def _faults(broker: LocalBroker, work: Path, *, quick: bool) -> dict:
    """Broker restart, kill -9 and restart, garbage, SIGTERM under load in one run; each {survived, details}."""
    mq, rp, loops, speed = [f"q{i}" for i in range(6)], ["r0", "r1", "r2"], (2 if quick else 4), 5.0
    for i, r in enumerate(rp):
        write_recording(_trace(_SEED + 2 + i, 6, rotate=i), work / f"{r}.nc")
    replay = {r: {"kind": "replay", "path": f"{r}.nc", "speed": speed, "loop": loops} for r in rp}
    events, archive = work / "faults-events.jsonl", work / "faults.sqlite"
    cfg = write_config(work / "faults.toml", {**{m: {"kind": "mqtt", "url": broker.url} for m in mq}, **replay},
                  {"mqtt": broker.url, "events": events.name, "archive": archive.name})
    ref = load_config(write_config(work / "ref.toml", {r: dict(s, speed=0.0) for r, s in replay.items()}, {})).service()
    asyncio.run(ref.run(until_finished=True))
    reference = {r["id"] for r in ref.log.recent}
    svc, svc2, sub, pub, out = _Service(cfg, work, "faults-1"), None, None, None, {}
    try:
        sub, got, since = subscribe_alarms(broker.url)
        pub = run_child("publish", {"url": broker.url, "machines": mq, "seconds": 900}, work, core=1)
        wait_until(lambda: min(svc.machines()[q]["chunks"] for q in mq) > 40, 60.0)    # 2 s of data from each
        t_down = time.time()                                   # (a) the broker goes away for 1 s
        broker.stop()
        time.sleep(1.0)
        broker.start()
        t_up = time.time()
        after = wait_until(lambda: any(r["detected"] > t_up and r["machine"] in mq for _, r in got), 20.0)
        reconnected, alive = wait_until(svc.connected, 10.0), svc.proc.poll() is None
        wait_until(lambda: sum(r["machine"] in rp for r in _read_log(events)) >= 3, 30.0)
        time.sleep(0.5)
        end_process(svc.proc)                                       # (c) kill -9 ...
        t_kill, before_kill, got1 = time.time(), _read_log(events), list(got)
        seen = {r["id"] for _, r in got1}
        out["broker_restart"] = {"survived": bool(after and reconnected and alive), "details": {
            "down_s": round(t_up - t_down, 3), "service_alive": alive, "mqtt_sources_reconnected": reconnected,
            "alarms_detected_after_restart": sum(r["detected"] > t_up for _, r in got1), "duplicate_alarms":
            len(got1) - len(seen), "alarms_detected_while_down": sum(t_down <= r["detected"] <= t_up for _, r in got1),
            "logged_events_without_alarm": sum(r["id"] not in seen for r in before_kill if since < r["detected"]
                                               < t_kill - 1)}}
        svc2 = _Service(cfg, work, "faults-2")                 # ... and a restart on the same log and archive
        wait_until(lambda: svc2.machines()["q0"]["chunks"] > 5, 20.0)
        t_garbage, sent = time.time(), _garbage(broker.url, "q0", list(_trace(_SEED, 1).channels))   # (b) garbage
        wait_until(lambda: all(m["state"] == "finished" and m["queue"] == 0 for k, m in svc2.machines().items()
                          if k in rp), loops * 6 * CUT_S / speed * 3 + 30, step=0.5)
        wait_until(lambda: any(r["detected"] > t_garbage and r["machine"] == "q0" for _, r in got), 15.0)
        alive2, stats, t_stop = svc2.proc.poll() is None, svc2.machines(), time.time()
        summary = svc2.stop()                                  # (d) SIGTERM while q0..q5 publish
        stop_s = time.time() - t_stop
    finally:
        for x in (svc, svc2, pub, sub):
            close_quietly(x)
    q0_after = [r for r in _read_log(events) if r["machine"] == "q0" and r["detected"] > t_garbage]
    out["garbage"] = {"survived": bool(alive2 and stats["q0"]["rejected"] == len(sent) and q0_after
                                       and stats["q1"]["rejected"] == 0), "details": {
        "sent": sent, "rejected_q0": stats["q0"]["rejected"], "rejected_q1": stats["q1"]["rejected"],
        "last_error_q0": stats["q0"]["last_error"], "service_alive": alive2, "q0_events_after": len(q0_after),
        "q0_alarms_after": sum(r["detected"] > t_garbage and r["machine"] == "q0" for _, r in got)}}
    log_text = svc2.log_path.read_text(errors="replace")
    out["stop_while_publishing"] = {"survived": bool(not svc2.hung and summary is not None), "details": {
        "exit_code": svc2.proc.returncode, "seconds": round(stop_s, 2), "hung": svc2.hung,
        "summary_written": summary is not None, "diagnosis": "deadlock: MQTTSource.run calls loop_stop() on the event "
        "loop, paho threads wait in on_message for put() on it" if svc2.hung and "on_message" in log_text else None}}
    ids, store = [r["id"] for r in _read_log(events)], open_archive(archive)
    try:
        archived = store.events(limit=1_000_000)
    finally:
        store.close()
    a_ids, replay_ids = [r["id"] for r in archived], {i for i in ids if i.split("/")[0] in rp}
    lost, must = {r["id"] for r in before_kill} - set(ids), {r["id"] for r in before_kill} | replay_ids
    return {**out, "kill_9": {"survived": bool(not lost and len(ids) == len(set(ids)) and replay_ids == reference
                                               and len(a_ids) == len(set(a_ids)) and must <= set(a_ids) <= set(ids)),
                              "details": {
        "logged_before_kill": len(before_kill), "logged_at_end": len(ids), "lost_from_log": len(lost),
        "log_ids_unique": len(ids) == len(set(ids)), "reference_replay_events": len(reference),
        "replay_events_logged": len(replay_ids), "missing_vs_reference": len(reference - replay_ids),
        "extra_vs_reference": len(replay_ids - reference), "archived": len(a_ids), "archive_equals_log": set(a_ids)
        == set(ids), "archive_ids_unique": len(a_ids) == len(set(a_ids)), "archive_missing": len(must - set(a_ids)),
        "archived_with_segment": sum(r.get("experiment") is not None for r in archived),
        "replay": f"{len(rp)} machines, {loops} x 24 s at speed {speed:g}; reference in process at speed 0"}}}


def _memory_child(loops: int, speed: float, out: str, events: str, archive: str | None = None) -> None:
    """Subprocess: one machine replaying a 60 s trace ``loops`` times at ``speed``; RSS every second."""
    trace = _trace(_SEED + 5, 15, event_share=0.3)
    spec = MachineSpec("mem", ReplaySource("mem", trace, speed=speed, loop=loops), demo_monitor("mem"))
    svc, rows, proc = MonitorService([spec], events_path=events, archive=archive), [], psutil.Process()

    async def main() -> None:
        stop, t0 = asyncio.Event(), time.perf_counter()
        task = asyncio.create_task(svc.run(stop, until_finished=True))
        while True:
            rows.append((time.perf_counter() - t0, spec.monitor.samples, proc.memory_info().rss))
            if task.done():
                return await task
            await asyncio.wait([task], timeout=1.0)
    asyncio.run(main())
    Path(out).write_text(json.dumps({"rows": rows, "fs": trace.fs, "events": len(svc.log.recent)}))


def _memory(work: Path, *, quick: bool, archive: bool) -> dict:
    loops, tag = (10 if quick else 60), ("archive" if archive else "log")
    res = run_child("memory", {"loops": loops, "speed": 50.0, "events": str(work / f"mem-{tag}.jsonl"), "archive":
                            str(work / f"mem-{tag}.sqlite") if archive else None}, work, None, loops * 6.0 + 120)
    rows = np.asarray(res["rows"], dtype=float)
    wall_h, signal_h, rss, h = rows[:, 0] / 3600, rows[:, 1] / res["fs"] / 3600, rows[:, 2] / 2**20, len(rows) // 2
    slope = {f"slope_mb_per_{k}_h": float(np.polyfit(x[h:], rss[h:], 1)[0]) if len(rows) - h >= 3 else None
             for k, x in (("wall", wall_h), ("signal", signal_h))}
    return {"outputs": "event log and archive (SQLite)" if archive else "event log, no archive",
            "signal_h": round(float(signal_h[-1]), 4), "wall_s": round(float(rows[-1, 0]), 1), "speed": 50.0,
            "events": res["events"], **slope, **{f"rss_{k}_mb": round(float(v), 1) for k, v in (
                ("start", rss[0]), ("half", rss[h]), ("end", rss[-1]), ("max", rss.max()))},
            "rss_mb_every_10_s": [round(float(v), 1) for v in rss[::10]]}


def _guard(fn) -> dict:
    try:
        return fn()
    except Exception as exc:  # noqa: BLE001 - one part failing is reported, the others still run
        return {"error": f"{type(exc).__name__}: {exc}"}


def _targets(m: dict) -> list:
    th, lat, faults, lim = m.get("throughput", {}), m.get("latency", {}), m.get("faults", {}), TARGETS
    rt, axes = th.get("realtime", {}), lim["axes_per_core_min"]
    p99, p99_one = (x.get("receive_minus_arrival", {}).get("p99_ms") for x in (lat, lat.get("service_on_core_0", {})))
    slopes = [v.get("slope_mb_per_signal_h") for v in m.get("memory", {}).values() if isinstance(v, dict)]
    worst = None if None in slopes or not slopes else max(slopes)
    rows = [(f">= {axes} axes at 10 kHz per core, steady state (estimator + detectors, 50 ms chunks)",
             th.get("axes_per_core"), (th.get("axes_per_core") or 0) >= axes),
            (f"one core keeps up in real time with >= {axes} axes (>= 99 % of due processed, queue never full)",
             {k: rt.get(k) for k in ("machines", "processed_share", "keeps_up")},
             rt.get("keeps_up") and (rt.get("machines") or 0) >= axes),
            (f"alarm latency p99 <= {lim['alarm_p99_ms_max']:g} ms at 20 axes (received - chunk arrival)",
             p99 if p99 is not None else lat.get("not measured", lat.get("error")),
             p99 is not None and p99 <= lim["alarm_p99_ms_max"]),
            ("the same with the service pinned to one core", p99_one,
             p99_one is not None and p99_one <= lim["alarm_p99_ms_max"])]
    for key, text in (("broker_restart", "broker restart: reconnects, alarms after it arrive"),
                      ("garbage", "garbage on a topic: counted, the service runs on and detects"),
                      ("kill_9", "kill -9 + restart: logged events kept, none twice, = the uninterrupted run"),
                      ("stop_while_publishing", "SIGTERM while machines publish: the service stops cleanly")):
        ok = faults.get(key, {}).get("survived")
        rows.append((text, ok if ok is not None else faults.get("not measured", faults.get("error")), ok))
    rows.append((f"memory flat: RSS slope < {lim['memory_mb_per_signal_hour_max']:g} MB per hour of signal (second "
                 "half, worst of with/without archive)", worst, worst is not None and worst < lim[
                     "memory_mb_per_signal_hour_max"]))
    return [{"target": t, "measured": v, "met": bool(ok)} for t, v, ok in rows]


def run_monitor_bench(progress=None, *, quick: bool = False) -> dict:
    """Run the monitor bench; returns ``{"monitor": {...}}`` (strict JSON values).

    Parameters
    ----------
    progress : callable, optional
        Called with a label after each part.
    quick : bool
        Shorter runs: 10 axes steady state, 5 s real time, 10 s of alarms, 10 min of signal for the memory.

    Returns
    -------
    dict
        ``{"monitor": {"throughput", "latency", "faults", "memory", "targets": [{target, measured, met}]}}``;
        without mosquitto the latency and faults read ``{"not measured": ...}``.
    """
    began, work, out = time.perf_counter(), Path(tempfile.mkdtemp(prefix="ds-bench-monitor-")), {"quick": quick}
    step = progress or (lambda label: None)
    try:
        out["throughput"] = _guard(lambda: _throughput(work, quick=quick))
        step("monitor throughput")
        binary = find_mosquitto()
        if binary is None or importlib.util.find_spec("paho") is None:
            out["latency"] = out["faults"] = {"not measured": "mosquitto (or paho-mqtt) not installed"}
        else:
            setup_demo_axis(work)
            for part, fn in (("latency", _latency), ("faults", _faults)):
                def one(fn=fn, folder=work / f"broker-{part}") -> dict:
                    broker = LocalBroker(folder)
                    try:
                        return fn(broker, work, quick=quick)
                    finally:
                        broker.stop()
                out[part] = _guard(one)
                step(f"monitor {part}")
        out["memory"] = {tag: _guard(lambda a=archive: _memory(work, quick=quick, archive=a))
                         for tag, archive in (("events_log_only", False), ("with_archive", True))}
        step("monitor memory")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    out.update(targets=_targets(out), wall_s=time.perf_counter() - began)
    # strict JSON: non-finite floats -> None, numpy scalars -> Python
    return {"monitor": json.loads(json.dumps(out, default=lambda o: o.item()), parse_constant=lambda c: None)}
