"""Bounded, regularised least squares for one axis of the controller-rate model, scored by held-out segments.

Per axis the logged current is ``I = X theta + c F`` (air samples: ``F = 0``;
see :mod:`drivesense.identify.controller`).  The fit here makes a physical
model by construction rather than warning after the fact:

* **one sign per axis**: with ``s = sign(c) = sign(1 / K_m)``, the moved mass,
  the friction levels (Coulomb in both directions, viscous, Stribeck) satisfy
  ``s theta >= 0`` (the motor pushes the mass and overcomes friction), and
  ``s c > 0``;
* **force-free motion first**: the air cuts alone give ``theta_air`` (a ridge
  towards zero keeps near-collinear terms finite); the calibration cuts then
  give ``c`` and move ``theta`` only as far as their data pay for, through a
  prior ``mu ||D (theta - theta_air)||^2`` -- a term that only the cut's own
  process force could explain stays at its air-cut value;
* further bounds from the machine (a horizontal axis's offset is a sensor
  offset, not a weight; an axis that carries another is not lighter);
* **held-out error decides**: every trace is cut into contiguous segments;
  leaving one segment out at a time, the error on the left-out samples picks
  the term set and the regularisation (:func:`held_out_error`).

All fits work on per-segment Gram matrices, so a leave-one-segment-out fold
costs a ``k x k`` bounded solve (``scipy.optimize.lsq_linear``, BVLS), not a
pass over the samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from drivesense.errors import IdentificationError
from drivesense.identify.least_squares import residual_variance

__all__ = ["AxisProblem", "BoundedFit", "Constraints", "fit_bounded", "covariance", "drive_sign", "held_out_residuals", "held_out_error", "segment_ids", "SIGN_TERMS",
           "RIDGE_GRID", "SHRINK_GRID"]

#: Terms whose coefficient has the sign of ``c`` (the force constant's inverse): masses and friction levels.
SIGN_TERMS = ("coulomb_pos", "coulomb_neg", "viscous", "stribeck")
#: Ridge of the air-cut stage, relative to the normalised Gram matrix per sample [-], tried by held-out error.
RIDGE_GRID = (1e-6, 1e-3, 1e-1)
#: Shrinkage of the calibration stage towards the air-cut terms [-] (large: the air cut's values kept).
SHRINK_GRID = (1e-2, 1.0, 1e2, 1e6)
#: Shortest segment of a trace for the held-out error [s].
SEGMENT_S = 4.0
#: Segments per trace at most.
MAX_SEGMENTS = 6


def segment_ids(lengths: Sequence[int], fs: float) -> np.ndarray:
    """Segment number of every sample: each trace cut into up to :data:`MAX_SEGMENTS` contiguous pieces
    of at least :data:`SEGMENT_S`.

    Parameters
    ----------
    lengths : sequence of int
        Samples per trace, in the order they are concatenated.
    fs : float
        Trace rate [Hz].
    """
    ids, nxt = [], 0
    for n in lengths:
        k = int(max(1, min(MAX_SEGMENTS, n // max(1, int(SEGMENT_S * fs)))))
        ids.append(nxt + np.minimum((np.arange(n) * k) // max(n, 1), k - 1))
        nxt += k
    return np.concatenate(ids) if ids else np.zeros(0, dtype=int)


@dataclass
class AxisProblem:
    """One axis's data as per-segment Gram matrices (see the module docstring).

    Parameters
    ----------
    X : ndarray, shape (n, k)
        Term features [unit of each feature].
    y : ndarray, shape (n,)
        Logged current [A].
    force : ndarray, shape (n,)
        Reference force [N] (0 on air samples).
    is_cal : ndarray of bool, shape (n,)
        Calibration samples.
    segment : ndarray of int, shape (n,)
        Segment of each sample (:func:`segment_ids`).
    names : list of str
        Term names, one per column of ``X``.
    use_for_c : ndarray of bool, optional
        Calibration samples the force constant is fitted on (default: all); held-out errors use all.
    """

    X: np.ndarray
    y: np.ndarray
    force: np.ndarray
    is_cal: np.ndarray
    segment: np.ndarray
    names: list
    use_for_c: np.ndarray | None = None
    scale: np.ndarray = field(init=False)
    grams: dict = field(init=False)

    def __post_init__(self) -> None:
        self.scale = np.sqrt(np.mean(self.X ** 2, axis=0))
        self.scale[~(self.scale > 0)] = 1.0
        Z = np.column_stack([self.X / self.scale, self.force])
        fit_rows = self.use_for_c if self.use_for_c is not None else np.ones(self.y.size, dtype=bool)
        self.grams = {}
        for g in np.unique(self.segment):
            rows = self.segment == g
            cal = bool(self.is_cal[rows][0])
            zr, yr = Z[rows], self.y[rows]
            f_rows = rows & (fit_rows if cal else True)
            zf, yf = Z[f_rows], self.y[f_rows]
            self.grams[int(g)] = {"cal": cal, "n": int(rows.sum()), "G": zr.T @ zr, "b": zr.T @ yr,
                                  "yy": float(yr @ yr), "Gfit": zf.T @ zf, "bfit": zf.T @ yf, "nfit": int(f_rows.sum())}

    def segments(self, cal: bool | None = None) -> list[int]:
        """Segment numbers.

        Parameters
        ----------
        cal : bool, optional
            True: calibration segments only; False: air segments only; None: all.
        """
        return [g for g, v in self.grams.items() if cal is None or v["cal"] == cal]

    def has_air(self) -> bool:
        """True when some segments are air cuts."""
        return bool(self.segments(False))


@dataclass
class BoundedFit:
    """Result of :func:`fit_bounded` on a column subset.

    Attributes
    ----------
    cols : list of int
        Columns of the problem used.
    theta : ndarray
        Coefficients [A per unit of the feature] (unscaled).
    c : float
        Inverse force constant [A/N] (0 when the problem has no calibration samples).
    theta_air : ndarray
        The air-cut stage's coefficients (NaN without air samples) [A per unit of the feature].
    active : dict
        Column -> "lower"/"upper" for coefficients at a bound.
    """

    cols: list
    theta: np.ndarray
    c: float
    theta_air: np.ndarray
    active: dict


def _solve_quadratic(A: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """``argmin z^T A z - 2 g^T z`` within the bounds (A symmetric positive semi-definite)."""
    k = A.shape[0]
    A = 0.5 * (A + A.T) + 1e-12 * max(float(np.trace(A)) / k, 1e-300) * np.eye(k)
    try:
        R = np.linalg.cholesky(A).T
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(A)
        R = (V * np.sqrt(np.maximum(w, 1e-12 * w.max()))).T
    rhs = np.linalg.solve(R.T, g)
    if np.all(np.isinf(lb)) and np.all(np.isinf(ub)):
        return np.linalg.solve(A, g)
    return lsq_linear(R, rhs, bounds=(lb, ub), method="bvls").x


def _sum(problem: AxisProblem, segs: Sequence[int], key: str) -> np.ndarray:
    return sum((problem.grams[g][key] for g in segs), start=np.zeros_like(problem.grams[segs[0]][key]))


@dataclass
class Constraints:
    """Bounds of one axis's coefficients in the scaled (fit) space.

    Parameters
    ----------
    axis : str
        The axis letter (its own ``inertia_<axis>`` is a mass: ``s theta >= 0``).
    sign : float
        ``s = sign(c)`` (+1 or -1) [-].
    lower, upper : dict of str to float
        Extra bounds per term on ``s * theta`` [A per unit of the feature] (e.g. a mass floor, an offset limit).
    why : dict of str to str
        The rule behind each extra bound, for the report.
    fixed_c : float, optional
        ``c`` given (``--km``) [A/N].
    """

    axis: str
    sign: float
    lower: dict = field(default_factory=dict)
    upper: dict = field(default_factory=dict)
    why: dict = field(default_factory=dict)
    fixed_c: float | None = None

    def bounds(self, names: Sequence[str], scale: np.ndarray, with_c: bool) -> tuple[np.ndarray, np.ndarray]:
        """(lb, ub) of the scaled coefficients (and ``c`` last when `with_c`).

        Parameters
        ----------
        names : sequence of str
            Term names of the columns.
        scale : ndarray
            RMS of each column (the fit divides the columns by it) [unit of the feature].
        with_c : bool
            Append the bounds of ``c`` (its sign, or its given value).
        """
        s = self.sign
        lb, ub = np.full(len(names), -np.inf), np.full(len(names), np.inf)
        for i, n in enumerate(names):
            lo = 0.0 if (n in SIGN_TERMS or n == f"inertia_{self.axis}") else -np.inf
            lo = max(lo, self.lower.get(n, -np.inf))
            hi = self.upper.get(n, np.inf)
            # s * theta in [lo, hi]  ->  theta_scaled in [lo, hi] * scale^-1 ... oriented by s
            a, b = lo * scale[i], hi * scale[i]
            lb[i], ub[i] = (a, b) if s > 0 else (-b, -a)
        if with_c:
            if self.fixed_c is not None:
                c = self.fixed_c
                lb, ub = np.append(lb, c - 1e-12 * abs(c)), np.append(ub, c + 1e-12 * abs(c))
            else:
                lb, ub = np.append(lb, 0.0 if s > 0 else -np.inf), np.append(ub, np.inf if s > 0 else 0.0)
        return lb, ub


def _stage_air(problem: AxisProblem, cols: list, segs: Sequence[int], ridge: float, lb, ub) -> np.ndarray:
    G = _sum(problem, segs, "Gfit")[np.ix_(cols, cols)]
    b = _sum(problem, segs, "bfit")[cols]
    n = sum(problem.grams[g]["nfit"] for g in segs)
    return _solve_quadratic(G + ridge * n * np.eye(len(cols)), b, lb, ub)


def _stage_cal(problem: AxisProblem, cols: list, segs: Sequence[int], prior: np.ndarray | None, shrink: float,
               ridge: float, lb, ub) -> np.ndarray:
    idx = [*cols, problem.X.shape[1]]
    G = _sum(problem, segs, "Gfit")[np.ix_(idx, idx)]
    b = _sum(problem, segs, "bfit")[idx]
    n = sum(problem.grams[g]["nfit"] for g in segs)
    k = len(cols)
    P = np.zeros((k + 1, k + 1))
    q = np.zeros(k + 1)
    if prior is not None:
        P[:k, :k] = shrink * n * np.eye(k)
        q[:k] = shrink * n * prior
    else:
        P[:k, :k] = ridge * n * np.eye(k)
    return _solve_quadratic(G + P, b + q, lb, ub)


def _fit_scaled(problem: AxisProblem, cols: list, cons: Constraints, ridge: float, shrink: float,
                air_segs: Sequence[int], cal_segs: Sequence[int]) -> tuple[np.ndarray, float, np.ndarray | None]:
    names = [problem.names[i] for i in cols]
    lb, ub = cons.bounds(names, problem.scale[cols], with_c=False)
    air = _stage_air(problem, cols, air_segs, ridge, lb, ub) if air_segs else None
    if not cal_segs:
        return air, 0.0, air
    lbc, ubc = cons.bounds(names, problem.scale[cols], with_c=True)
    z = _stage_cal(problem, cols, cal_segs, air, shrink, ridge, lbc, ubc)
    return z[:-1], float(z[-1]), air


def fit_bounded(problem: AxisProblem, cols: list, cons: Constraints, *, ridge: float = 1e-6,
                shrink: float = 1e6) -> BoundedFit:
    """Fit the columns `cols` on every segment (air stage, then calibration stage with the air prior).

    Parameters
    ----------
    problem : AxisProblem
        The axis's data.
    cols : list of int
        Columns (terms) to use.
    cons : Constraints
        Sign and bounds.
    ridge : float
        Ridge of the air stage (and of a calibration stage without air cuts) [-].
    shrink : float
        Weight of the prior ``theta_air`` in the calibration stage [-].
    """
    ts, c, air = _fit_scaled(problem, cols, cons, ridge, shrink, problem.segments(False), problem.segments(True))
    names = [problem.names[i] for i in cols]
    lb, ub = cons.bounds(names, problem.scale[cols], with_c=False)
    tol = 1e-9 * np.maximum(np.abs(ts), 1e-12)
    active = {cols[i]: ("lower" if abs(ts[i] - lb[i]) <= tol[i] + 1e-15 else "upper")
              for i in range(len(cols)) if abs(ts[i] - lb[i]) <= tol[i] + 1e-15 or abs(ts[i] - ub[i]) <= tol[i] + 1e-15}
    scale = problem.scale[cols]
    return BoundedFit(cols=list(cols), theta=ts / scale, c=c,
                      theta_air=(air / scale) if air is not None else np.full(len(cols), np.nan), active=active)


def held_out_error(problem: AxisProblem, cols: list, cons: Constraints, *, ridge: float = 1e-6,
                   shrink: float = 1e6) -> float:
    """Mean squared current residual [A^2] on left-out segments, leaving out one segment at a time.

    Parameters
    ----------
    problem : AxisProblem
        The axis's data.
    cols : list of int
        Columns (terms) to use.
    cons : Constraints
        Sign and bounds.
    ridge : float
        As :func:`fit_bounded` [-].
    shrink : float
        As :func:`fit_bounded` [-].
    """
    sse, n = 0.0, 0
    for g, ts, c in _folds(problem, cols, cons, ridge, shrink, problem.segments()):
        held = problem.grams[g]
        idx = [*cols, problem.X.shape[1]]
        z = np.append(ts, c)
        G, b = held["G"][np.ix_(idx, idx)], held["b"][idx]
        sse += max(held["yy"] - 2.0 * float(z @ b) + float(z @ G @ z), 0.0)
        n += held["n"]
    if n == 0:
        raise IdentificationError("too few segments for a held-out error (need two air or two calibration segments)")
    return sse / n


def _folds(problem: AxisProblem, cols: list, cons: Constraints, ridge: float, shrink: float, segs):
    """``(segment, theta_scaled, c)`` of the fit without each segment of `segs` (those that can be left out)."""
    air_all, cal_all = problem.segments(False), problem.segments(True)
    cached = None
    for g in segs:
        if problem.grams[g]["cal"]:
            if len(cal_all) < 2 and not air_all:
                continue
            if cached is None:
                cached = _fit_scaled(problem, cols, cons, ridge, shrink, air_all, [])[0] if air_all else None
            ts, c = _cal_fold(problem, cols, cons, ridge, shrink, cached, [h for h in cal_all if h != g])
        else:
            if len(air_all) < 2:
                continue
            ts, c, _ = _fit_scaled(problem, cols, cons, ridge, shrink, [h for h in air_all if h != g], cal_all)
        yield g, ts, c


def held_out_residuals(problem: AxisProblem, cols: list, cons: Constraints, *, ridge: float = 1e-6,
                       shrink: float = 1e6) -> np.ndarray:
    """The current residual of every sample [A] from the fit without its segment (NaN where it cannot be left out).

    Parameters
    ----------
    problem : AxisProblem
        The axis's data.
    cols : list of int
        Columns (terms) to use.
    cons : Constraints
        Sign and bounds.
    ridge : float
        As :func:`fit_bounded` [-].
    shrink : float
        As :func:`fit_bounded` [-].
    """
    out = np.full(problem.y.size, np.nan)
    Xs = problem.X[:, cols] / problem.scale[cols]
    for g, ts, c in _folds(problem, cols, cons, ridge, shrink, problem.segments()):
        rows = problem.segment == g
        out[rows] = problem.y[rows] - Xs[rows] @ ts - c * problem.force[rows]
    return out


def _cal_fold(problem, cols, cons, ridge, shrink, air_theta, cal_segs) -> tuple[np.ndarray, float]:
    names = [problem.names[i] for i in cols]
    if not cal_segs:        # one calibration segment only: c from the air prior is undetermined -> use all air
        return air_theta, 0.0
    lbc, ubc = cons.bounds(names, problem.scale[cols], with_c=True)
    z = _stage_cal(problem, cols, cal_segs, air_theta, shrink, ridge, lbc, ubc)
    return z[:-1], float(z[-1])


def covariance(problem: AxisProblem, fit: BoundedFit, residual: np.ndarray, *, with_c: bool) -> np.ndarray:
    """Covariance of (theta, c) [unscaled units], free coefficients only (those at a bound get 0).

    Parameters
    ----------
    problem : AxisProblem
        The axis's data.
    fit : BoundedFit
        The final fit.
    residual : ndarray
        Its current residual over all samples [A].
    with_c : bool
        Include ``c`` as the last coefficient.
    """
    k = len(fit.cols)
    idx = [*fit.cols, problem.X.shape[1]] if with_c else list(fit.cols)
    G = sum(v["G"] for v in problem.grams.values())[np.ix_(idx, idx)]
    free = [i for i in range(len(idx)) if i >= k or fit.cols[i] not in fit.active]
    cov = np.zeros((len(idx), len(idx)))
    if free:
        sub = G[np.ix_(free, free)]
        try:
            inv = np.linalg.inv(sub + 1e-12 * max(float(np.trace(sub)), 1e-300) * np.eye(len(free)))
        except np.linalg.LinAlgError:
            inv = np.linalg.pinv(sub)
        cov[np.ix_(free, free)] = residual_variance(residual, len(free)) * inv
    unscale = np.append(problem.scale[fit.cols], 1.0) if with_c else problem.scale[fit.cols]
    return cov / np.outer(unscale, unscale)


def drive_sign(problem: AxisProblem, km: float | None = None) -> tuple[float, str]:
    """The drive's sign ``s`` of ``c = 1 / K_m``, shared by the moved mass and the friction levels.

    Whatever resists the motion -- friction, and in a cut the feed force too -- makes the current follow
    ``sgn(v)`` with the drive's sign, and the moved mass makes it follow the acceleration with the same sign.
    A minimal least-squares fit ``I ~ 1 + a + sgn(v)`` over every trace (no force regressor, which in a cut is
    collinear with the friction) gives both; the better determined one (larger t-statistic) decides.  A given
    ``K_m`` decides instead.

    Parameters
    ----------
    problem : AxisProblem
        The axis's data (its ``own`` feature columns are read by name: ``inertia_<axis>``, ``coulomb_*``).
    km : float, optional
        A given force constant [N/A].

    Returns
    -------
    (s, source)
        +1 or -1, and what decided it.
    """
    if km is not None:
        return math.copysign(1.0, km), "the given K_m"
    names = problem.names
    own = next((i for i, n in enumerate(names) if n.startswith("inertia_") and n == _own_inertia(names)), None)
    friction = [i for i, n in enumerate(names) if n in ("coulomb_pos", "coulomb_neg")]
    cols = [np.ones(problem.y.size)]
    labels = []
    if own is not None and np.ptp(problem.X[:, own]) > 0:
        cols.append(problem.X[:, own])
        labels.append("the moved mass")
    if friction and np.ptp(problem.X[:, friction].sum(axis=1)) > 0:
        cols.append(problem.X[:, friction].sum(axis=1))      # max(sigma, 0) + min(sigma, 0) = sigma
        labels.append("the friction")
    if not labels:      # the axis never moves: only the calibration force can fix the sign
        if not problem.segments(True):
            raise IdentificationError("neither motion nor a calibration force fixes the sign of K_m")
        A = np.column_stack([problem.X, problem.force])
        z, *_ = np.linalg.lstsq(A, problem.y, rcond=None)
        return math.copysign(1.0, z[-1] or 1.0), "the calibration force (the axis does not move)"
    A = np.column_stack(cols)
    z, *_ = np.linalg.lstsq(A, problem.y, rcond=None)
    r = problem.y - A @ z
    var = float(r @ r) / max(problem.y.size - A.shape[1], 1)
    cov = var * np.linalg.pinv(A.T @ A)
    t = [abs(z[k]) / math.sqrt(cov[k, k]) if cov[k, k] > 0 else 0.0 for k in range(1, A.shape[1])]
    k = int(np.argmax(t))
    if not z[k + 1] or not math.isfinite(z[k + 1]):
        raise IdentificationError("neither motion nor friction fixes the sign of K_m")
    return math.copysign(1.0, z[k + 1]), f"{labels[k]} (t = {t[k]:.3g})"


def _own_inertia(names: Sequence[str]) -> str:
    """``inertia_<own>``: the first inertia term of a candidate list (the identification puts its own first)."""
    return next((n for n in names if n.startswith("inertia_")), "")
