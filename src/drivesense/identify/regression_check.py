"""The built-in check of ``identify nc``: the physical model against the regression, on held-out segments.

The regression (:class:`~drivesense.machine.regression_model.RegressionModel`)
is fitted on the same calibration cuts.  Both are scored on held-out data: the
calibration segments leave-one-segment-out (the same segments for both: each
left-out segment predicted by a fit on the others), and the air cuts (force
zero), which the regression never sees and the model scores
leave-one-segment-out.  Within one cut the regression also learns that cut's
process (how its x, y and z forces move together), which a held-out
calibration segment rewards and the next part program does not; the air cut
shows what it makes of motion without a process.  The figure is RMSE over
the peak-to-peak of the calibration force.  Per axis the method with the smaller
held-out error is what ``estimate --per-axis auto`` takes; the report says
where the physics lost.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivesense.identify.physical_fit import segment_ids
from drivesense.machine.regression_model import RegressionModel, regression_feature_names, regression_features
from drivesense.recording import Recording

__all__ = ["RegressionCheck", "compare_with_regression"]


@dataclass
class RegressionCheck:
    """Result of :func:`compare_with_regression`.

    Attributes
    ----------
    regression : RegressionModel
        Fitted on every calibration cut.
    choice : dict of str to str
        Per axis ``"model"`` or ``"regression"``: the smaller held-out error.
    report : dict
        Per axis: ``model_nrmse``, ``regression_nrmse``, ``ratio`` (model / regression), ``choice``, ``note``.
    """

    regression: RegressionModel
    choice: dict
    report: dict


def _regression_held_out(cal: Sequence[Recording], axes: Sequence[str], features: Sequence[str], shift) -> dict:
    """Per axis: squared error sum of the regression over left-out segments [N^2], with the sample count."""
    X = np.vstack([regression_features(r, features) for r in cal])
    seg = segment_ids([r.n_samples for r in cal], cal[0].fs)
    out = {}
    for a in axes:
        y = np.concatenate([shift(r, a) for r in cal])
        sse = 0.0
        for g in np.unique(seg):
            held = seg == g
            if held.all():
                return {}
            w, *_ = np.linalg.lstsq(X[~held], y[~held], rcond=None)
            e = X[held] @ w - y[held]
            sse += float(e @ e)
        out[a] = (sse, y.size, float(np.ptp(y)))
    return out


def compare_with_regression(traces: Sequence[Recording], axes: Sequence[str], datas: Mapping, reports: Mapping,
                            fs: float, left_out: Mapping[str, str] | None = None) -> RegressionCheck | None:
    """Fit the regression on the calibration cuts and compare its held-out error with the model's, per axis.

    Parameters
    ----------
    traces : sequence of Recording
        All traces of the identification (the calibration cuts are those with ``force_*``).
    axes : sequence of str
        Identified axes.
    datas : mapping
        Per axis, the identification's concatenated data (its ``force`` shifted by the identified delay and
        ``is_cal``), so both methods are scored against the same reference.
    reports : mapping
        Per axis, the identification report (``held_out.calibration_force_rms_n``, ``K_m``).
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
    cal = [r for r in traces if all(f"force_{a}" in r for a in axes)]
    if not cal:
        return None
    spindle = all("spindle_current" in r for r in cal)
    all_axes = sorted({c[:-len("_current")] for c in cal[0].channels
                       if c.endswith("_current") and c != "spindle_current" and f"{c[:-8]}_velocity" in cal[0]})
    features = regression_feature_names(all_axes, spindle)
    forces = {a: datas[a].force[datas[a].is_cal] for a in axes}
    offsets = np.cumsum([0] + [r.n_samples for r in cal])

    def shift(rec: Recording, a: str) -> np.ndarray:
        i = next(k for k, r in enumerate(cal) if r is rec)
        return forces[a][offsets[i]:offsets[i + 1]]

    regression = RegressionModel.fit([{**{c: r[c] for c in r.channels}, **{f"force_{a}": shift(r, a) for a in axes}}
                                      for r in cal], axes, features)
    held = _regression_held_out(cal, axes, features, shift)
    air = [r for r in traces if not any(c.startswith("force_") for c in r.channels)]
    choice, report = {}, {}
    for a in axes:
        if a not in reports:
            sse, n, ptp = held.get(a, (math.nan, 1, math.nan))
            choice[a] = "regression"
            report[a] = {"model_nrmse": None, "regression_nrmse": math.sqrt(sse / n) / ptp if ptp > 0 else None,
                         "choice": "regression",
                         "note": f"no physical model of axis {a} ({(left_out or {}).get(a, 'not identified')}): "
                                 "--per-axis auto takes the regression on this axis"}
            continue
        ho = reports[a]["held_out"]
        model_rms = ho.get("calibration_force_rms_n")
        if a not in held or model_rms is None:
            choice[a] = "model"
            report[a] = {"choice": "model", "note": "too few calibration segments to compare with the regression"}
            continue
        sse, n, ptp = held[a]
        cal_reg_rms = math.sqrt(sse / n)
        air_reg = [regression.predict(a, r) for r in air]
        if air_reg and ho.get("air_force_rms_n") is not None:
            # the air cuts are held out for the regression as they stand (never fitted on): force 0
            n_air = sum(e.size for e in air_reg)
            sse += sum(float(e @ e) for e in air_reg)
            n += n_air
            model_rms = math.sqrt((model_rms ** 2 * ho["samples_calibration_held_out"]
                                   + ho["air_force_rms_n"] ** 2 * ho["samples_air_held_out"])
                                  / (ho["samples_calibration_held_out"] + ho["samples_air_held_out"]))
        reg_rms = math.sqrt(sse / n)
        ratio = model_rms / reg_rms if reg_rms > 0 else math.inf
        choice[a] = "model" if ratio <= 1.0 else "regression"
        report[a] = {"model_nrmse": model_rms / ptp if ptp > 0 else None,
                     "regression_nrmse": reg_rms / ptp if ptp > 0 else None,
                     "model_rms_n": model_rms, "regression_rms_n": reg_rms, "ratio": ratio, "choice": choice[a],
                     "calibration_only": {"model_rms_n": ho["calibration_force_rms_n"], "regression_rms_n": cal_reg_rms},
                     "note": ("the physical model wins on held-out data (calibration segments and air cuts)" if ratio <= 1.0 else
                              f"the physical model loses to the regression ({ratio:.2f}x its held-out error): "
                              "--per-axis auto takes the regression on this axis")}
    return RegressionCheck(regression=regression, choice=choice, report=report)
