"""Identify the controller-rate machine model from a calibration cut and ordinary air cuts.

::

    report = ds.identify.identify_controller([air_cut, calibration_cut])
    ds.io.write_axes_file("AXES.toml", report.model)      # feeds ModelBased / estimate --method model

Per axis the logged current is linear in the parameters
(:mod:`drivesense.machine.controller_model`)::

    I = sum_j theta_j phi_j + c F,        K_m = 1 / c,   p_j = theta_j / c

so every trace contributes, with or without forces: an air cut (no ``force_*``
channel: ``F = 0``) determines the ``theta_j`` (friction, masses, the weight
and offsets, ripple) in amperes; a calibration cut (``force_<axis>`` from a
dynamometer) adds ``c``, the force constant with the controller's sign.  No
dedicated moves are needed: whatever the part program excites is used, and
more moves determine more terms.

The model is physical by construction (:mod:`drivesense.identify.physical_fit`):
a bounded, regularised least-squares problem per axis with one sign of
``K_m``, masses and friction levels >= 0, the air cuts first and the
calibration cuts shrunk towards them, and the machine's kinematics as bounds
(:mod:`drivesense.identify.kinematics`).  Where a bound is active the report
says which term and why.  The confidence intervals account for the
autocorrelation of the residual (effective sample size).

A candidate term is left out, with the reason, when:

* *not excited* -- the traces do not move the axis that way (no reversal in
  one direction, too little travel for a ripple period, no slow motion for a
  Stribeck curve, another axis that never accelerates);
* *indistinguishable* -- collinear with the kept terms (variance inflation);
* *left out by held-out error* -- the leave-one-segment-out error over the air
  and calibration segments is no worse without it
  (:mod:`drivesense.identify.term_choice`).

The offset and the axis's own inertia are always kept.  The non-linear
settings are chosen by the fit: the logging window (point samples or the
trace interval), the delay of the drive channels behind the force reference
(calibration cuts only; it becomes the estimate's latency), the Stribeck
velocity and the ripple period (a search over spatial periods, or given).
Beside the model, the regression every user could write is fitted on the
same calibration cuts and both are compared on held-out data
(:mod:`drivesense.identify.regression_check`); the per-axis winner is stored
for ``estimate --per-axis auto``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from drivesense.errors import ConfigError, IdentificationError, MissingChannelError
from drivesense.identify.excitation import STRIBECK_SPEEDS, SLIDING_SPEED, best_period, unexcited_terms
from drivesense.identify.kinematics import carried_first, check_kinematics, mass_floor, merge_bounds, offset_bound
from drivesense.identify.least_squares import LeastSquaresFit, residual_variance, solve_least_squares
from drivesense.identify.physical_fit import (AxisProblem, Constraints, drive_sign, fit_bounded, held_out_residuals,
                                             segment_ids)
from drivesense.identify.term_choice import choose_terms, physical_terms, term_table
from drivesense.identify.regression_check import compare_with_regression
from drivesense.machine.controller_model import (ControllerAxis, ControllerModel, axis_direction, feature_column,
                                                 friction_direction)
from drivesense.recording import Recording

__all__ = ["identify_controller", "ControllerIdentification", "MIN_RATE_HZ", "trace_axes", "is_calibration_cut",
           "as_air_cut"]

#: Lowest trace rate the identification accepts [Hz].
MIN_RATE_HZ = 25.0
#: Terms kept whatever their held-out error (with the axis's own mass).
_STRUCTURAL = ("offset",)
#: Friction, masses and offsets from the air cuts alone, then the force constant (when both kinds are given).
TWO_STAGE = True
#: A delay of the drive channels behind the force is taken only if it cuts the base residual by this share [-].
DELAY_GAIN = 0.05
#: Presliding distances tried [m] (0: the window-mean sign of the velocity).
_PRESLIDING = (0.0, 2e-6, 5e-6, 10e-6, 20e-6, 50e-6, 100e-6)
#: Relaxation times of the friction held at standstill tried [s] (0: none).
_HOLD_TIMES = (0.0, 0.3, 1.0, 3.0, 10.0)


@dataclass
class ControllerIdentification:
    """Result of :func:`identify_controller`.

    Attributes
    ----------
    model : ControllerModel
        The identified model.
    axes : dict
        Per axis: ``terms`` (name -> value, ci95, unit, air-cut value), ``K_m`` and its
        ``K_m_ci95`` [N/A], ``K_m_source``, ``force_sign``, ``active_bounds`` (name -> why),
        ``dropped`` (name -> reason), the held-out error, the chosen ridge and shrinkage,
        residual RMS on the air and calibration samples [A] and [N], sample counts.
    limits : list of str
        What the trace rate cannot resolve.
    warnings : list of str
        Axes left out (with the reason).
    seconds : float
        Wall time of the identification [s].
    regression_check : dict
        Per axis, the held-out error of the model and of the regression on the
        calibration segments, their ratio and the method ``--per-axis auto`` takes.
    kinematics : dict
        The vertical axis and which axis carries which, as given.
    """

    model: ControllerModel
    axes: dict
    limits: list
    warnings: list = field(default_factory=list)
    seconds: float = 0.0
    regression_check: dict = field(default_factory=dict)
    kinematics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain types for JSON."""
        return {"model": self.model.to_dict(), "axes": self.axes, "limits": list(self.limits),
                "warnings": list(self.warnings), "seconds": float(self.seconds),
                "regression_check": self.regression_check, "kinematics": self.kinematics}


def trace_axes(rec: Recording) -> list[str]:
    """Axis letters of a controller trace: every ``<a>_current`` with ``<a>_velocity`` and ``<a>_acceleration``.

    Parameters
    ----------
    rec : Recording
        A trace.
    """
    out = []
    for ch in rec.channels:
        if ch.endswith("_current") and ch != "spindle_current":
            a = ch[:-len("_current")]
            if f"{a}_velocity" in rec and f"{a}_acceleration" in rec:
                out.append(a)
    return out


# ------------------------------------------------------------------ data
@dataclass
class _AxisData:
    """Concatenated samples of one axis: channels, force reference (NaN-free) and which samples are calibration."""

    arrays: dict
    force: np.ndarray        # shifted force reference [N] (0 on air samples)
    is_cal: np.ndarray       # bool
    starts: np.ndarray       # first sample of each trace (the presliding state restarts there)


def _shifted(force: np.ndarray, delay_samples: float) -> np.ndarray:
    """``F(t - d)``: the reference delayed like the drive channels, by linear interpolation (ends held)."""
    if delay_samples == 0:
        return force
    idx = np.arange(force.size, dtype=float)
    return np.interp(idx - delay_samples, idx, force)


def _axis_data(traces: Sequence[Recording], axis: str, channels: Sequence[str], delay_samples: float) -> _AxisData:
    parts: dict[str, list] = {c: [] for c in channels}
    force, is_cal = [], []
    for rec in traces:
        has_force = is_calibration_cut(rec)
        if has_force and f"force_{axis}" not in rec:
            continue        # a cut without this axis's force: its load on the axis is unknown
        for c in channels:
            parts[c].append(np.asarray(rec[c], dtype=float))
        n = rec.n_samples
        force.append(_shifted(np.asarray(rec[f"force_{axis}"], dtype=float), delay_samples) if has_force
                     else np.zeros(n))
        is_cal.append(np.full(n, has_force))
    if not force:
        raise IdentificationError(f"axis {axis}: no trace can be used (every cut lacks force_{axis})")
    starts = np.cumsum([0] + [f.size for f in force[:-1]])
    return _AxisData({c: np.concatenate(v) for c, v in parts.items()}, np.concatenate(force), np.concatenate(is_cal),
                     starts)


def _velocity_noise(velocity: np.ndarray) -> float:
    """Standstill noise of a logged velocity [m/s]: robust spread of the slow samples, at least 10 um/s."""
    slow = velocity[np.abs(velocity) < 5e-4]
    if slow.size < 10:
        return 1e-5
    mad = 1.4826 * float(np.median(np.abs(slow - np.median(slow))))
    return max(4.0 * mad, 1e-5)


# ------------------------------------------------------------------ one axis
@dataclass
class _Settings:
    window_s: float
    v_eps: float
    v_s: float = 0.0
    period: float = 0.0
    x_pre: float = 0.0
    hold_time: float = 0.0
    fs: float = 1.0


def _direction(axis: str, data: _AxisData, st: _Settings) -> np.ndarray:
    """Friction direction over the concatenated traces, the presliding state restarting with each trace."""
    if st.x_pre <= 0:
        return friction_direction(data.arrays[f"{axis}_velocity"], data.arrays[f"{axis}_acceleration"],
                                  st.window_s, st.v_eps)
    bounds = [*data.starts, data.force.size]
    pos = data.arrays[f"{axis}_position"]
    decay = math.exp(-1.0 / (st.fs * st.hold_time)) if st.hold_time > 0 else 1.0
    return np.concatenate([axis_direction(axis, {f"{axis}_position": pos[a:b]}, window_s=st.window_s, v_eps=st.v_eps,
                                          x_pre=st.x_pre, hold_decay=decay) for a, b in zip(bounds[:-1], bounds[1:])])


def _columns(names, axis, data: _AxisData, st: _Settings) -> np.ndarray:
    d = _direction(axis, data, st)
    return np.column_stack([feature_column(n, axis, data.arrays, window_s=st.window_s, v_eps=st.v_eps, v_s=st.v_s,
                                           period=st.period, direction=d) for n in names])


def _fit_terms(names, axis, data: _AxisData, st: _Settings, km: float | None) -> LeastSquaresFit:
    X = _columns(names, axis, data, st)
    y = data.arrays[f"{axis}_current"]
    if km is not None:
        return solve_least_squares(X, y - data.force / km, list(names))
    return _fit_matrix(X, y, data, list(names), axis, st.v_eps)


def _fit_matrix(X: np.ndarray, y: np.ndarray, data: _AxisData, names: list, axis: str, v_eps: float) -> LeastSquaresFit:
    """Air cuts and calibration cuts together: two stages when both are there in numbers, else jointly."""
    air = ~data.is_cal
    if TWO_STAGE and air.sum() >= max(10 * len(names), 200) and data.is_cal.sum() >= 50:
        sliding = data.is_cal & (np.abs(data.arrays[f"{axis}_velocity"]) > max(50.0 * v_eps, SLIDING_SPEED))
        return _two_stage(X, y, data, names, sliding if sliding.sum() >= 50 else data.is_cal)
    return solve_least_squares(np.column_stack([X, data.force]), y, [*names, "c"])


def _two_stage(X: np.ndarray, y: np.ndarray, data: _AxisData, names: list, sliding: np.ndarray) -> LeastSquaresFit:
    """The machine terms from the air cuts alone (no force to confuse them), then ``c`` on the sliding calibration samples.

    In a cut the process force and the friction direction flip together with
    the feed direction, so a joint fit trades the force constant against the
    friction level; the air cut, with the same moves and no force, fixes the
    friction first.  A standing axis shares a process force with its guides'
    and nut's presliding spring, so the force constant comes from the samples
    where the axis slides (friction at its sliding level).
    """
    air, cal = ~data.is_cal, data.is_cal
    first = solve_least_squares(X[air], y[air], names)
    r = y[sliding] - X[sliding] @ first.theta
    f = data.force[sliding]
    ff = float(f @ f)
    if ff <= 0:
        raise IdentificationError("the calibration cuts hold no force while the axis slides")
    c = float(f @ r) / ff
    res_cal = y[cal] - X[cal] @ first.theta - c * data.force[cal]
    s2 = residual_variance(r - c * f, 1)
    k = len(names)
    cov = np.zeros((k + 1, k + 1))
    cov[:k, :k] = first.cov
    cov[k, k] = s2 / ff
    residual = np.empty_like(y)
    residual[air] = first.residual
    residual[cal] = res_cal
    return LeastSquaresFit([*names, "c"], np.append(first.theta, c), cov, residual, float(residual @ residual))


def _identify_axis(axis: str, others: Sequence[str], data: _AxisData, window_s: float, fs: float,
                   km: float | None, period: float | None, bounds: Mapping | None = None
                   ) -> tuple[ControllerAxis, dict, list]:
    st = _Settings(window_s=window_s, v_eps=_velocity_noise(data.arrays[f"{axis}_velocity"]), fs=fs)
    dropped = unexcited_terms(axis, others, data.arrays, st.window_s, st.v_eps, fs)
    base = [n for n in ("offset", f"inertia_{axis}", "coulomb_pos", "coulomb_neg", "viscous") if n not in dropped]
    optional = [n for n in ("position", *(f"inertia_{b}" for b in others)) if n not in dropped]
    names = base + optional
    # presliding: the Dahl state of the logged position (friction kept at standstill), if it fits better
    if f"{axis}_position" in data.arrays and "coulomb_pos" in names:
        rss = {}
        for x_pre in _PRESLIDING:
            for hold in _HOLD_TIMES if x_pre > 0 else (0.0,):
                st.x_pre, st.hold_time = x_pre, hold
                rss[(x_pre, hold)] = _fit_terms(names, axis, data, st, km).rss
        st.x_pre, st.hold_time = min(rss, key=rss.get)
    # Stribeck velocity: the best of a grid (same number of parameters)
    if "stribeck" not in dropped:
        rss = {}
        for vs in STRIBECK_SPEEDS:
            st.v_s = vs
            rss[vs] = _fit_terms([*names, "stribeck"], axis, data, st, km).rss
        st.v_s = min(rss, key=rss.get)
        names.append("stribeck")
    # position-periodic terms at the strongest spatial period of the residual
    if "ripple" not in dropped:
        fit = _fit_terms(names, axis, data, st, km)
        st.period, why = best_period(axis, data.arrays, st.window_s, st.v_eps, fit.residual, period)
        if st.period > 0:
            names += ["ripple1_sin", "ripple1_cos", "ripple2_sin", "ripple2_cos"]
        else:
            dropped["ripple"] = why
    keep = [*_STRUCTURAL, f"inertia_{axis}", *(n for n in ("coulomb_pos", "coulomb_neg") if n in names)]
    v = data.arrays[f"{axis}_velocity"]
    sliding = data.is_cal & (np.abs(v) > max(50.0 * st.v_eps, SLIDING_SPEED))
    lengths = np.diff([*data.starts, data.force.size])
    X = _columns(names, axis, data, st)
    segments = segment_ids(lengths, fs)
    use_for_c = sliding | ~data.is_cal if sliding.sum() >= 50 else None
    problem = AxisProblem(X, data.arrays[f"{axis}_current"], data.force, data.is_cal, segments, list(names),
                          use_for_c=use_for_c)
    sign, sign_source = drive_sign(problem, km)
    cons = Constraints(axis=axis, sign=sign, fixed_c=1.0 / km if km is not None else None, **dict(bounds or {}))
    force_sign = 1.0
    if problem.segments(True):
        # does the reference read the load with the drive's sign, or against it (a dynamometer turned against the
        # machine's axis)?  The physical fit of each orientation, the better one on the calibration samples
        flipped = AxisProblem(X, data.arrays[f"{axis}_current"], -data.force, data.is_cal, segments, list(names),
                              use_for_c=use_for_c)
        every = list(range(len(names)))
        sse = [_calibration_sse(p, fit_bounded(p, every, cons)) for p in (problem, flipped)]
        if sse[1] < sse[0]:
            problem, force_sign = flipped, -1.0
    names, ridge, shrink, mse = choose_terms(problem, cons, keep, dropped)
    if "stribeck" not in names:
        st.v_s = 0.0
    if not any(n.startswith("ripple") for n in names):
        st.period = 0.0
    cols = [problem.names.index(n) for n in names]
    fit = fit_bounded(problem, cols, cons, ridge=ridge, shrink=shrink)
    K, K_ci, terms, active = physical_terms(axis, problem, fit, cons, km)
    held_residual = held_out_residuals(problem, cols, cons, ridge=ridge, shrink=shrink)
    # the held-out error of the calibration and the air segments, from the same folds
    cal_mse = _mean_square(held_residual[data.is_cal]) if len(problem.segments(True)) >= 2 else float("nan")
    air_mse = _mean_square(held_residual[~data.is_cal]) if len(problem.segments(False)) >= 2 else float("nan")
    trace = np.repeat(np.arange(lengths.size), lengths)
    if np.unique(trace[data.is_cal]).size >= 2:
        # two calibration cuts or more: the check leaves out a whole cut (another program or material), which
        # segments of one cut cannot stand for; the air cuts keep their segments
        per_cut = AxisProblem(X, problem.y, problem.force, data.is_cal, trace, list(problem.names),
                              use_for_c=use_for_c)
        held_residual = np.where(data.is_cal, held_out_residuals(per_cut, cols, cons, ridge=ridge, shrink=shrink),
                                 held_residual)
    model = ControllerAxis(K_m=K, terms=tuple(terms), v_eps=st.v_eps, K_m_ci95=K_ci, v_s=st.v_s, period=st.period,
                           x_pre=st.x_pre, hold_time=st.hold_time, dropped=dict(dropped), force_sign=int(force_sign))
    residual = problem.y - problem.X[:, cols] @ fit.theta - fit.c * problem.force
    air = dict(zip(names, fit.theta_air))
    report = {"K_m": K, "K_m_ci95": K_ci, "K_m_source": "identified from the calibration cut(s)" if km is None
              else "given (--km)", "terms": term_table(terms, air, K), "active_bounds": active,
              "drive_sign_from": sign_source, "force_sign": int(force_sign),
              **({"force_sign_note": f"the reference force_{axis} reads the process load against the drive's sign "
                                     "(a dynamometer whose axis is turned against the machine's): the model stays "
                                     "physical and its estimate follows the reference's sign"}
                 if force_sign < 0 else {}),
              "v_eps_m_s": st.v_eps, "v_s_m_s": model.v_s, "period_m": model.period, "x_pre_m": st.x_pre,
              "hold_time_s": st.hold_time, "dropped": dict(dropped), "ridge": ridge, "shrink": shrink,
              "held_out": {"current_rms_a": math.sqrt(mse), "force_rms_n": math.sqrt(mse) * abs(K),
                           "calibration_force_rms_n": math.sqrt(cal_mse) * abs(K) if math.isfinite(cal_mse) else None,
                           "air_force_rms_n": math.sqrt(air_mse) * abs(K) if math.isfinite(air_mse) else None,
                           "samples_air_held_out": int(np.sum(~data.is_cal)),
                           "samples_calibration_held_out": int(np.sum(data.is_cal)),
                           "segments": len(problem.grams)},
              "samples_air": int(np.sum(~data.is_cal)), "samples_calibration": int(np.sum(data.is_cal)),
              "_held_out_force_error": force_sign * K * held_residual,
              "residual_rms_a": {"air": _rms(residual[~data.is_cal]), "calibration": _rms(residual[data.is_cal])},
              "residual_rms_n": {"air": _rms(residual[~data.is_cal], abs(K)),
                                 "calibration": _rms(residual[data.is_cal], abs(K))}}
    return model, report, []


def _calibration_sse(problem: AxisProblem, fit) -> float:
    """Squared current residual [A^2] of a bounded fit on the calibration samples the force constant is fitted on
    (where the axis slides: a standing axis's nut may hold the force)."""
    r = problem.y - problem.X[:, fit.cols] @ fit.theta - fit.c * problem.force
    rows = problem.is_cal if problem.use_for_c is None else problem.is_cal & problem.use_for_c
    return float(np.sum(r[rows] ** 2))


def _mean_square(x: np.ndarray) -> float:
    """Mean square of the finite samples (NaN: where no segment could be left out), NaN if there are none."""
    x = x[np.isfinite(x)]
    return float(np.mean(x ** 2)) if x.size else float("nan")


def _rms(x: np.ndarray, scale: float = 1.0) -> float | None:
    return float(np.sqrt(np.mean(x ** 2))) * scale if x.size else None


# ------------------------------------------------------------------ the whole machine
def _check_traces(traces: Sequence[Recording]) -> tuple[float, list[str]]:
    if isinstance(traces, Recording):
        traces = [traces]
    if not traces:
        raise ConfigError("identify nc needs at least one trace (air cuts and/or calibration cuts)")
    for i, rec in enumerate(traces):
        if not isinstance(rec, Recording):
            raise ConfigError(f"trace {i + 1}: expected a Recording, got {type(rec).__name__}")
    rates = sorted({round(rec.fs, 6) for rec in traces})
    if len(rates) > 1:
        raise ConfigError(f"the traces have different rates ({', '.join(f'{r:g}' for r in rates)} Hz); "
                          "bring them to one with --resample HZ")
    fs = traces[0].fs
    if fs < MIN_RATE_HZ:
        raise ConfigError(f"trace rate {fs:g} Hz is below {MIN_RATE_HZ:g} Hz: accelerations and friction "
                          "reversals cannot be resolved; log the drives at 25 Hz or faster")
    axes = trace_axes(traces[0])
    if not axes:
        raise MissingChannelError("no axis found: a controller trace needs <axis>_current, <axis>_velocity and "
                                  "<axis>_acceleration channels (e.g. x_current [A], x_velocity [mm/s])")
    for rec in traces[1:]:
        missing = [a for a in axes if a not in trace_axes(rec)]
        if missing:
            raise MissingChannelError(f"trace '{rec.name or '?'}' lacks axis/axes {', '.join(missing)} "
                                      f"that '{traces[0].name or 'the first trace'}' has")
    return fs, axes


def _limits(fs: float, window_s: float, axes_models: Mapping[str, ControllerAxis]) -> list[str]:
    out = [f"trace rate {fs:g} Hz: process-force content above {fs / 2:g} Hz (tooth passing, chatter, impacts) "
           "is not resolved; the estimate is the force averaged over the logging window"
           + (f" of {window_s * 1e3:.3g} ms" if window_s > 0 else ""),
           f"reversals and accelerations shorter than {2e3 / fs:.3g} ms are smeared (friction direction and "
           "inertia are window means)",
           "structural modes (ball-screw axial mode, column rocking) lie above the Nyquist frequency and are not modelled"]
    for a, m in axes_models.items():
        if m.period > 0 and window_s > 0:
            out.append(f"axis {a}: the {m.period * 1e3:.3g} mm ripple averages out above "
                       f"{m.period / window_s * 1e3:.3g} mm/s")
    return out


def is_calibration_cut(rec: Recording) -> bool:
    """True for a trace with a force reference (``force_*``): a calibration cut; False: an air cut.

    Parameters
    ----------
    rec : Recording
        A trace.
    """
    return any(c.startswith("force_") for c in rec.channels)


def as_air_cut(rec: Recording) -> Recording:
    """An air cut whose dynamometer was logging anyway: the trace without its ``force_*`` channels.

    Parameters
    ----------
    rec : Recording
        A trace of the program run without material.
    """
    return rec.select(*[c for c in rec.channels if not c.startswith("force_")]) if is_calibration_cut(rec) else rec


def _base_scorer(traces, axes, channels, km, T: float, fs: float):
    """``score(d)``: residual of the base terms at delay ``d`` [samples], summed over the axes (each relative
    to its current's variance).  The features and the air-cut stage do not depend on ``d``: built once."""
    parts = []
    for a in axes:
        data = _axis_data(traces, a, channels[a], 0.0)
        st = _Settings(window_s=T, v_eps=_velocity_noise(data.arrays[f"{a}_velocity"]), fs=fs)
        X = _columns(["offset", f"inertia_{a}", "coulomb_pos", "coulomb_neg", "viscous"], a, data, st)
        parts.append((a, data, X, max(float(np.var(data.arrays[f"{a}_current"])), 1e-30)))

    def score(d: float) -> float:
        total = 0.0
        for a, data, X, var in parts:
            shifted = _AxisData(data.arrays, _shift_segments(data, d), data.is_cal, data.starts)
            y = data.arrays[f"{a}_current"]
            if km.get(a) is not None:
                fit = solve_least_squares(X, y - shifted.force / km[a], ["b"] * X.shape[1])
            else:
                fit = _fit_matrix(X, y, shifted, ["b"] * X.shape[1], a, _velocity_noise(data.arrays[f"{a}_velocity"]))
            total += fit.rss / var / y.size
        return total

    return score


def _shift_segments(data: _AxisData, d: float) -> np.ndarray:
    bounds = [*data.starts, data.force.size]
    return np.concatenate([_shifted(data.force[a:b], d) for a, b in zip(bounds[:-1], bounds[1:])])


def _window_and_delay(traces, axes, channels, km, fs: float, window_s, delay_s, has_cal: bool) -> tuple[float, float]:
    """Logging window [s] and delay [samples] of the best base fit: a coarse grid, then a fine one."""
    windows = [window_s] if window_s is not None else [0.0, 1.0 / fs]
    scorers = {T: _base_scorer(traces, axes, channels, km, T, fs) for T in windows}
    if delay_s is not None or not has_cal:
        delay = (delay_s or 0.0) * fs
        return min(windows, key=lambda T: scorers[T](delay)), delay
    step = max(0.5, 1e-3 * fs)
    top = max(2.0, 0.04 * fs)
    scores = [(scorers[T](d), T, d) for T in windows for d in np.arange(0.0, top + 1e-9, step)]
    best, T, d0 = min(scores)
    fine = [d for d in np.arange(d0 - step + 0.1, d0 + step - 0.05, 0.1) if d >= 0]
    best_fine, d = min((scorers[T](d), d) for d in fine)
    at_zero = scorers[T](0.0)
    # a delay is an estimate's latency and shifts every axis: taken only where the data clearly ask for it (on
    # real 50 Hz traces the residual moved by 1-3 % over 0-60 ms, and the best of that flat curve did worse on
    # other cuts than no delay)
    if at_zero <= min(best, best_fine) * (1.0 + DELAY_GAIN):
        return T, 0.0
    return T, float(d)


def identify_controller(traces: Sequence[Recording], *, km: Mapping[str, float] | None = None,
                        window_s: float | None = None, delay_s: float | None = None,
                        period: Mapping[str, float] | None = None, vertical: str | None = None,
                        carries: Mapping[str, Sequence[str]] | None = None) -> ControllerIdentification:
    """Identify a :class:`~drivesense.machine.controller_model.ControllerModel` from controller traces.

    Parameters
    ----------
    traces : sequence of Recording
        Controller traces at one rate (>= 25 Hz) with ``<a>_current`` [A],
        ``<a>_velocity`` [m/s], ``<a>_acceleration`` [m/s^2] and, for the
        position terms, ``<a>_position`` [m] per axis.  Traces with
        ``force_<a>`` [N] are calibration cuts; traces without any
        ``force_*`` are air cuts (process force zero).
    km : mapping of str to float, optional
        Force constants [N/A] of some axes, given instead of identified (an
        axis without force in the calibration cuts needs one); the sign is
        the controller's (as logged).
    window_s : float, optional
        Logging window [s] (default: the better of point samples and the trace interval).
    delay_s : float, optional
        Delay of the drive channels behind the force reference [s] (default:
        the best of 0-2 trace intervals on the calibration cuts; 0 without).
    period : mapping of str to float, optional
        Spatial period of an axis's position-periodic terms [m] (e.g. the
        screw lead; default: searched over 3-60 mm).
    vertical : str, optional
        The vertical axis (the only one carrying a weight): the other axes'
        offsets are bounded to a current-sensor offset (:data:`OFFSET_FRACTION`
        of their largest current, :mod:`drivesense.identify.kinematics`).  None: every axis's offset is free.
    carries : mapping of str to sequence of str, optional
        Kinematics, e.g. ``{"y": ["x"]}`` (Y carries X): a carrier's moved
        mass is bounded below by the mass of every axis it carries.

    Returns
    -------
    ControllerIdentification

    Raises
    ------
    ConfigError
        No traces, mixed rates, a rate below 25 Hz, bad ``km``.
    MissingChannelError
        A trace lacks an axis's channels.
    IdentificationError
        An axis's force constant is determined neither by the calibration cuts nor given.
    """
    from threadpoolctl import threadpool_limits

    # many small least-squares problems: BLAS threads only contend (50 ms instead of 2 ms per fit on 2 busy cores)
    with threadpool_limits(limits=1, user_api="blas"):
        return _identify(traces, km, window_s, delay_s, period, vertical, carries)


def _identify(traces, km, window_s, delay_s, period, vertical, carries) -> ControllerIdentification:
    started = time.perf_counter()
    traces = [traces] if isinstance(traces, Recording) else list(traces)
    fs, axes = _check_traces(traces)
    km = dict(km or {})
    for a, value in km.items():
        if a not in axes:
            raise ConfigError(f"--km names axis {a!r}, which the traces lack (they have {', '.join(axes)})")
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value != 0):
            raise ConfigError(f"--km {a}={value!r}: the force constant must be a nonzero number [N/A]")
    check_kinematics(axes, vertical, carries)
    has_cal = any(is_calibration_cut(rec) for rec in traces)
    uncalibrated = [a for a in axes if a not in km and not any(f"force_{a}" in rec for rec in traces)]
    if uncalibrated:
        raise IdentificationError(
            f"no calibration cut holds force_{'/'.join(uncalibrated)}: give a trace with dynamometer forces "
            f"(force_x [N], ...) or the force constants with --km {uncalibrated[0]}=VALUE [N/A]")
    channels = {a: [f"{b}_{c}" for b in axes for c in ("current", "velocity", "acceleration")]
                + [f"{a}_position"] * (f"{a}_position" in traces[0]) for a in axes}
    T, d = _window_and_delay(traces, axes, channels, km, fs, window_s, delay_s, has_cal)
    models, reports, warnings = {}, {}, []
    left_out = {}
    datas = {a: _axis_data(traces, a, channels[a], d) for a in axes}
    bounds = {a: offset_bound(a, datas[a].arrays[f"{a}_current"], vertical) for a in axes}
    for a in carried_first(axes, carries):
        others = [b for b in axes if b != a]
        try:
            models[a], reports[a], warn = _identify_axis(a, others, datas[a], T, fs, km.get(a), (period or {}).get(a),
                                                         bounds[a])
            extra = bounds[a]
            for _ in range(4):      # lighter than an axis it carries: again, with that axis's mass as its floor
                floor = mass_floor(a, models, carries, extra)
                if floor is None:
                    break
                extra = merge_bounds(bounds[a], floor)
                models[a], reports[a], warn = _identify_axis(a, others, datas[a], T, fs, km.get(a),
                                                             (period or {}).get(a), extra)
        except IdentificationError as exc:      # one axis without a force constant does not sink the others
            left_out[a] = str(exc)
            continue
        warnings.extend(warn)
    if not models:
        raise IdentificationError("; ".join(left_out.values()))
    warnings.extend(f"axis {a} left out of the model: {why}" for a, why in left_out.items())
    errors = {a: r.pop("_held_out_force_error") for a, r in reports.items()}
    check = compare_with_regression(traces, axes, datas, errors, fs, left_out) if has_cal else None
    # the traces' own declared delay (meta nc_delay_s) is added to the latency by the estimator: keep the rest
    declared = max((float(rec.meta.get("nc_delay_s", 0.0) or 0.0) for rec in traces if is_calibration_cut(rec)), default=0.0)
    model = ControllerModel(axes=models, window_s=float(T), delay_s=max(float(d / fs) - declared, 0.0),
                            rate_hz=float(fs), regression=check.regression if check else None,
                            choice=check.choice if check else {})
    return ControllerIdentification(model=model, axes=reports, limits=_limits(fs, T, models), warnings=warnings,
                                    seconds=time.perf_counter() - started,
                                    regression_check=check.report if check else {},
                                    kinematics={"vertical": vertical, "carries": {k: list(v) for k, v in
                                                                                  (carries or {}).items()}})
