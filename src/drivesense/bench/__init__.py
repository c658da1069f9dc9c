"""Benchmarks behind ``drivesense bench``: accuracy on the paper's conditions and speed ratios."""

from drivesense.bench.accuracy import ConditionResult, run_accuracy, run_condition
from drivesense.bench.machine import machine_info
from drivesense.bench.speed import run_speed

__all__ = ["run_accuracy", "run_condition", "ConditionResult", "run_speed", "machine_info", "run_bench",
           "BENCH_KINDS", "summarise"]


#: Parts of the bench, in the order ``all`` runs them.
BENCH_KINDS = ("accuracy", "speed", "identify", "learn", "wear", "io", "nc", "events", "monitor", "fleet")

#: Where each optional part lives: module and function returning a dict to merge into the bench JSON.
_PARTS = {"learn": ("drivesense.bench.learn", "run_learn_bench"),
          "wear": ("drivesense.bench.wear", "run_wear_bench"),
          "io": ("drivesense.bench.io", "run_io_bench"),
          "nc": ("drivesense.bench.nc", "run_nc_bench"),
          "events": ("drivesense.bench.events", "run_events_bench"),
          "monitor": ("drivesense.bench.monitor", "run_monitor_bench"),
          "fleet": ("drivesense.bench.fleet", "run_fleet_bench")}


def run_bench(kind: str = "all", *, axis=None, signal=None, progress=None) -> dict:
    """Run one part of the benchmark suite (or ``all``); returns the bench JSON as a dict.

    Parameters
    ----------
    kind : {"accuracy", "speed", "identify", "learn", "wear", "io", "nc", "events", "monitor", "fleet", "all"}
        Which part to run.
    axis : BallScrewAxis, optional
        Estimator axis parameters (default: Table 1).
    signal : SignalParams, optional
        Estimator signal chain (default: the paper's).
    progress : callable, optional
        Called with a label after each step.
    """
    from drivesense.errors import ConfigError
    from drivesense.machine.presets import table1_axis, table1_signal

    if kind not in (*BENCH_KINDS, "all"):
        raise ConfigError(f"unknown bench {kind!r}; choose {', '.join(BENCH_KINDS)} or all")
    axis = axis or table1_axis()
    signal = signal or table1_signal()
    out: dict = {"machine": machine_info(), "physics": "full simulator physics (see drivesense.sim.scenarios)"}
    if kind in ("accuracy", "all"):
        rows, _ = run_accuracy(axis, signal, progress=progress)
        out["accuracy"] = rows
        out["accuracy_summary"] = summarise(rows)
    if kind in ("speed", "all"):
        out["speed"] = run_speed(axis, signal)
        if progress:
            progress("speed")
    if kind in ("identify", "all"):
        from drivesense.bench.identify import run_frf_bench

        out["identify"] = run_frf_bench(progress=progress)
        try:
            from drivesense.bench.linear_axis import run_linear_axis_bench
        except ImportError:  # pragma: no cover - the linear-axis bench is added separately
            pass
        else:
            out.update(run_linear_axis_bench(progress=progress))
    for part, (module, function) in _PARTS.items():
        if kind in (part, "all"):
            import importlib

            try:
                runner = getattr(importlib.import_module(module), function)
            except (ImportError, AttributeError):
                if kind == part:
                    raise ConfigError(f"bench {part!r} is not available in this installation") from None
                continue
            out.update(runner(progress=progress))
    return out


def summarise(rows: list[dict]) -> dict:
    """Worst NRMSE per method and direction, and the cross-feed rigid/vibration ratio.

    Parameters
    ----------
    rows : list of dict
        One row per scenario and method (``scenario``, ``direction``,
        ``method``, ``nrmse``), as the accuracy bench writes them.

    Returns
    -------
    dict
    """
    summary: dict = {"worst_nrmse": {}, "cross_rigid_over_vibration_min": None}
    for r in rows:
        key = f"{r['method']}/{r['direction']}"
        summary["worst_nrmse"][key] = max(summary["worst_nrmse"].get(key, 0.0), r["nrmse"])
    ratios = []
    by = {(r["scenario"], r["method"]): r for r in rows}
    for (scen, method), r in by.items():
        if method == "rigid" and r["direction"] == "cross" and (scen, "vibration") in by:
            ratios.append(r["nrmse"] / by[(scen, "vibration")]["nrmse"])
    if ratios:
        summary["cross_rigid_over_vibration_min"] = min(ratios)
    return summary
