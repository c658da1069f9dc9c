"""``drivesense bench fleet`` in quick mode: the JSON it promises, and the behaviour targets hold.

Quick mode (4 recordings of 15 s) is too short for the speed targets (the cluster's fixed costs dominate);
their figures must be there and be numbers.  Identity with the serial run, resume after ``kill -9`` and
the failing input must hold at any size.
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
    assert out["identical_to_serial"] == {"one_worker": True, "two_workers": True}
    resume = out["resume"]
    assert resume["survived"], resume
    assert resume["rerun_ran"] + resume["rerun_skipped"] == 4 and resume["results_rewritten_with_row_before"] == 0
    assert out["failure"]["survived"] and "broken.nc" in out["failure"]["error"]
    met = {t["target"].split(" ")[0]: t["met"] for t in out["targets"]}
    assert met["results"] and met["resume"] and met["a"]
