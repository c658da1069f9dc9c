"""``bench nc --real DIR``: the controller-rate model on real traces a user points it at, beside the regression.

A folder of controller exports of one machine (CSV read through a column
map, or drivesense's own ``.nc``/``.csv``): air cuts are the files whose name
says so (``aircut``, ``air_cut``, ``air-cut`` or ``_air``), every other file
with the three forces is a cut.  One calibration cut and one air cut identify
the model (``identify nc``: the air cut sharing the longest name prefix with
the calibration cut, unless given); the regression is fitted on the same
calibration cut; both, and the model with ``--per-axis auto``, are scored on
every other cut of the folder, per file and axis (NRMSE: RMSE over the
peak-to-peak of that file's reference, the reference delayed by the method's
latency), with the ratios to the regression.  Nothing here knows the data
set: the files, the map and the kinematics come from the user.
"""

from __future__ import annotations

import functools
import os
import re
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from drivesense.errors import ConfigError
from drivesense.recording import Recording

__all__ = ["run_real_nc_bench", "is_air_cut", "real_bench_files"]

AXES = ("x", "y", "z")
_AIR = re.compile(r"(^|[_\-. ])air([ _-]?cut)?([_\-. ]|$)", re.IGNORECASE)


def is_air_cut(path: str | Path) -> bool:
    """True when a file's name says it is an air cut (``*_Aircut_*``, ``air_cut``, ``..._air.csv``).

    Parameters
    ----------
    path : str or Path
        A trace file.
    """
    return bool(_AIR.search(Path(path).stem))


def real_bench_files(folder: str | Path, calibration: str | None = None, air: str | None = None) -> dict:
    """The folder's traces: ``calibration``, ``air`` and ``held_out`` (paths).

    Parameters
    ----------
    folder : str or Path
        The folder (``*.csv`` and ``*.nc``).
    calibration : str, optional
        The calibration cut's file name (default: the first cut by name).
    air : str, optional
        The air cut's file name (default: the air cut sharing the longest name prefix with the calibration cut).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"--real {folder}: not a folder")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".csv", ".nc") and p.is_file())
    airs = [p for p in files if is_air_cut(p)]
    cuts = [p for p in files if not is_air_cut(p)]
    if not cuts or not airs:
        raise ConfigError(f"--real {folder}: needs at least one cut and one air cut (a file named *aircut*), "
                          f"found {len(cuts)} cut(s) and {len(airs)} air cut(s)")
    by_name = {p.name: p for p in files}
    for option, name in (("--calibration", calibration), ("--air", air)):
        if name is not None and name not in by_name:
            raise ConfigError(f"{option} {name}: no such file in {folder} (it has {', '.join(by_name)})")
    cal = by_name[calibration] if calibration else cuts[0]
    if is_air_cut(cal):
        raise ConfigError(f"--calibration {cal.name}: that is an air cut; name a cut with forces")
    if air is not None and not is_air_cut(by_name[air]):
        raise ConfigError(f"--air {air}: not named as an air cut (*aircut*, *air_cut*, *_air*); it would be scored "
                          "as a held-out cut too: rename it or name another")
    if len(cuts) < 2:
        raise ConfigError(f"--real {folder}: no held-out cut besides the calibration cut {cal.name}; add the cuts to score")
    air_path = by_name[air] if air else max(airs, key=lambda p: (len(os.path.commonprefix([p.stem, cal.stem])),
                                                                   -airs.index(p)))
    return {"calibration": cal, "air": air_path, "held_out": [p for p in cuts if p != cal]}


def _train_hybrid(model, cal: Recording, cal_file: str, held_out: list, n: int, read, regression) -> tuple[dict, list]:
    """The hybrid on the calibration cut (and the held-out cut nearest to it by name whose reference frame is the
    calibration cut's), small-set defaults."""
    from drivesense.learn import Hybrid
    from drivesense.learn.model import TrainConfig

    extra_paths, extra = [], []
    for path in sorted(held_out, key=lambda p: -len(os.path.commonprefix([p.stem, cal.name or ""]))):
        if len(extra) >= n - 1:
            break
        rec = read(path)
        if all(f"force_{a}" in rec for a in AXES) and all(v["as_calibrated"] for v in
                                                           _frame(regression.estimate(rec), rec).values()):
            extra_paths.append(path)
            extra.append(rec)
    if len(extra) < n - 1:
        raise ConfigError(f"--hybrid {n}: no held-out cut with the calibration cut's reference frame to train on")
    started = time.perf_counter()
    est = Hybrid(config=TrainConfig(seed=0)).fit([cal, *extra], model_based=model)
    seconds = time.perf_counter() - started
    hist = est.model.history
    return {"estimator": est, "train_files": [cal_file, *(p.name for p in extra_paths)], "train_seconds": seconds,
            "epochs": hist.get("epochs"), "correction": hist.get("correction"), "validation": hist.get("validation"),
            "windows_per_epoch": est.model.config.windows_per_epoch}, extra


def _frame(est: Recording, ref: Recording) -> dict:
    """Which reference channel (and sign) each estimated axis follows best: a dynamometer frame turned against the
    calibration cut's shows as ``x -> -force_y`` (both methods then fail on that file, through no fault of theirs)."""
    out = {}
    for a in AXES:
        corr = {f"{'-' if c < 0 else '+'}force_{b}": abs(c) for b in AXES
                for c in [float(np.corrcoef(est[f"force_{a}"], ref[f"force_{b}"])[0, 1])]}
        best = max(corr, key=corr.get)
        out[a] = {"follows": best, "correlation": corr[best], "as_calibrated": best == f"+force_{a}"}
    return out


def _nrmse(est: Recording, ref: Recording) -> dict[str, float | None]:
    from drivesense.score import aligned_reference

    latency = float(est.meta.get("latency_s", 0.0))
    out = {}
    for a in AXES:
        if f"force_{a}" not in est.channels:       # an axis the method does not estimate (left out of the model)
            out[a] = None
            continue
        r = aligned_reference(ref[f"force_{a}"], ref.fs, None, latency)
        ptp = float(np.ptp(r))
        out[a] = float(np.sqrt(np.mean((est[f"force_{a}"] - r) ** 2))) / ptp if ptp > 0 else float("nan")
    return out


def run_real_nc_bench(folder: str | Path, *, columns: str | None = None, calibration: str | None = None,
                      air: str | None = None, vertical: str | None = None,
                      carries: Mapping[str, Sequence[str]] | None = None, bad_samples: str = "repair",
                      hybrid_cuts: int = 0, progress: Callable | None = None) -> dict:
    """Identify on one calibration cut and its air cut, score every other cut of the folder beside the regression.

    Parameters
    ----------
    folder : str or Path
        Folder of traces of one machine at one rate.
    columns : str, optional
        Column map of the CSV exports (a file or a shipped name, e.g. ``kit-dmc60h``).
    calibration, air : str, optional
        File names of the calibration cut and the air cut (see :func:`real_bench_files`).
    vertical : str, optional
        The vertical axis (``identify nc --vertical``).
    carries : mapping, optional
        Kinematics (``identify nc --carries``).
    bad_samples : {"refuse", "repair", "off"}
        What to do with physically impossible samples (real exports have some).
    hybrid_cuts : {0, 1, 2}
        Also train the hybrid on top of the identified model on this many cuts (the calibration cut, then the
        held-out cut sharing the longest name prefix with it, which is then no longer scored) with the small-set
        defaults, and score it on the remaining cuts beside the regression fitted on the same cuts.
    progress : callable, optional
        Called with a label after each file.

    Returns
    -------
    dict
        ``{"nc_real": {...}}``: the files, the identification (terms, active bounds, held-out check), per file and
        axis the NRMSE of regression, model and auto with the ratios, the pooled means and the targets.
    """
    from drivesense.estimate import ModelBased, Regression
    from drivesense.identify.controller import as_air_cut, identify_controller
    from drivesense.io import read_trace, resolve_column_map

    if hybrid_cuts not in (0, 1, 2):
        raise ConfigError(f"--hybrid {hybrid_cuts}: train the hybrid on 1 or 2 cuts (0: not at all)")
    files = real_bench_files(folder, calibration, air)
    if hybrid_cuts == 2 and len(files["held_out"]) < 2:
        raise ConfigError("--hybrid 2 trains on the calibration cut and one more: the folder needs two held-out cuts")

    column_map = resolve_column_map(columns) if columns is not None else None     # read once, checked first

    @functools.lru_cache(maxsize=None)      # a cut the hybrid trains on or checks is read once, not again
    def read(path: Path) -> Recording:
        return read_trace(path, columns=column_map, bad_samples=bad_samples)

    cal_rec, air_rec = read(files["calibration"]), as_air_cut(read(files["air"]))
    started = time.perf_counter()
    report = identify_controller([air_rec, cal_rec], vertical=vertical, carries=carries)
    identify_seconds = time.perf_counter() - started
    methods = {"regression": Regression(axes=AXES).fit([cal_rec]), "model": ModelBased(report.model),
               "auto": ModelBased(report.model, per_axis="auto")}
    held_out = list(files["held_out"])
    learned = None
    if hybrid_cuts and not all(a in methods["auto"].axes for a in AXES):
        learned = {"skipped": "the hybrid corrects an estimate of x, y and z; identify nc left out "
                              + ", ".join(a for a in AXES if a not in methods["auto"].axes)}
    elif hybrid_cuts:
        learned, extra = _train_hybrid(report.model, cal_rec, files["calibration"].name, held_out, hybrid_cuts, read,
                                       methods["regression"])
        methods["hybrid"] = learned.pop("estimator")
        methods["regression_same_cuts"] = Regression(axes=AXES).fit([cal_rec, *extra])
        held_out = [p for p in held_out if p.name not in learned["train_files"]]
        if progress:
            progress("nc real hybrid trained")
    compared = [m for m in methods if m != "regression"]
    rows = []
    for path in held_out:
        rec = read(path)
        if not all(f"force_{a}" in rec for a in AXES):
            continue
        estimates = {m: e.estimate(rec) for m, e in methods.items()}
        row = {"file": path.name, "samples": rec.n_samples,
               "nrmse": {m: _nrmse(est, rec) for m, est in estimates.items()},
               "reference_frame": _frame(estimates["regression"], rec)}
        row["ratio"] = {m: {a: None if row["nrmse"][m][a] is None else row["nrmse"][m][a] / row["nrmse"]["regression"][a]
                            for a in AXES} for m in compared}
        rows.append(row)
        if progress:
            progress(f"nc real {path.name}")
    if not rows:
        raise ConfigError(f"--real {folder}: no held-out cut with force_x/y/z besides the calibration cut")
    def ratios_of(m: str, axes=AXES) -> list[float]:
        return [r["ratio"][m][a] for r in rows for a in axes if r["ratio"][m][a] is not None]

    summary = {m: {"mean_ratio": float(np.mean(ratios_of(m))), "worst_ratio": float(max(ratios_of(m))),
                   "per_axis_mean_ratio": {a: float(np.mean(ratios_of(m, (a,)))) if ratios_of(m, (a,)) else None
                                           for a in AXES},
                   "axes_estimated": [a for a in AXES if ratios_of(m, (a,))]}
               for m in compared}
    if "hybrid" in methods:
        # the hybrid corrects auto's estimate (the regression where the physics lost or was left out)
        learned["over_model"] = {a: float(np.mean([r["nrmse"]["hybrid"][a] / r["nrmse"]["auto"][a] for r in rows]))
                                 for a in AXES}
        learned["over_regression_same_cuts"] = float(np.mean([r["nrmse"]["hybrid"][a]
                                                              / r["nrmse"]["regression_same_cuts"][a]
                                                              for r in rows for a in AXES]))
    masses = {a: report.model.axis(a).value(f"inertia_{a}") for a in report.model.axes}
    # model or auto: the one that estimates every axis and does better (auto, where the model left an axis out)
    full = [m for m in ("model", "auto") if len(summary[m]["axes_estimated"]) == len(AXES)]
    best = min(full, key=lambda m: (summary[m]["worst_ratio"], summary[m]["mean_ratio"])) if full else "auto"
    turned = [r["file"] for r in rows if not all(v["as_calibrated"] for v in r["reference_frame"].values())]
    targets = {
        "best_worst_axis_ratio": {"value": summary[best]["worst_ratio"], "method": best,
                                  "target": "<= 1 (model or auto, every file and axis)",
                                  "met": summary[best]["worst_ratio"] <= 1.0 and best in full},
        "best_mean_ratio": {"value": summary[best]["mean_ratio"], "method": best, "target": "<= 0.8",
                            "met": summary[best]["mean_ratio"] <= 0.8 and best in full},
        "masses_physical": {"value": masses, "target": ">= 0 on every axis", "met": all(m >= 0 for m in masses.values())},
        "identify_seconds": {"value": identify_seconds, "target": "< 10", "met": identify_seconds < 10.0}}
    if "hybrid" in methods:
        worst = max(learned["over_model"].values())
        targets["hybrid_mean_ratio"] = {"value": summary["hybrid"]["mean_ratio"], "target": "<= 0.7",
                                        "met": summary["hybrid"]["mean_ratio"] <= 0.7}
        targets["hybrid_over_model_worst_axis"] = {"value": worst, "target": "<= 1 (never worse than its model)",
                                                   "met": worst <= 1.0}
        targets["hybrid_train_seconds"] = {"value": learned["train_seconds"], "target": "<= 120",
                                           "met": learned["train_seconds"] <= 120.0}
    return {"nc_real": {
        "folder": str(folder), "columns": columns, "calibration": files["calibration"].name,
        "air": files["air"].name, "rate_hz": cal_rec.fs, "vertical": vertical,
        "carries": {k: list(v) for k, v in (carries or {}).items()},
        "identification": {"seconds": identify_seconds, "choice": dict(report.model.choice),
                           "regression_check": report.regression_check,
                           "axes": {a: {"K_m": r["K_m"], "terms": r["terms"], "active_bounds": r["active_bounds"],
                                        "dropped": r["dropped"], "held_out": r["held_out"]}
                                    for a, r in report.axes.items()}},
        "files": rows, "summary": summary, "targets": targets, "reference_frame_differs": turned, **({"hybrid": learned} if learned else {}),
        "baseline": "13-term least squares of each force on the x/y/z/spindle currents, sgn(v), v and a, fitted on "
                    "the calibration cut"}}
