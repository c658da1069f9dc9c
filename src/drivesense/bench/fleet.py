"""``drivesense bench fleet``: the batch on Dask against the same batch run serially, resume after a kill.

Inputs: simulated 60 s recordings of the demo axis (10 kHz, 4 s cuts; one simulated trace,
each input a different rotation of it: the same work, different content).  Job:
``batch detect --method vibration --teeth 2`` with the demo's idle runs (estimator and
detectors: what a changed detector is rerun over an archive with).

*identical*: every output array and summary value of the Dask runs equals the
serial run's, bit for bit.  *throughput*: wall time of the batch on one worker
over two workers (the clusters started, their workers warmed and the job
prepared before the clock runs), in rounds of alternating order (1, 2, then 2,
1): this machine's speed drifts by 10-20 % within a minute, and the alternation
makes a drift weigh on both alike.  48 recordings, so that the last task's tail
(half a task per worker on average) and each run's fixed costs stay a few
percent of the wall time, as in a batch of an archive.  *overhead*: the
one-worker batches' wall time over the compute time their tasks report, minus
one -- what the scheduler costs per task; the one-worker wall over the serial
wall is reported beside it.  *resume*: ``drivesense
batch detect`` killed (SIGKILL, the whole process group) once half the rows
are written, then run again: it must run exactly the inputs without a row and
leave every result written before untouched.  *failure*: a broken file among
the inputs gets an error row; the others complete.  *failover*: three live monitor workers share 30
machines on a local mosquitto and one is killed (:mod:`drivesense.bench.failover`).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from drivesense.bench.failover import RESUME_S_MAX, run_failover
from drivesense.bench.monitor import CUT_S
from drivesense.bench.rig import CLI, setup_demo_axis
from drivesense.fleet.batch import ROWS, local_cluster, read_rows, run_batch
from drivesense.fleet.inputs import file_inputs
from drivesense.fleet.jobs import DetectJob
from drivesense.io import read_recording, write_recording
from drivesense.recording import Recording
from drivesense.monitor.sources import SimulatedSource

__all__ = ["run_fleet_bench", "TARGETS", "RECORDING_S", "N_INPUTS", "ROUNDS"]

#: The issue's targets.
TARGETS = {"speedup_2_workers_min": 1.8, "overhead_per_task_max": 0.10, "failover_resume_s_max": RESUME_S_MAX}
#: Length of each input recording [s].
RECORDING_S = 60.0
#: Input recordings of the full bench.
N_INPUTS = 48
#: Rounds of the throughput comparison, each one run on one worker and one on two (full bench).
ROUNDS = 2
#: Columns of a row that are about the run, not the result.
_RUN_COLUMNS = {"seconds", "cpu_seconds", "finished", "worker", "input"}


def _recordings(folder: Path, n: int, seconds: float) -> list[Path]:
    """``n`` recordings of ``seconds`` each: one simulated trace (the demo's 4 s cuts end to end, the friction map's
    idle runs cover their positions), rotated differently."""
    folder.mkdir(parents=True, exist_ok=True)
    src = SimulatedSource("fleet", seed=23, cut_s=CUT_S, event_share=0.5)
    cuts = [src.simulate_cut(k) for k in range(max(1, int(round(seconds / src.cut_s))))]
    base = {c: np.concatenate([r[c] for r in cuts]) for c in cuts[0].channels}
    paths = []
    for i in range(n):
        shift = i * 7919
        rec = Recording.from_arrays({c: np.roll(v, -shift) for c, v in base.items()}, fs=cuts[0].fs,
                                    meta={"name": f"fleet bench recording {i}"})
        paths.append(write_recording(rec, folder / f"rec{i:03d}.nc"))
    return paths


def _job(work: Path) -> DetectJob:
    return DetectJob(method="vibration", axis_file=work / "AXIS.toml", idle=sorted(work.glob("idle*.nc")), teeth=2)


def _same_results(out_a: Path, out_b: Path, keys) -> bool:
    """Every row value (run columns aside) and every output array equal, bit for bit."""
    rows_a, rows_b = read_rows(out_a, keys), read_rows(out_b, keys)
    if set(rows_a) != set(keys) or set(rows_b) != set(keys):
        return False
    for k in keys:
        a, b = ({c: v for c, v in r.items() if c not in _RUN_COLUMNS} for r in (rows_a[k], rows_b[k]))
        if a != b:
            return False
        for rel in filter(None, a.get("outputs", "").split(";")):
            if not rel.endswith(".nc"):                # JSON, TOML: the same text
                if (out_a / rel).read_bytes() != (out_b / rel).read_bytes():
                    return False
                continue
            ra, rb = read_recording(out_a / rel), read_recording(out_b / rel)
            if ra.channels != rb.channels or not all(np.array_equal(ra[c], rb[c]) for c in ra.channels):
                return False
    return True


def _on_cluster(job, items, out: Path, warm: Path, workers: int) -> tuple[float, object]:
    """Wall time [s] of the batch on a warmed LocalCluster of ``workers`` processes, and its report."""
    from distributed import Client

    with local_cluster(workers, dashboard=False) as cluster, Client(cluster) as client:
        run_batch(job, items[:workers], warm, client=client)           # imports and compiled code, per worker
        t, cpu = time.perf_counter(), time.process_time()
        report = run_batch(job, items, out, client=client)
        wall = time.perf_counter() - t
        report.client_cpu_share = (time.process_time() - cpu) / wall     # client + scheduler, this process
        return wall, report


def _throughput(job, items, work: Path, rounds: int) -> dict:
    """Batches on one and on two workers, ``rounds`` times in alternating order; per worker count, the runs'
    output folders, wall times [s] and reports."""
    runs: dict[int, dict[str, list]] = {w: {"out": [], "wall_s": [], "report": []} for w in (1, 2)}
    for r in range(rounds):
        for workers in ((1, 2) if r % 2 == 0 else (2, 1)):
            out = work / f"w{workers}-{r}"
            wall, report = _on_cluster(job, items, out, work / f"warm-w{workers}-{r}", workers)
            for key, value in (("out", out), ("wall_s", wall), ("report", report)):
                runs[workers][key].append(value)
    return runs


def _run_figures(runs: dict) -> dict:
    """One worker count's figures over its runs (strict JSON)."""
    rows = [r for rep in runs["report"] for r in rep.rows]
    return {"wall_s": float(np.mean(runs["wall_s"])), "walls_s": runs["wall_s"],
            "failed": sum(rep.failed for rep in runs["report"]),
            "client_cpu_share": float(np.mean([rep.client_cpu_share for rep in runs["report"]])),
            "task_compute_s_median": float(np.median([r["seconds"] for r in rows])),
            "task_cpu_s_median": float(np.median([r["cpu_seconds"] for r in rows])),
            "tasks_per_worker": sorted(Counter(r["worker"] for r in runs["report"][0].rows).values())}


def _resume(work: Path, folder: Path, n: int, serial_out: Path, keys) -> dict:
    """Kill ``drivesense batch detect`` half-way (SIGKILL, process group), run it again; what was redone."""
    out = work / "resume"
    cmd = [sys.executable, "-c", CLI, "batch", "detect", str(folder), "--teeth", "2", "--axis",
           str(work / "AXIS.toml"),
           *(a for p in sorted(work.glob("idle*.nc")) for a in ("--idle", str(p))), "--out", str(out),
           "--workers", "2", "--json", str(work / "resume.json")]
    log = open(work / "resume-first.log", "wb")
    proc = subprocess.Popen(cmd, stdout=log, stderr=log, start_new_session=True)
    deadline, rows_dir = time.time() + 600, out / ROWS
    while time.time() < deadline and proc.poll() is None:
        if rows_dir.exists() and len(list(rows_dir.glob("*.json"))) >= n // 2:
            break
        time.sleep(0.05)
    killed_while_running = proc.poll() is None
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()
    log.close()
    time.sleep(1.0)                                    # orphaned workers, if any, notice and exit
    rows_before = read_rows(out, keys)                 # complete before the kill: their results must stay
    done_files = [f for r in rows_before.values() for f in filter(None, (r.get("outputs") or "").split(";"))]
    stamps = {f: (out / f).stat().st_mtime_ns for f in done_files}
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    report = json.loads((work / "resume.json").read_text()) if rerun.returncode == 0 else {}
    rewritten = [f for f, mt in stamps.items() if not (out / f).exists() or (out / f).stat().st_mtime_ns != mt]
    n_before, equal = len(rows_before), _same_results(out, serial_out, keys)
    ok = (killed_while_running and rerun.returncode == 0 and report.get("ran") == n - n_before
          and report.get("skipped") == n_before and not rewritten and equal)
    return {"inputs": n, "rows_before_kill": n_before, "killed_while_running": killed_while_running,
            "rerun_ran": report.get("ran"), "rerun_skipped": report.get("skipped"),
            "results_with_row_before": len(stamps), "results_rewritten_with_row_before": len(rewritten),
            "equal_to_serial": equal, "rerun_rc": rerun.returncode, "survived": bool(ok),
            **({"rerun_error": rerun.stderr[-600:]} if rerun.returncode else {})}


def _failure(work: Path, job, paths: list[Path]) -> dict:
    """A broken input among good ones: an error row for it, the others complete."""
    broken = work / "broken" / "broken.nc"
    broken.parent.mkdir(exist_ok=True)
    broken.write_bytes(b"this is not a netCDF file")
    report = run_batch(job, file_inputs([*paths[:2], broken]), work / "failure", workers=0)
    errors = {r["input"]: r["error"] for r in report.rows if r["status"] == "error"}
    return {"inputs": 3, "failed": report.failed, "error": errors.get(str(broken), ""),
            "survived": report.failed == 1 and set(errors) == {str(broken)} and len(report.rows) == 3}


def run_fleet_bench(progress=None, *, quick: bool = False) -> dict:
    """Run the fleet bench; ``{"fleet": {...}}`` (strict JSON values).

    Parameters
    ----------
    progress : callable, optional
        Called with a label after each step.
    quick : bool
        Fewer and shorter recordings (the tests).
    """
    step = progress or (lambda label: None)
    n, seconds, rounds = (4, 15.0, 1) if quick else (N_INPUTS, RECORDING_S, ROUNDS)
    work = Path(tempfile.mkdtemp(prefix="drivesense-bench-fleet-"))
    try:
        setup_demo_axis(work)
        paths = _recordings(work / "recordings", n, seconds)
        job = _job(work)
        items = file_inputs(paths)
        step("recordings")
        t = time.perf_counter()
        job.ensure_prepared()                          # once for every run below: the friction map fit
        prepare_s = time.perf_counter() - t
        run_batch(job, items[:1], work / "warm-serial", workers=0)         # imports and compiled code, here
        t = time.perf_counter()
        serial = run_batch(job, items, work / "serial", workers=0)
        serial_s = time.perf_counter() - t
        step("serial")
        keys = [r["key"] for r in serial.rows]
        runs = _throughput(job, items, work, rounds)
        step("one and two workers")
        identical = {name: all(_same_results(o, work / "serial", keys) for o in runs[w]["out"])
                     for name, w in (("one_worker", 1), ("two_workers", 2))}
        resume = _resume(work, work / "recordings", n, work / "serial", keys)
        step("resume")
        failure = _failure(work, job, paths)
        step("failure")
        (work / "failover").mkdir()
        for f in ("AXIS.toml", *(p.name for p in work.glob("idle*.nc"))):
            shutil.copy(work / f, work / "failover" / f)
        failover = run_failover(work / "failover", quick=quick, progress=lambda label: step(f"failover: {label}"))
        task_s = [r["seconds"] for r in serial.rows]
        out = {"inputs": n, "recording_s": seconds, "method": "detect --method vibration --teeth 2 (friction map "
               "from the demo's idle runs)", "cores": os.cpu_count(), "prepare_s": prepare_s,
               "serial": {"wall_s": serial_s, "per_task_s": serial_s / n, "task_compute_s_median":
                          float(np.median(task_s))},
               "rounds": rounds, "one_worker": _run_figures(runs[1]), "two_workers": _run_figures(runs[2]),
               "speedup_2_over_1": sum(runs[1]["wall_s"]) / sum(runs[2]["wall_s"]),
               "speedup_rounds": [a / b for a, b in zip(runs[1]["wall_s"], runs[2]["wall_s"])],
               "one_worker_over_serial": float(np.mean(runs[1]["wall_s"])) / serial_s - 1.0,
               "overhead_per_task": sum(runs[1]["wall_s"]) / sum(r["seconds"] for rep in runs[1]["report"]
                                                                 for r in rep.rows) - 1.0,
               "identical_to_serial": identical, "resume": resume, "failure": failure, "failover": failover}
        out["targets"] = [
            {"target": "results identical (bit for bit) to the serial run", "measured": identical,
             "met": all(identical.values())},
            {"target": f"2 workers >= {TARGETS['speedup_2_workers_min']:g}x one worker ({n} recordings, "
                       f"{rounds} round(s) of alternating order)", "measured":
             out["speedup_2_over_1"], "met": out["speedup_2_over_1"] >= TARGETS["speedup_2_workers_min"]},
            {"target": f"scheduler overhead per task <= {TARGETS['overhead_per_task_max']:.0%} on "
                       f"{seconds:g} s recordings (one worker: wall / task compute - 1)",
             "measured": out["overhead_per_task"],
             "met": out["overhead_per_task"] <= TARGETS["overhead_per_task_max"]},
            {"target": "resume after kill -9 half-way recomputes nothing that was written", "measured":
             {k: resume[k] for k in ("rows_before_kill", "rerun_ran", "rerun_skipped",
                                     "results_rewritten_with_row_before")}, "met": resume["survived"]},
            {"target": "a failing recording is recorded and never stops the batch", "measured": failure["error"][:60],
             "met": failure["survived"]},
            {"target": f"monitor failover: {failover['workers']} workers, {failover['machines']} machines, one killed: "
                       f"no event lost or doubled, its machines resume within {RESUME_S_MAX:g} s",
             "measured": {k: failover[k] for k in ("machines_moved", "events_reference", "events_lost", "events_extra",
                                                   "events_doubled", "alarms_doubled", "alarms_missing",
                                                   "resume_s_max")},
             "met": failover["survived"]}]
        return {"fleet": out}
    finally:
        shutil.rmtree(work, ignore_errors=True)
