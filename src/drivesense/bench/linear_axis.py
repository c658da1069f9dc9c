"""Linear-motor machine benchmark: four-step identification and ModelBased per process (third paper, Table 2).

The identification runs on simulated air moves, the processes on the full
simulator physics (LuGre friction with stiction and presliding, ripple,
drift and load dependence, cogging harmonics varying along the travel,
motor-constant droop, current-loop lag, yaw coupling, noise, quantisation,
run-to-run variation, a causal linear-phase anti-alias FIR in the NC trace logger);
ModelBased uses the *identified* model, presliding distance included; each
row also scores the same model with the paper's friction sign (``paper_*``).  Scores: RMSE [N], NRMSE (RMSE /
peak-to-peak of the reference over the scoring window) and max |F| of the
reference, per process and axis; the reference is the true force on the
workpiece, zero-phase low-passed at 120 Hz, delayed by the trace's declared
logger delay.  The scoring window starts 0.3 s after the first acceleration
ends (it includes the tool's entry into the material).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from drivesense.estimate.model_based import ModelBased
from drivesense.identify.linear_axis import run_identification
from drivesense.machine.linear_motor import AXES, ThreeAxisModel
from drivesense.recording import Recording
from drivesense.score import score_estimate
from drivesense.sim.machining import ProcessSettings, simulate_air_moves, simulate_process

__all__ = ["LINEAR_CASES", "run_linear_axis_bench", "identification_table", "score_process", "session_truth",
           "reversal_scores"]

#: Processes of the benchmark: (process, a_e [mm], a_p [mm], v_f [mm/min], n [1/min]), after Table 2.
LINEAR_CASES = (
    ("groove_+x", 10, 2, 800, 5400), ("groove_-x", 10, 2, 600, 5400), ("groove_+y", 10, 2, 700, 5000),
    ("groove_-y", 10, 1, 500, 3500), ("groove_+x+y", 10, 2, 600, 4500), ("groove_+x-y", 10, 1, 600, 5400),
    ("groove_-x+y", 10, 2, 600, 5400), ("groove_-x-y", 10, 2, 800, 6000),
    ("side_+x", 5, 2, 800, 5400), ("side_-x", 5, 3, 800, 6000), ("side_+y", 7, 2, 800, 5400),
    ("side_-y", 5, 5, 600, 5400), ("side_+x+y", 5, 2, 600, 4500), ("side_+x-y", 5, 4, 800, 5400),
    ("side_-x+y", 5, 3, 600, 4500), ("side_-x-y", 5, 4, 800, 6000),
    ("pocket_ccw", 2, 2, 600, 4500), ("ramp_-y+z", 10, 2, 600, 5000),
)
_PARAMS = ("k", "s_r", "m", "F_C", "F_br", "v_s", "sigma")
_TARGETS = {"k": 0.05, "s_r": 0.05, "m": 0.05, "stacked_m": 0.05, "F_C": 0.10, "F_br": 0.10, "v_s": 0.10,
            "sigma": 0.10, "cogging_amplitude": 0.10}


def identification_table(identified: ThreeAxisModel, true: ThreeAxisModel) -> dict:
    """Identified vs true values and relative errors, per axis.

    Parameters
    ----------
    identified : ThreeAxisModel
        Result of the identification.
    true : ThreeAxisModel
        The simulator's nominal model.

    Returns
    -------
    dict
        ``{ax: {param: {"identified", "true", "rel_error", "target", "ok"}}}``
        for k [N/m], s_r [m], m [kg], stacked_m [kg], F_C, F_br [N], v_s [m/s],
        sigma [N s/m] and the fundamental cogging amplitude [N].
    """
    out = {}
    si, st = identified.stacked_masses(), true.stacked_masses()
    for ax in AXES:
        a, b = identified.axis(ax), true.axis(ax)
        vals = {p: (getattr(a, p), getattr(b, p)) for p in _PARAMS}
        vals["stacked_m"] = (si[ax], st[ax])
        vals["cogging_amplitude"] = (float(a.cogging_amplitudes(1)[0]), float(b.cogging_amplitudes(1)[0]))
        out[ax] = {}
        for p, (got, want) in vals.items():
            rel = abs(got / want - 1.0)
            out[ax][p] = {"identified": float(got), "true": float(want), "rel_error": float(rel),
                          "target": _TARGETS[p], "ok": bool(rel <= _TARGETS[p])}
    return out


def session_truth(air_moves, nominal: ThreeAxisModel) -> ThreeAxisModel:
    """The true model of a simulated identification session: ``nominal`` with the session's varied values.

    Parameters
    ----------
    air_moves : sequence of Recording
        Simulated air moves (``meta["true_model"]``).
    nominal : ThreeAxisModel
        The preset's nominal model (cogging table, masses).

    Returns
    -------
    ThreeAxisModel
    """
    truth = air_moves[0].meta.get("true_model") if air_moves else None
    if not truth:
        return nominal
    return ThreeAxisModel(**{a: nominal.axis(a).with_values(**truth[a]) for a in AXES})


def score_process(estimate: Recording, trace: Recording, axis: str) -> dict:
    """RMSE, NRMSE and max |F| of one axis of a ModelBased estimate over the trace's scoring window.

    Parameters
    ----------
    estimate : Recording
        Output of :meth:`ModelBased.estimate`.
    trace : Recording
        The simulated trace with ``force_{axis}`` and ``meta["score_window"]``.
    axis : str
        Axis letter.

    Returns
    -------
    dict
        ``rmse_n`` [N], ``nrmse`` [-], ``max_abs_force_n`` [N], ``peak_to_peak_n`` [N].
    """
    ch = f"force_{axis}"
    window = tuple(trace.meta["score_window"])
    s = score_estimate(estimate, trace, channel=ch, window=window)
    t = trace.time
    sel = (t >= window[0]) & (t < window[1])
    return {"rmse_n": s.rmse_n, "nrmse": s.nrmse, "max_abs_force_n": float(np.max(np.abs(trace[ch][sel]))),
            "peak_to_peak_n": s.peak_to_peak_n}


def reversal_scores(estimate: Recording, trace: Recording, axis: str, *, half_width: float = 0.25,
                    min_speed: float = 5e-4) -> dict:
    """RMSE near the axis's velocity reversals inside the scoring window, and elsewhere in it.

    Parameters
    ----------
    estimate : Recording
        Output of :meth:`ModelBased.estimate`.
    trace : Recording
        The simulated trace (``{axis}_velocity``, ``force_{axis}``, ``score_window``).
    axis : str
        Axis letter.
    half_width : float
        Time around each reversal counted as "near" [s].
    min_speed : float
        The velocity must exceed this on both sides of a reversal, less than
        ``half_width`` apart [m/s].

    Returns
    -------
    dict
        ``reversals`` (count), ``rmse_reversal_n`` and ``rmse_elsewhere_n`` [N]
        (None where there is nothing to score).
    """
    from drivesense.score import aligned_reference

    t = trace.time
    start, end = trace.meta["score_window"]
    v = trace[f"{axis}_velocity"]
    sign = np.where(v > min_speed, 1, np.where(v < -min_speed, -1, 0))
    idx = np.flatnonzero(sign)
    flips = [int(b) for a, b in zip(idx[:-1], idx[1:])          # through zero, not stop-dwell-go
             if sign[a] != sign[b] and (b - a) / trace.fs <= half_width and start <= t[b] < end]
    err = estimate[f"force_{axis}"] - aligned_reference(trace[f"force_{axis}"], trace.fs, None,
                                                         float(estimate.meta.get("latency_s", 0.0)))
    inside = (t >= start) & (t < end)
    near = np.zeros(t.size, dtype=bool)
    for i in flips:
        near |= np.abs(t - t[i]) <= half_width
    rms = lambda sel: float(np.sqrt(np.mean(err[sel] ** 2))) if sel.any() else None
    return {"reversals": len(flips), "rmse_reversal_n": rms(inside & near), "rmse_elsewhere_n": rms(inside & ~near)}


def run_linear_axis_bench(progress: Callable[[str], None] | None = None, *, seed: int = 1,
                          settings: ProcessSettings | None = None, cases=LINEAR_CASES,
                          figure: str | Path | None = None) -> dict:
    """Identify the machine from air moves, then score ModelBased on every process (full physics).

    Parameters
    ----------
    progress : callable, optional
        Called with a label after the identification and after each process.
    seed : int
        Seed of the air moves and the processes.
    settings : ProcessSettings, optional
        Machine and controller (default: the preset with the full physics).
    cases : sequence of tuple
        ``(process, a_e [mm], a_p [mm], v_f [mm/min], n [1/min])``.
    figure : str or Path, optional
        Write the circular-pocket figure (estimate vs truth, x and y) here.

    Returns
    -------
    dict
        ``linear_axis``: rows ``{process, axis, moving, rmse_n, nrmse,
        max_abs_force_n, peak_to_peak_n, reversals, rmse_reversal_n,
        rmse_elsewhere_n, paper_rmse_n, paper_nrmse, a_e_mm, a_p_mm,
        v_f_mm_min, n_rpm}`` (``paper_*``: the same model with the paper's
        friction sign instead of the presliding state);
        ``linear_identify``: :func:`identification_table` against the
        session's true values (:func:`session_truth`) and against the preset's
        nominal ones, plus the per-step report; ``linear_identify_seconds``: wall time per axis;
        ``linear_summary``: the targets.
    """
    settings = settings or ProcessSettings()
    air = simulate_air_moves(seed=100 + seed, settings=settings)
    t0 = time.perf_counter()
    report = run_identification(air)
    t_ident = time.perf_counter() - t0
    if progress:
        progress("identify")
    table = identification_table(report.model, session_truth(air, settings.physics.model()))
    est = ModelBased(report.model)
    paper = ModelBased(report.model, presliding=False)     # the paper's friction sign, for comparison
    rows, pocket = [], None
    for k, (proc, ae, ap, vf, n) in enumerate(cases):
        trace = simulate_process(proc, ap * 1e-3, ae * 1e-3, vf / 60e3, float(n), seed=seed * 1000 + k,
                                 settings=settings)
        forces, forces_paper = est.estimate(trace), paper.estimate(trace)
        moving = trace.meta["moving_axes"]
        for ax in ("x", "y") + (("z",) if "z" in moving else ()):
            base = score_process(forces_paper, trace, ax)
            rows.append({"process": proc, "axis": ax, "moving": ax in moving, **score_process(forces, trace, ax),
                         **reversal_scores(forces, trace, ax),
                         "paper_rmse_n": base["rmse_n"], "paper_nrmse": base["nrmse"],
                         "a_e_mm": ae, "a_p_mm": ap, "v_f_mm_min": vf, "n_rpm": n})
        if proc == "pocket_ccw":
            pocket = (trace, forces)
        if progress:
            progress(proc)
    figures = []
    if figure is not None and pocket is not None:
        from drivesense.plot import plot_pocket_estimate, save_figure

        figures.append(str(save_figure(plot_pocket_estimate(pocket[0], pocket[1]), figure)))
    const = [r for r in rows if r["moving"] and r["process"].split("_")[0] in ("groove", "side")]
    const_all = [r for r in rows if r["process"].split("_")[0] in ("groove", "side")]
    standing = [r for r in rows if not r["moving"]]
    truth = session_truth(air, settings.physics.model())
    ident_ok = all(v["ok"] for ax in table.values() for v in ax.values())
    return {
        "linear_axis": rows,
        "linear_identify": {"table": table, "all_within_targets": ident_ok,
                            "table_vs_nominal": identification_table(report.model, settings.physics.model()),
                            "report": report.steps,
                            "presliding": {ax: {"identified_m": report.model.axis(ax).x_pre,
                                                "lugre_scale_m": _lugre_scale(settings, truth, ax)}
                                           for ax in AXES},
                            "physics": "full simulator physics, air moves of one session; 'table' compares with "
                                       "the session's true values (nominal with its run-to-run variation)"},
        "linear_identify_seconds": {"total": t_ident, **report.seconds},
        "linear_summary": {
            "constant_feed_moving_axis_worst_nrmse": max(r["nrmse"] for r in const) if const else None,
            "constant_feed_target_nrmse": 0.10,
            "constant_feed_within_target": bool(const) and all(r["nrmse"] <= 0.10 for r in const),
            "median_rmse_n": float(np.median([r["rmse_n"] for r in rows])),
            "reversal_rmse_n": {f"{r['process']}/{r['axis']}": [r["rmse_reversal_n"], r["rmse_elsewhere_n"]]
                                for r in rows if r["reversals"]},
            "constant_feed_worst_nrmse_standing_included": max(r["nrmse"] for r in const_all) if const_all else None,
            "standing_axis_median_nrmse": float(np.median([r["nrmse"] for r in standing])) if standing else None,
            "standing_axis_median_nrmse_paper_friction": float(np.median([r["paper_nrmse"] for r in standing]))
            if standing else None,
            "median_rmse_n_paper_friction": float(np.median([r["paper_rmse_n"] for r in rows])),
            "figures": figures,
        },
    }


def _lugre_scale(settings: ProcessSettings, truth: ThreeAxisModel, ax: str) -> list[float] | None:
    """The simulator's presliding length ``[F_C / sigma0, F_br / sigma0]`` [m] of axis ``ax`` (None without LuGre)."""
    fr = settings.physics.axis(ax).friction
    if fr is None or fr.sigma0 <= 0:
        return None
    a = truth.axis(ax)
    return [a.F_C / fr.sigma0, a.F_br / fr.sigma0]
