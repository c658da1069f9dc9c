"""``bench nc``: the regression baseline and the shape of the bench JSON (the figures live in the bench)."""

from __future__ import annotations

import json

import numpy as np

from drivesense.bench.nc import regression_baseline, run_nc_bench
from drivesense.machine.regression_model import regression_feature_names, regression_features
from drivesense.recording import Recording


def _trace(seed: int, n: int = 400) -> Recording:
    rng = np.random.default_rng(seed)
    ch = {f"{a}_{q}": rng.standard_normal(n) for a in "xyz" for q in ("current", "velocity", "acceleration")}
    ch["spindle_current"] = rng.standard_normal(n)
    return Recording.from_arrays(ch, fs=50.0)


def test_the_baseline_is_thirteen_terms_and_recovers_a_linear_law():
    rec = _trace(1)
    names = regression_feature_names("xyz")
    X = regression_features(rec, names)
    assert X.shape == (400, 13)
    w = np.arange(1.0, 14.0)
    truth = {f"force_{a}": X @ (w * (i + 1)) for i, a in enumerate("xyz")}
    cal = rec.with_channels(truth, units={k: "N" for k in truth})
    est = regression_baseline([cal]).estimate(_trace(2))
    X2 = regression_features(_trace(2), names)
    for i, a in enumerate("xyz"):
        assert np.allclose(est[f"force_{a}"], X2 @ (w * (i + 1)))
    assert est.meta["latency_s"] == 0.0


def test_bench_json_is_strict_and_names_its_targets():
    out = run_nc_bench(rates=(50.0,), learned_sizes=())
    text = json.dumps(out, allow_nan=False)
    nc = json.loads(text)["nc"]
    res = nc["50hz"]
    assert set(res["regression"]["nrmse"]) == {"x", "y", "z"}
    assert set(res["model"]["ratio"]["per_axis"]) == {"x", "y", "z"}
    assert len(res["held_out_cuts"]) >= 5 and res["calibration_cut"] not in res["held_out_cuts"]
    assert set(res["auto"]["choice"]) == {"x", "y", "z"} and set(res["auto"]["fallbacks"]) <= {"x", "y", "z"}
    for name in ("model_mean_ratio_50hz", "model_worst_axis_ratio_50hz", "identify_seconds_50hz",
                 "auto_worst_axis_ratio_50hz"):
        assert {"value", "target", "met"} <= set(nc["targets"][name])
