"""Learned-reconstruction benchmark: LSTM vs ModelBased vs Hybrid on held-out runs (third paper, Table 2).

Builds (or reuses) the seeded dataset, identifies the axes from simulated air
moves for ModelBased and the Hybrid, trains both learned methods, and scores
every method on the held-out parameter combinations and the held-out process
type against the reference force low-passed like the training targets.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from drivesense.learn.features import filtered_target
from drivesense.score import aligned_reference

__all__ = ["run_learn_bench", "evaluate_methods", "default_dataset_dir"]


def default_dataset_dir() -> Path:
    """Cache folder of the benchmark dataset (``$DRIVESENSE_CACHE`` or ``~/.cache/drivesense``)."""
    return Path(os.environ.get("DRIVESENSE_CACHE", Path.home() / ".cache" / "drivesense")) / "dataset"


def _rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def evaluate_methods(estimators: dict, runs, *, coverage_method: str | None = "lstm") -> dict:
    """Score estimators on runs: per run and axis RMSE [N], NRMSE, max |F| [N], and interval coverage.

    Parameters
    ----------
    estimators : dict of str to estimator
        Objects with ``estimate(recording)``; the one named ``coverage_method``
        also with ``estimate(recording, intervals=True)``.
    runs : sequence of Recording
        Held-out traces with reference ``force_x/y/z`` and ``meta["score_window"]``.
    coverage_method : str, optional
        Which estimator's intervals to check.

    Returns
    -------
    dict
        ``rows`` (process, run, split, axis, method, rmse_n, nrmse, max_abs_force_n), ``coverage``,
        ``infer_seconds`` per method and ``signal_seconds``.
    """
    rows, inside, total = [], 0, 0
    infer = {m: 0.0 for m in estimators}
    signal_s = 0.0
    for rec in runs:
        window = rec.meta.get("score_window", (rec.t0, rec.t0 + rec.duration))
        sel = (rec.time >= window[0]) & (rec.time < window[1])
        signal_s += rec.duration
        for method, est in estimators.items():
            t0 = time.perf_counter()
            want = method == coverage_method
            out = est.estimate(rec, intervals=True) if want else est.estimate(rec)
            infer[method] += time.perf_counter() - t0
            for ax in "xyz":
                ch = f"force_{ax}"
                ref = aligned_reference(filtered_target(rec, ch, aligned=False), rec.fs, None,
                                        float(out.meta.get("latency_s", 0.0)))[sel]
                got = out[ch][sel]
                p2p = float(np.ptp(ref))
                rows.append({"process": rec.meta.get("process", ""), "run": rec.meta.get("name", ""),
                             "split": rec.meta.get("split", ""), "axis": ax, "method": method,
                             "rmse_n": _rmse(got, ref), "nrmse": _rmse(got, ref) / p2p if p2p > 0 else float("inf"),
                             "max_abs_force_n": float(np.max(np.abs(ref)))})
                if want:
                    lo, hi = out[f"{ch}_lower"][sel], out[f"{ch}_upper"][sel]
                    inside += int(np.sum((ref >= lo) & (ref <= hi)))
                    total += ref.size
    return {"rows": rows, "coverage": inside / total if total else float("nan"), "infer_seconds": infer,
            "signal_seconds": signal_s}


def _median_rmse(rows, method, splits=("test",), processes=None, axes="xy"):
    vals = [r["rmse_n"] for r in rows if r["method"] == method and r["split"] in splits and r["axis"] in axes
            and (processes is None or r["process"] in processes)]
    return float(np.median(vals)) if vals else float("nan")


def _hybrid_wins(rows, split: str) -> list[bool]:
    """Per run of ``split``: is the hybrid's mean x/y RMSE below both the LSTM's and the model's?"""
    by_run: dict = {}
    for r in rows:
        if r["split"] == split and r["axis"] in "xy":
            by_run.setdefault(r["run"], {}).setdefault(r["method"], []).append(r["rmse_n"])
    return [np.mean(v["hybrid"]) < min(np.mean(v["lstm"]), np.mean(v["model"])) for v in by_run.values()]


def run_learn_bench(*, progress: Callable[[str], None] | None = None, data_dir=None, config=None,
                    figures_dir=None) -> dict:
    """Build the dataset, train LSTM and Hybrid, and compare with ModelBased on held-out runs.

    Parameters
    ----------
    progress : callable, optional
        Called with a label after each step.
    data_dir : str or Path, optional
        Dataset cache (default :func:`default_dataset_dir`).
    config : TrainConfig, optional
        Training settings.
    figures_dir : str or Path, optional
        Where to write the pocket and worst-outlier figures (default: a
        ``figures`` folder beside the dataset cache).

    Returns
    -------
    dict
        ``{"learn": {...}}`` for the bench JSON.
    """
    from drivesense.estimate import make
    from drivesense.identify.linear_axis import identify_axes
    from drivesense.learn.dataset import HELD_OUT_PROCESS, build_dataset, load_dataset
    from drivesense.sim.machining import simulate_air_moves

    data_dir = Path(data_dir or default_dataset_dir())
    t0 = time.perf_counter()
    index = build_dataset(data_dir, progress=None)
    build_s = time.perf_counter() - t0
    runs = [rec for _, rec in load_dataset(data_dir)]
    if progress:
        progress("dataset")
    axes = identify_axes(simulate_air_moves(seed=100))
    lstm, hybrid = make("lstm", config=config), make("hybrid", config=config)
    import tracemalloc

    tracemalloc.start()
    t0 = time.perf_counter()
    lstm.fit(runs)
    train_lstm = time.perf_counter() - t0
    if progress:
        progress("train lstm")
    t0 = time.perf_counter()
    hybrid.fit(runs, model_based=axes)
    train_hybrid = time.perf_counter() - t0
    peak_mb = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    if progress:
        progress("train hybrid")
    held = [r for r in runs if r.meta.get("split") in ("test", "test_process")]
    lstm.estimate(held[0])  # compile before timing
    t0 = time.perf_counter()
    for rec in held:
        lstm.estimate(rec)
    plain_infer_s = time.perf_counter() - t0
    # "model_paper": the same identified model with the paper's friction sign instead of the presliding state
    ev = evaluate_methods({"model": make("model", axes=axes), "model_paper": make("model", axes=axes, presliding=False),
                           "lstm": lstm, "hybrid": hybrid}, held)
    rows = ev["rows"]
    if progress:
        progress("evaluate")
    methods = ("model", "model_paper", "lstm", "hybrid")
    med = {m: _median_rmse(rows, m) for m in methods}
    mean = {m: float(np.mean([r["rmse_n"] for r in rows if r["method"] == m and r["split"] == "test"
                              and r["axis"] in "xy"])) for m in methods}
    pocket = {m: _median_rmse(rows, m, processes=("pocket_ccw",)) for m in methods}
    held_proc = {m: _median_rmse(rows, m, splits=("test_process",)) for m in methods}
    wins, wins_process = _hybrid_wins(rows, "test"), _hybrid_wins(rows, "test_process")
    figures = _figures(Path(figures_dir or data_dir.parent / "figures"), held, rows,
                       {"model": make("model", axes=axes), "lstm": lstm, "hybrid": hybrid})
    result = {
        "median_rmse": med, "mean_rmse": mean, "pocket_rmse": pocket, "held_out_process": HELD_OUT_PROCESS,
        "held_out_process_median_rmse": held_proc, "hybrid_best_fraction": float(np.mean(wins)) if wins else None,
        "hybrid_best_fraction_held_out_process": float(np.mean(wins_process)) if wins_process else None,
        "lstm_over_model_median": med["lstm"] / med["model"], "lstm_over_model_pocket": pocket["lstm"] / pocket["model"],
        "lstm_over_paper_model_median": med["lstm"] / med["model_paper"],
        "lstm_over_paper_model_pocket": pocket["lstm"] / pocket["model_paper"],
        "coverage_90": ev["coverage"], "train_seconds": train_lstm, "train_hybrid_seconds": train_hybrid,
        "train_peak_mb": peak_mb, "dataset_build_seconds": build_s, "dataset_bytes": index["bytes_on_disk"],
        "dataset_runs": len(runs), "held_out_runs": len(held),
        "infer_realtime_factor": ev["signal_seconds"] / plain_infer_s,
        "infer_with_intervals_realtime_factor": ev["signal_seconds"] / ev["infer_seconds"]["lstm"],
        "rows": rows, "figures": figures,
    }
    return {"learn": result}


def _figures(folder: Path, held, rows, estimators) -> list[str]:
    from drivesense.plot import plot_estimates, save_figure

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    pocket = next((r for r in held if r.meta.get("process") == "pocket_ccw"), None)
    worst = max((r for r in rows if r["method"] == "lstm" and r["axis"] in "xy"), key=lambda r: r["rmse_n"])
    worst_rec = next(r for r in held if r.meta.get("name") == worst["run"])
    for label, rec, ax in (("pocket", pocket, "x"), ("pocket", pocket, "y"), ("worst_lstm", worst_rec, worst["axis"])):
        if rec is None:
            continue
        truth = rec.with_channels({f"force_{ax}": filtered_target(rec, f"force_{ax}", aligned=False)})
        ests = {m: e.estimate(rec) for m, e in estimators.items()}
        fig = plot_estimates(truth, ests, channel=f"force_{ax}", zoom_s=min(6.0, rec.duration), max_freq=125.0,
                             title=f"{rec.meta.get('name')}: force_{ax}, model vs LSTM vs hybrid")
        path = save_figure(fig, folder / f"learn_{label}_{ax}.png")
        out.append(str(path))
    return out
