"""``drivesense bench fleet`` in quick mode: the JSON it promises, and the behaviour targets hold.

Quick mode (4 recordings of 15 s) is too short for the speed targets (the cluster's fixed costs dominate);
their figures must be there and be numbers.  Identity with the serial run, resume after ``kill -9`` and
the failing input must hold at any size; so must the monitor failover (quick: 3 worker processes on a real
mosquitto, 6 machines for 24 s; one worker stopped with SIGTERM, then another killed with SIGKILL).
"""

from __future__ import annotations

import json

from drivesense.bench import BENCH_KINDS
from drivesense.bench.fleet import run_fleet_bench


def test_fleet_bench_quick():
    out = run_fleet_bench(quick=True)["fleet"]
    json.dumps(out, allow_nan=False)                      # strict JSON
    assert "fleet" in BENCH_KINDS
    assert out["inputs"] == 4 and out["recording_s"] == 15.0
    for run in ("one_worker", "two_workers"):
        assert out[run]["failed"] == 0 and out[run]["wall_s"] > 0
    assert out["two_workers"]["tasks_per_worker"] and sum(out["two_workers"]["tasks_per_worker"]) == 4
    for key in ("speedup_2_over_1", "overhead_per_task", "one_worker_over_serial"):
        assert isinstance(out[key], float)
    assert out["rounds"] == 1 and len(out["speedup_rounds"]) == 1 and out["one_worker"]["walls_s"]
    for run in ("one_worker", "two_workers"):                 # a task's CPU time is within its wall time
        assert 0 < out[run]["task_cpu_s_median"] <= out[run]["task_compute_s_median"] * 1.05 + 0.01
    assert out["identical_to_serial"] == {"one_worker": True, "two_workers": True}
    resume = out["resume"]
    assert resume["survived"], resume
    assert resume["rerun_ran"] + resume["rerun_skipped"] == 4 and resume["results_rewritten_with_row_before"] == 0
    assert out["failure"]["survived"] and "broken.nc" in out["failure"]["error"]
    fo = out["failover"]
    assert fo["machines"] == 6 and fo["workers"] == 3 and fo["machines_moved"] >= 1, fo
    assert fo["events_reference"] > 0 and fo["all_marked_to_the_end"], fo
    assert (fo["events_lost"], fo["events_extra"], fo["events_doubled"], fo["alarms_doubled"]) == (0, 0, 0, 0), fo
    assert fo["alarms_missing"] == 0, fo                  # every logged event had its alarm
    for phase in ("leave", "kill"):                       # SIGTERM (hand-over), then SIGKILL
        assert fo[phase]["machines_moved"] >= 1 and fo[phase]["exit"] == (0 if phase == "leave" else -9), fo[phase]
        assert all(r["resumed_s"] is not None and r["resumed_s"] <= 5.0 for r in fo[phase]["resume"]), fo[phase]
    assert fo["survived"]
    met = {t["target"].split(" ")[0]: t["met"] for t in out["targets"]}
    assert met["results"] and met["resume"] and met["a"] and met["monitor"]
