"""Identification benchmark: the ball-screw FRF fit against the simulator's true parameters.

Each excitation (chirp, multisine, PRBS) runs on the full-physics simulator;
the fit gets only the catalogue values ``K_t`` and lead.  The axis identified
from the chirp then drives ``VibrationMode`` over the ten cutting conditions,
to show the identified parameter file is good enough to estimate force.
"""

from __future__ import annotations

from typing import Callable

from drivesense.bench.accuracy import run_accuracy
from drivesense.identify.frf import FIT_PARAMETERS, fit_frf, measure_frf
from drivesense.sim.excitation import EXCITATIONS
from drivesense.sim.scenarios import ScenarioSettings, simulate_frf_excitation

__all__ = ["run_frf_bench", "FRF_TARGETS"]

#: Relative tolerances of the issue (T_b: absolute, in s).
FRF_TARGETS = {"J_r": 0.02, "M_t": 0.02, "K_r": 0.02, "C_t": 0.10, "C_k": 0.10, "D_r": 0.10, "T_b": 0.02e-3}


def run_frf_bench(*, seed: int = 2, progress: Callable[[str], None] | None = None) -> dict:
    """Identify the Table 1 stage from simulated excitation and score the result.

    Parameters
    ----------
    seed : int
        Seed of the excitation runs.
    progress : callable, optional
        Called with a label after each step.

    Returns
    -------
    dict
        ``{"frf": [per excitation: values, errors, within_targets, seconds],
        "targets": ..., "vibration_with_identified": [rows], "vibration_with_identified_worst_nrmse": ...}``.
    """
    settings = ScenarioSettings()
    rows, chirp_fit = [], None
    for kind in EXCITATIONS:
        rec = simulate_frf_excitation(kind, settings, seed=seed)
        true = rec.meta["true_axis"]
        true_tb = rec.meta["true_signal"]["T_b"]
        measured = measure_frf(rec, K_t=true["K_t"], lead=true["lead"])
        fit = fit_frf(measured, K_t=true["K_t"], lead=true["lead"])
        errors = {p: fit.values[p] / true[p] - 1.0 for p in FIT_PARAMETERS if p != "T_b"}
        errors["T_b"] = fit.values["T_b"] - true_tb
        ok = {p: abs(errors[p]) <= FRF_TARGETS[p] for p in FRF_TARGETS}
        rows.append({"excitation": kind, "values": fit.values, "true": {**true, "T_b": true_tb},
                     "error": errors, "within_targets": ok, "all_within_targets": all(ok.values()),
                     "normalised_rms": fit.normalised_rms, "seconds": fit.seconds,
                     "n_frequencies": int(measured.freq.size)})
        if kind == "chirp":
            chirp_fit = fit
        if progress:
            progress(f"frf {kind}")
    acc, _ = run_accuracy(chirp_fit.axis, chirp_fit.signal, methods=("vibration",))
    if progress:
        progress("vibration with identified axis")
    return {"frf": rows, "targets": FRF_TARGETS,
            "vibration_with_identified": [{k: r[k] for k in ("scenario", "direction", "rmse_n", "nrmse")}
                                          for r in acc],
            "vibration_with_identified_worst_nrmse": max(r["nrmse"] for r in acc)}
