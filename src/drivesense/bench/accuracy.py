"""Accuracy benchmark: every estimator on the ten end-milling conditions, full physics.

For feed conditions each estimator builds its friction map from three idling
runs; for cross-feed conditions (X stands) it takes a tare before the cut.
Scores are RMSE [N] and NRMSE against the simulator's true force, low-passed
like the estimate and delayed by the estimate's declared latency, over each
scenario's scoring window (start-up transients excluded).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from drivesense.estimate import SignalParams, available, make
from drivesense.estimate.design import lowpass_sos
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.milling import tooth_passing_frequency
from drivesense.recording import Recording
from drivesense.score import score_estimate
from drivesense.sim.scenarios import CutCondition, ScenarioSettings, paper_conditions, simulate_cut, simulate_idle

__all__ = ["ConditionResult", "run_condition", "run_accuracy"]


@dataclass
class ConditionResult:
    """Everything computed for one condition.

    Attributes
    ----------
    condition : CutCondition
    cut : Recording
        The simulated cut (drive signals and true force).
    estimates : dict of str to Recording
        Estimate per method.
    rows : list of dict
        One accuracy row per method (``scenario, direction, method, rmse_n,
        nrmse, max_abs_error_n, peak_to_peak_n, harmonic_error, latency_s``).
    idle_repeatability_n : dict of str to float
        Run-to-run repeatability of each method's friction map [N] (feed only).
    friction_maps : dict of str to FrictionMap
        Each method's friction map (feed only).
    """

    condition: CutCondition
    cut: Recording
    estimates: dict[str, Recording] = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)
    idle_repeatability_n: dict[str, float] = field(default_factory=dict)
    friction_maps: dict = field(default_factory=dict)


def run_condition(cond: CutCondition, axis: BallScrewAxis, signal: SignalParams,
                  settings: ScenarioSettings | None = None, *, seed: int = 1,
                  methods: tuple[str, ...] | None = None) -> ConditionResult:
    """Simulate one condition (cut and, for feed, 3 idle runs) and score every method.

    Parameters
    ----------
    cond : CutCondition
        The cutting condition.
    axis : BallScrewAxis
        Axis parameters the estimators use.
    signal : SignalParams
        The estimators' phase-lag compensation and low-pass.
    settings : ScenarioSettings, optional
        Simulated physics and signal chain (default: full physics).
    seed : int, optional
        Seed of the cut; the idle runs use ``1000 + 10 * seed`` onwards.
    methods : tuple of str, optional
        Estimator names (default: every ball-screw method).

    Returns
    -------
    ConditionResult
    """
    settings = settings or ScenarioSettings()
    cut = simulate_cut(cond, settings, seed=seed)
    idle = simulate_idle(cond, settings, seed=1000 + 10 * seed) if cond.direction == "feed" else None
    sos = lowpass_sos(signal, cut.fs)
    tooth_pass = tooth_passing_frequency(cond.spindle_rpm, settings.tool.flutes)
    result = ConditionResult(cond, cut)
    for method in methods or available("ballscrew"):
        est = make(method, axis=axis, signal=signal)
        if idle is not None:
            est.fit(idle)
            result.idle_repeatability_n[method] = est.friction_map.repeatability_rms
            result.friction_maps[method] = est.friction_map
        else:
            est.tare(cut, *cut.meta["tare_window"])
        out = est.estimate(cut)
        result.estimates[method] = out
        s = score_estimate(out, cut, sos=sos, tooth_pass_hz=tooth_pass, cutoff_hz=signal.lpf_hz)
        row = {"scenario": cond.name, "direction": cond.direction, "method": method}
        row.update({k: v for k, v in s.to_dict().items() if k != "window"})
        row["latency_s"] = out.meta["latency_s"]
        if method in result.idle_repeatability_n:
            row["friction_map_repeatability_n"] = result.idle_repeatability_n[method]
        result.rows.append(row)
    return result


def run_accuracy(axis: BallScrewAxis, signal: SignalParams, settings: ScenarioSettings | None = None, *,
                 conditions: list[CutCondition] | None = None, seed: int = 1, methods: tuple[str, ...] | None = None,
                 progress: Callable[[str], None] | None = None,
                 keep: bool = False) -> tuple[list[dict], list[ConditionResult]]:
    """Run :func:`run_condition` over the paper's ten conditions.

    Parameters
    ----------
    axis, signal
        Estimator parameters (what the user believes about the axis).
    settings : ScenarioSettings, optional
        Simulator physics (default: full physics of the Table 1 stage).
    conditions : list of CutCondition, optional
        Default :func:`~drivesense.sim.scenarios.paper_conditions`.
    seed : int
        Seed of the cuts.
    methods : sequence of str
        Estimators to run (default: every ball-screw method).
    progress : callable, optional
        Called with each condition's name when it is done.
    keep : bool
        Keep the recordings (for figures); otherwise only rows are kept.

    Returns
    -------
    rows : list of dict
    results : list of ConditionResult
        Empty unless ``keep``.
    """
    rows, results = [], []
    for cond in conditions or paper_conditions():
        res = run_condition(cond, axis, signal, settings, seed=seed, methods=methods)
        rows.extend(res.rows)
        if keep:
            results.append(res)
        if progress:
            progress(cond.name)
    return rows, results
