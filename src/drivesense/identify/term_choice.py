"""Which terms an axis keeps, and their physical values: held-out error decides, bounds make them physical.

Used by :mod:`drivesense.identify.controller` once the non-linear settings
(logging window, presliding, Stribeck velocity, ripple period) are chosen:

1. terms the data cannot tell apart numerically (variance inflation above
   :data:`VIF_LIMIT`) are dropped first;
2. backward elimination by the leave-one-segment-out error of the bounded fit
   (:func:`drivesense.identify.physical_fit.held_out_error`): a term stays only
   if leaving it out makes the held-out error worse;
3. the ridge of the air stage and the shrinkage of the calibration stage
   towards the air-cut values are chosen on the same held-out error;
4. the final bounded fit gives the coefficients, their 95 % intervals (free
   terms; a term at a bound has its bound as value and the reason), and the
   held-out error in amperes and newtons.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import IdentificationError
from drivesense.identify.least_squares import variance_inflation
from drivesense.identify.physical_fit import (RIDGE_GRID, SHRINK_GRID, AxisProblem, BoundedFit, Constraints,
                                              covariance, held_out_error)
from drivesense.machine.controller_model import ControllerTerm, term_unit

__all__ = ["choose_terms", "physical_terms", "term_table", "VIF_LIMIT", "active_bound_reason"]

#: Variance inflation above which a term is numerically indistinguishable from the others.
VIF_LIMIT = 1.0e4
#: A term leaves only if the held-out error without it is at most this factor of the error with it.
KEEP_MARGIN = 1.0


def _mse(problem: AxisProblem, names: Sequence[str], cons: Constraints, ridge: float, shrink: float) -> float:
    cols = [problem.names.index(n) for n in names]
    return held_out_error(problem, cols, cons, ridge=ridge, shrink=shrink)


def choose_terms(problem: AxisProblem, cons: Constraints, keep: Sequence[str], dropped: dict) -> tuple[list, float, float, float]:
    """Terms, ridge and shrinkage with the smallest held-out error; `dropped` gets each left-out term's reason.

    Parameters
    ----------
    problem : AxisProblem
        The axis's data with every candidate term.
    cons : Constraints
        Sign and bounds.
    keep : sequence of str
        Terms kept whatever the error (the offset, the axis's own mass).
    dropped : dict
        Term -> reason, updated in place.

    Returns
    -------
    (names, ridge, shrink, mse)
        Kept term names, the chosen regularisation and its held-out mean squared current residual [A^2].
    """
    names = list(problem.names)
    while True:
        X = problem.X[:, [problem.names.index(n) for n in names]]
        vif = variance_inflation(X)
        worst = max(((vif[i], n) for i, n in enumerate(names) if n not in keep), default=None)
        if worst is None or worst[0] < VIF_LIMIT:
            break
        names.remove(worst[1])
        dropped[worst[1]] = f"indistinguishable from the other terms (variance inflation {worst[0]:.3g})"
    ridge, shrink = RIDGE_GRID[0], SHRINK_GRID[-1]
    best = _mse(problem, names, cons, ridge, shrink)
    while True:
        trials = [(_mse(problem, [m for m in names if m != n], cons, ridge, shrink), n) for n in names if n not in keep]
        if not trials:
            break
        err, name = min(trials)
        if err > best * KEEP_MARGIN:
            break
        names.remove(name)
        dropped[name] = (f"left out by held-out error: {math.sqrt(err):.3g} A without it, "
                         f"{math.sqrt(best):.3g} A with it (leave-one-segment-out)")
        best = err
    grid = [(r, s) for r in RIDGE_GRID for s in (SHRINK_GRID if problem.has_air() and problem.segments(True) else (SHRINK_GRID[-1],))]
    scored = [(_mse(problem, names, cons, r, s), r, s) for r, s in grid]
    best, ridge, shrink = min(scored)
    return names, ridge, shrink, best


def active_bound_reason(name: str, axis: str, side: str, problem: AxisProblem, cols: Sequence[int],
                        cons: Constraints) -> str:
    """Why a term sits at its bound: the bound's rule, then confounding or too little excitation.

    Parameters
    ----------
    name : str
        Term name.
    axis : str
        Axis letter.
    side : {"lower", "upper"}
        Which bound (in the fit's orientation).
    problem : AxisProblem
        The axis's data.
    cols : sequence of int
        Columns of the final fit.
    cons : Constraints
        Sign and bounds.
    """
    if name in cons.why:
        rule = cons.why[name]
    elif name == f"inertia_{axis}":
        rule = "a moved mass is >= 0"
    else:
        rule = "a friction level is >= 0"
    X = problem.X[:, list(cols)]
    Xs = X / problem.scale[list(cols)]
    i = [problem.names[c] for c in cols].index(name)
    with np.errstate(invalid="ignore", divide="ignore"):      # a constant column (the offset) has no correlation
        corr = np.nan_to_num(np.corrcoef(Xs.T)) if Xs.shape[1] > 1 else np.ones((1, 1))
    others = [(abs(corr[i, j]), problem.names[cols[j]]) for j in range(len(cols)) if j != i]
    top = max(others, default=(0.0, ""))
    vif = float(variance_inflation(X)[i])
    if vif > 10 and top[0] > 0.5:
        cause = f"confounded with {top[1]} (correlation {top[0]:.2f}, variance inflation {vif:.3g})"
    else:
        cause = "too little excitation: the data alone would push it past the bound"
    return f"at its bound ({rule}): {cause}"


def physical_terms(axis: str, problem: AxisProblem, fit: BoundedFit, cons: Constraints,
                   km_given: float | None) -> tuple[float, float, list, dict]:
    """Physical coefficients ``p = theta K_m`` with 95 % intervals (delta method), and the active bounds.

    Parameters
    ----------
    axis : str
        Axis letter.
    problem : AxisProblem
        The axis's data.
    fit : BoundedFit
        The final bounded fit.
    cons : Constraints
        Sign and bounds.
    km_given : float, optional
        ``K_m`` given by the user [N/A].

    Returns
    -------
    (K_m, K_m_ci95, terms, active)
        ``terms``: list of ControllerTerm; ``active``: term -> reason.
    """
    names = [problem.names[c] for c in fit.cols]
    residual = problem.y - problem.X[:, fit.cols] @ fit.theta - fit.c * problem.force
    with_c = km_given is None and bool(problem.segments(True))
    cov = covariance(problem, fit, residual, with_c=with_c)
    k = len(names)
    if km_given is None:
        c = fit.c
        se_c = math.sqrt(max(cov[k, k], 0.0)) if with_c else 0.0
        if c == 0 or not abs(c) > 1.96 * se_c:
            raise IdentificationError(
                f"axis {axis}: the calibration cuts do not determine the force constant "
                f"(1/K_m = {c:.3g} +- {1.96 * se_c:.2g} A/N); give it with --km {axis}=VALUE [N/A]")
        K, K_ci = 1.0 / c, 1.96 * se_c / c ** 2
    else:
        K, K_ci = float(km_given), 0.0
    terms = []
    for i, n in enumerate(names):
        if with_c:
            grad = np.zeros(k + 1)
            grad[i] = K
            grad[k] = -fit.theta[i] * K ** 2
            var = float(grad @ cov @ grad)
        else:
            var = K ** 2 * cov[i, i]
        terms.append(ControllerTerm(n, float(fit.theta[i] * K), float(1.96 * math.sqrt(max(var, 0.0)))))
    active = {problem.names[c]: active_bound_reason(problem.names[c], axis, side, problem, fit.cols, cons)
              for c, side in fit.active.items()}
    return float(K), float(K_ci), terms, active


def term_table(terms: Sequence[ControllerTerm], air: Mapping[str, float], K: float) -> dict:
    """Report rows: value, ci95, unit and the air-cut stage's value of each term.

    Parameters
    ----------
    terms : sequence of ControllerTerm
        The identified terms.
    air : mapping of str to float
        The air-cut stage's coefficient of each term [A per unit of the feature] (NaN without air cuts).
    K : float
        The force constant [N/A].
    """
    return {t.name: {"value": t.value, "ci95": t.ci95, "unit": term_unit(t.name),
                     **({"air_cut_value": air[t.name] * K} if t.name in air and math.isfinite(air[t.name]) else {})}
            for t in terms}
