"""The built-in check of ``identify nc``: the physical model against the regression, on held-out data.

The regression (:class:`~drivesense.machine.regression_model.RegressionModel`)
is fitted on the same calibration cuts.  Both are scored sample by sample on
held-out data:

* the calibration segments, leave-one-segment-out (the same segments for
  both: each left-out segment predicted by a fit on the others), or with two
  calibration cuts or more, leave-one-cut-out (another program or material
  is what the next cut will be);
* the air cuts (force zero), which the regression never sees and the model
  scores leave-one-segment-out -- only their samples inside the calibration
  cuts' motion (speeds and accelerations of every axis no larger than in the
  cuts): a regression fitted at feed speed extrapolated to rapids says nothing
  about the next cut.

Within one cut the regression also learns how that cut's forces move together
(the process), which a held-out segment of the same cut rewards; the air cut
shows what it makes of motion without a process.

Three estimates per axis are compared: the model, the regression, and the
model while the axis slides with the regression while it stands
(``"sliding"``): a standing ball-screw axis's guides and nut hold the process
force by friction, so its own current does not see it, while the other axes'
currents do.  Sliding or not is decided on the calibration segments (only a
cut has a force for the guides to hold); the regression alone is taken only
where it also wins with the air cuts counted; either must beat the physics by
:data:`CHOICE_MARGIN`.  The choice is what
``estimate --per-axis auto`` takes, named in AXES.toml and the report.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivesense.identify.physical_fit import segment_ids
from drivesense.machine.controller_model import STANDING_SPEED
from drivesense.machine.regression_model import RegressionModel, regression_feature_names, regression_features
from drivesense.recording import Recording

__all__ = ["RegressionCheck", "compare_with_regression", "ENVELOPE_MARGIN", "CHOICE_MARGIN"]

#: An estimate replaces the physical model's only if it cuts the held-out RMSE by this share [-]: held-out segments
#: of the calibration cut reward what learns that cut's process, which the next part program does not share (on the
#: simulator a 16 % gain on the calibration segments was a 56 % loss on other programs).
CHOICE_MARGIN = 0.25
#: Ridge of the regression's leave-one-segment-out fits, relative to the scaled Gram matrix per sample [-].
REGRESSION_RIDGE = 1e-3
#: Air samples count when every axis's speed and acceleration are within this factor of the calibration cuts'.
ENVELOPE_MARGIN = 1.1
_NOTES = {"model": "the physical model wins on held-out data",
          "sliding": "the model while the axis slides, the regression while it stands (its guides hold the force "
                     "its current cannot see) wins on held-out data",
          "regression": "the regression wins on held-out data: --per-axis auto takes it on this axis"}


@dataclass
class RegressionCheck:
    """Result of :func:`compare_with_regression`.

    Attributes
    ----------
    regression : RegressionModel
        Fitted on every calibration cut.
    choice : dict of str to str
        Per axis ``"model"``, ``"sliding"`` or ``"regression"``: the smallest held-out error.
    report : dict
        Per axis: held-out NRMSE of each estimate, ``ratio`` (model / regression), ``choice``, ``note``.
    """

    regression: RegressionModel
    choice: dict
    report: dict


def _regression_held_out(cal: Sequence[Recording], axes: Sequence[str], features: Sequence[str], target) -> dict:
    """Per axis: the regression's error on every calibration sample [N] from a fit without its segment."""
    X = np.vstack([regression_features(r, features) for r in cal])
    scale = np.sqrt(np.mean(X ** 2, axis=0))
    scale[~(scale > 0)] = 1.0
    Xs = X / scale
    lengths = [r.n_samples for r in cal]
    # with two calibration cuts or more, whole cuts are left out (as the model's check does)
    seg = np.repeat(np.arange(len(cal)), lengths) if len(cal) >= 2 else segment_ids(lengths, cal[0].fs)
    out = {}
    for a in axes:
        y = target[a]
        err = np.full(y.size, np.nan)
        for g in np.unique(seg):
            held = seg == g
            if held.all():
                break
            # a small ridge on the columns scaled over the whole cut: a regressor that moves in the left-out segment
            # only (an approach move of an axis that otherwise stands) would else get a weight fitted to noise,
            # which the regression fitted on the whole cut does not have
            A = Xs[~held]
            w = np.linalg.solve(A.T @ A + REGRESSION_RIDGE * A.shape[0] * np.eye(A.shape[1]), A.T @ y[~held])
            err[held] = Xs[held] @ w - y[held]
        out[a] = err
    return out


def _envelope(air: Sequence[Recording], cal: Sequence[Recording]) -> np.ndarray:
    """Air samples inside the calibration cuts' motion: every axis's |v| and |a| within the cuts' (x margin)."""
    if not air:
        return np.zeros(0, dtype=bool)
    inside = np.ones(sum(r.n_samples for r in air), dtype=bool)
    for ch in (c for c in cal[0].channels if c.endswith(("_velocity", "_acceleration"))):
        if all(ch in r for r in air):
            limit = ENVELOPE_MARGIN * max(float(np.max(np.abs(r[ch]))) for r in cal)
            inside &= np.abs(np.concatenate([r[ch] for r in air])) <= limit
    return inside


def compare_with_regression(traces: Sequence[Recording], axes: Sequence[str], datas: Mapping, errors: Mapping,
                            fs: float, left_out: Mapping[str, str] | None = None) -> RegressionCheck | None:
    """Fit the regression on the calibration cuts and compare held-out errors with the model's, per axis.

    Parameters
    ----------
    traces : sequence of Recording
        All traces of the identification (the calibration cuts are those with ``force_*``).
    axes : sequence of str
        The traces' axes.
    datas : mapping
        Per axis, the identification's concatenated data (``force`` shifted by the identified delay,
        ``is_cal``, ``arrays``), so both methods are scored against the same reference.
    errors : mapping of str to ndarray
        Per identified axis, the model's held-out force error of every sample of ``datas`` [N] (NaN where a
        segment could not be left out).
    fs : float
        Trace rate [Hz].
    left_out : mapping of str to str, optional
        Axes the physical model could not be identified for, with the reason: the regression is all there is
        on them (choice ``"regression"``).

    Returns
    -------
    RegressionCheck or None
        None when no calibration cut holds every axis's force.
    """
    axes = [a for a in axes if a in errors or a in (left_out or {})]
    cal = [r for r in traces if all(f"force_{a}" in r for a in axes)]
    if not cal:
        return None
    air = [r for r in traces if not any(c.startswith("force_") for c in r.channels)]
    spindle = all("spindle_current" in r for r in cal)
    all_axes = [c[:-len("_current")] for c in cal[0].channels
                if c.endswith("_current") and c != "spindle_current" and f"{c[:-8]}_velocity" in cal[0]]
    features = regression_feature_names(all_axes, spindle)
    target = {a: datas[a].force[datas[a].is_cal] for a in axes}
    bounds = np.cumsum([0] + [r.n_samples for r in cal])
    runs = [{**{c: r[c] for c in r.channels}, **{f"force_{a}": target[a][bounds[i]:bounds[i + 1]] for a in axes}}
            for i, r in enumerate(cal)]
    regression = RegressionModel.fit(runs, axes, features)
    held = _regression_held_out(cal, axes, features, target)
    folds = "leave-one-cut-out" if len(cal) >= 2 else "leave-one-segment-out"
    inside = _envelope(air, cal)
    choice, report = {}, {}
    for a in axes:
        is_cal = datas[a].is_cal
        cal_reg = held[a]
        air_reg = np.concatenate([regression.predict(a, r) for r in air]) if air else np.zeros(0)
        standing = np.abs(datas[a].arrays[f"{a}_velocity"]) <= STANDING_SPEED
        ptp = float(np.ptp(target[a]))
        if a not in errors:
            ok = np.isfinite(cal_reg)
            rms = math.sqrt(float(np.mean(np.concatenate([cal_reg[ok], air_reg[inside]]) ** 2))) if ok.any() else math.nan
            choice[a] = "regression"
            report[a] = {"nrmse": {"regression": rms / ptp if ptp > 0 else None}, "choice": "regression",
                         "note": f"no physical model of axis {a} ({(left_out or {}).get(a, 'not identified')}): "
                                 "--per-axis auto takes the regression on this axis"}
            continue
        model = errors[a]
        reg = np.empty_like(model)
        reg[is_cal], reg[~is_cal] = cal_reg, air_reg
        use = np.isfinite(model) & np.isfinite(reg)
        use[~is_cal] &= inside
        candidates = {"model": model, "regression": reg, "sliding": np.where(standing, reg, model)}
        on_cal = use & is_cal
        if not on_cal.any():
            choice[a] = "model"
            report[a] = {"choice": "model", "note": "too few segments to compare with the regression"}
            continue
        rms = {k: math.sqrt(float(np.mean(e[use] ** 2))) for k, e in candidates.items()}
        rms_cal = {k: math.sqrt(float(np.mean(e[on_cal] ** 2))) for k, e in candidates.items()}
        # sliding or not is a question of forces the guides hold, which only a cut has: the calibration segments
        # decide it; the regression alone must also hold where no process is (the air cuts)
        physics = "sliding" if rms_cal["sliding"] < (1 - CHOICE_MARGIN) * rms_cal["model"] else "model"
        best = "regression" if rms["regression"] < (1 - CHOICE_MARGIN) * rms[physics] else physics
        choice[a] = best
        report[a] = {"nrmse": {k: v / ptp if ptp > 0 else None for k, v in rms.items()},
                     "calibration_nrmse": {k: v / ptp if ptp > 0 else None for k, v in rms_cal.items()},
                     "model_nrmse": rms["model"] / ptp if ptp > 0 else None,
                     "regression_nrmse": rms["regression"] / ptp if ptp > 0 else None,
                     "ratio": rms["model"] / rms["regression"] if rms["regression"] > 0 else math.inf,
                     "choice_ratio": rms[best] / rms["regression"] if rms["regression"] > 0 else math.inf,
                     "choice": best, "calibration_folds": folds,
                     "samples": {"calibration": int(np.sum(use & is_cal)),
                                                 "air_inside_the_cuts_motion": int(np.sum(use & ~is_cal)),
                                                 "standing": int(np.sum(use & standing))},
                     "note": _NOTES[best]}
    return RegressionCheck(regression=regression, choice=choice, report=report)
