"""``drivesense bench monitor``: the throughput part in quick mode on 2 axes gives the JSON it promises."""

from __future__ import annotations

import json

from drivesense.bench import BENCH_KINDS
from drivesense.bench.monitor import _throughput


def test_throughput_quick_two_axes(tmp_path):
    out = _throughput(tmp_path, quick=True, n_axes=2, realtime_axes=2)
    json.dumps(out, allow_nan=False)                      # strict JSON
    assert "monitor" in BENCH_KINDS
    assert set(out) >= {"steady_state", "axes_per_core", "monitor_over_estimator", "realtime", "baseline"}
    for key in ("chunk_50ms", "chunk_10ms"):
        cost = out["steady_state"][key]
        assert cost["axes"] == 2
        for name in ("cpu_s_per_axis_s", "axes_per_core", "estimator_cpu_s_per_axis_s", "monitor_over_estimator",
                     "wire_decode_cpu_s_per_axis_s"):
            assert isinstance(cost[name], float) and cost[name] > 0, name
    assert out["axes_per_core"] == out["steady_state"]["chunk_50ms"]["axes_per_core"]
    rt = out["realtime"]
    assert rt["machines"] == 2 and rt["rejected"] == 0
    assert isinstance(rt["keeps_up"], bool) and isinstance(rt["queue_never_full"], bool)
    assert rt["processed_samples"] > 0 and rt["due_samples"] > 0 and 0 < rt["processed_share"] <= 1.5
    assert set(rt["lag"]) == {"count", "p50_ms", "p99_ms", "max_ms"} and rt["lag"]["count"] > 0
    assert isinstance(rt["lag"]["p99_ms"], float)
