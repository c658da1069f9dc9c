"""The failover part of ``drivesense bench fleet``: monitor workers sharing machines, one of them killed.

Three ``drivesense monitor CONFIG --worker wK --events FOLDER`` processes share 30 machines (each the demo
axis X on an ``mqtt`` source) on a local mosquitto; a publisher plays every machine's simulated cuts (with
breakages, chatter and overloads) at real time in 50 ms chunks.  Half-way, the worker that holds the most
machines is killed with SIGKILL.  Then:

* *lost / doubled*: the events in the machines' logs (the union over the fleet) against a reference --
  the same chunks of each machine processed in this process from start to end, without interruption --
  and every id counted once; the alarms a subscriber received are checked for repeats too;
* *resume*: for every machine the killed worker held, the time from the kill until its new worker has
  re-primed on the chunks the broker kept and processed the first chunk the killed one had not (the
  ``resumed`` line of the machine's log), and the signal's lag behind real time at that moment.
"""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
import time
import urllib.request
from collections import Counter
from pathlib import Path

from drivesense.bench.monitor import (close_quietly, publisher_traces, run_child, setup_demo_axis,
                                      subscribe_alarms, wait_until, write_config)
from drivesense.serve.broker import LocalBroker, free_port
from drivesense.serve.config import load_config
from drivesense.serve.fleet import HOLD_S
from drivesense.serve.machine import MachineMonitor
from drivesense.serve.sources import ReplaySource

__all__ = ["run_failover", "RESUME_S_MAX"]

#: The issue's target: a killed worker's machines resume within this time [s].
RESUME_S_MAX = 5.0
_CLI = "from drivesense.cli import main; main()"


def _lines(path: Path) -> list[dict]:
    text = path.read_bytes() if path.exists() else b""
    return [json.loads(x) for x in text[:text.rfind(b"\n") + 1].splitlines()]


def _held(port: int) -> set:
    """Machines a worker holds, from its API (empty when it does not answer)."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/machines", timeout=5) as r:
            return {m["machine"] for m in json.loads(r.read()) if m.get("fleet", {}).get("held")
                    and m["state"] == "running"}
    except (OSError, ValueError):
        return set()


def _reference(config: Path, machines: list, sent: dict) -> dict:
    """Event ids of each machine's published chunks processed from start to end in this process."""
    spec = load_config(config).machines[0]                   # every machine has this same axis: fitted once
    traces, out = publisher_traces(machines), {}

    async def play(mid: str) -> None:
        monitor, stop, ids = MachineMonitor(mid, spec.monitor.axes, history_s=spec.monitor.history_s), \
            asyncio.Event(), []

        async def put(chunk) -> None:
            ids.extend(r["id"] for r in monitor.process(chunk))
            if chunk.seq + 1 >= sent[mid]:
                stop.set()
        await ReplaySource(mid, traces[mid], speed=0.0, chunk_s=0.05, loop=1000).run(put, stop)
        out[mid] = ids
    for mid in machines:
        asyncio.run(play(mid))
    return out


def run_failover(work: Path, *, quick: bool = False, progress=None) -> dict:
    """Run the failover measurement in ``work``; its figures (strict JSON values).

    Parameters
    ----------
    work : Path
        An empty folder (AXIS.toml and the idle runs are made there when missing).
    quick : bool
        6 machines for 24 s (the tests) instead of 30 for 40 s.
    progress : callable, optional
        Called with a label after each step.
    """
    step = progress or (lambda label: None)
    n_machines, seconds = (6, 24.0) if quick else (30, 40.0)
    if not (work / "AXIS.toml").exists():
        setup_demo_axis(work)
    machines, workers = [f"f{i:02d}" for i in range(n_machines)], ["w1", "w2", "w3"]
    broker = LocalBroker(work / "broker-failover")
    events = work / "failover-events"
    cfg = write_config(work / "failover.toml", {m: {"kind": "mqtt", "url": broker.url} for m in machines},
                       {"mqtt": broker.url})
    procs, ports, sub, pub = {}, {}, None, None
    try:
        for w in workers:
            ports[w] = free_port()
            with open(work / f"failover-{w}.log", "wb") as log:
                procs[w] = subprocess.Popen([sys.executable, "-c", _CLI, "monitor", str(cfg), "--worker", w,
                                             "--events", str(events), "--http", f"127.0.0.1:{ports[w]}",
                                             "--duration", "900", "--json", str(work / f"failover-{w}.json")],
                                            stdout=log, stderr=log)
        held: dict = {}

        def settled() -> bool:
            for w, p in procs.items():
                if p.poll() is not None:
                    raise RuntimeError(f"worker {w} exited with {p.returncode}: "
                                       f"{(work / f'failover-{w}.log').read_text(errors='replace')[-600:]}")
                held[w] = _held(ports[w])
            return sorted(m for h in held.values() for m in h) == machines
        if not wait_until(settled, 180.0, 0.5):
            raise RuntimeError(f"the workers did not share the machines out: {held}")
        step("workers up")
        sub, got, _ = subscribe_alarms(broker.url)
        pub = run_child("publish", {"url": broker.url, "machines": machines, "seconds": seconds}, work, None)
        victim = max(workers, key=lambda w: (len(held[w]), w))
        moved = sorted(held[victim])
        time.sleep(4.0 + seconds / 2)                              # the publisher starts (~4 s), then half-way
        procs[victim].kill()
        t_kill = time.time()
        procs[victim].wait()
        step("worker killed")
        publisher_exit = pub.wait(seconds + 120)
        sent = json.loads((work / "publish.json").read_text())["sent"]

        def caught_up() -> bool:
            marks = {m: (events / f"{m}.claim").read_bytes().split() for m in machines}
            return all(v and int(v[0]) >= sent[m] - 1 for m, v in marks.items())
        drained = wait_until(caught_up, 120.0, 0.5)
        time.sleep(1.0)                                            # the last alarms reach the subscriber
        for w in workers:
            if w != victim:
                procs[w].send_signal(signal.SIGTERM)
        exits = {w: procs[w].wait(60) for w in workers if w != victim}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        close_quietly(pub)
        close_quietly(sub)
        broker.stop()
    step("run")
    logs = {m: _lines(events / f"{m}.jsonl") for m in machines}
    one = write_config(work / "failover-reference.toml", {machines[0]: {"kind": "mqtt", "url": "mqtt://127.0.0.1"}},
                       {})
    reference = _reference(one, machines, sent)
    step("reference")
    ref_ids = {i for ids in reference.values() for i in ids}
    logged = [r["id"] for lines in logs.values() for r in lines if "id" in r]
    alarm_ids = Counter(r["id"] for _, r in got)
    resumes = []
    for m in moved:
        lines = logs[m]
        claim = next((x for x in lines if "claim" in x and x["at"] > t_kill), None)
        resumed = next((x for x in lines if "resumed" in x and x["at"] > t_kill), None)
        resumes.append({"machine": m, "new_worker": claim and claim["worker"],
                        "claimed_s": claim and claim["at"] - t_kill, "resumed_s": resumed and resumed["at"] - t_kill,
                        "primed_chunks": resumed and resumed["primed"], "lag_at_resume_s": resumed and resumed["lag_s"],
                        "prime_through": claim and claim["prime_through"]})
    resumed_s = [r["resumed_s"] for r in resumes if r["resumed_s"] is not None]
    lost, extra = ref_ids - set(logged), set(logged) - ref_ids
    out = {"machines": n_machines, "workers": len(workers), "publish_s": seconds, "chunk_ms": 50.0,
           "killed": victim, "killed_at_s": seconds / 2, "machines_moved": len(moved),
           "held_before": {w: len(h) for w, h in held.items()}, "chunks_sent": int(sum(sent.values())),
           "publisher_exit": publisher_exit, "all_marked_to_the_end": drained, "survivor_exits": exits,
           "events_reference": len(ref_ids), "events_logged": len(logged), "events_lost": len(lost),
           "events_extra": len(extra), "events_doubled": len(logged) - len(set(logged)),
           "lost_ids": sorted(lost)[:10], "extra_ids": sorted(extra)[:10],
           "alarms_received": sum(alarm_ids.values()), "alarms_doubled": sum(c - 1 for c in alarm_ids.values()),
           "resume": resumes, "resume_s_max": max(resumed_s) if len(resumed_s) == len(moved) and moved else None,
           "hold_s": HOLD_S}
    out["survived"] = bool(moved and drained and not lost and not extra and out["events_doubled"] == 0
                           and out["alarms_doubled"] == 0 and out["resume_s_max"] is not None
                           and out["resume_s_max"] <= RESUME_S_MAX)
    return out
