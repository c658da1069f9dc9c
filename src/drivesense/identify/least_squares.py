"""Least squares with honest confidence intervals, for models linear in their parameters.

Drive-signal residuals are autocorrelated (a friction misfit lasts a whole
move), so the textbook covariance ``s^2 (X^T X)^-1`` is far too narrow.  The
residual variance here is scaled by ``(1 + rho) / (1 - rho)`` with the lag-1
autocorrelation ``rho`` of the residual (the effective sample size of an
AR(1) residual), which is what :mod:`drivesense.identify.controller` reports
as 95 % intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LeastSquaresFit", "solve_least_squares", "residual_variance", "variance_inflation"]


@dataclass
class LeastSquaresFit:
    """Result of :func:`solve_least_squares`.

    Attributes
    ----------
    names : list of str
        Column names.
    theta : ndarray
        Coefficients, one per column [unit of y per unit of the column].
    cov : ndarray
        Their covariance (autocorrelation-corrected) [product of the two coefficients' units].
    residual : ndarray
        ``y - X theta`` [unit of y].
    rss : float
        Residual sum of squares [unit of y squared].
    """

    names: list
    theta: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    rss: float


def residual_variance(residual: np.ndarray, n_params: int) -> float:
    """Variance of one residual sample, inflated by the residual's lag-1 autocorrelation.

    Parameters
    ----------
    residual : ndarray
        Fit residual [any unit].
    n_params : int
        Fitted parameters (degrees of freedom lost).

    Returns
    -------
    float
        ``rss / (n - k) * (1 + rho) / (1 - rho)`` with ``rho`` clipped to [0, 0.99] [unit squared].
    """
    n = residual.size
    rss = float(residual @ residual)
    rho = 0.0
    if n > 2:
        r0, r1 = residual[:-1], residual[1:]
        rho = float(np.clip((r0 @ r1) / max(float(r0 @ r0), 1e-300), 0.0, 0.99))
    inflation = min((1 + rho) / (1 - rho), n / (n_params + 2.0)) if n > n_params + 2 else 1.0
    return rss / max(n - n_params, 1) * inflation


def solve_least_squares(X: np.ndarray, y: np.ndarray, names: list, ridge: float = 1e-9) -> LeastSquaresFit:
    """Ridge-regularised least squares on RMS-normalised columns, with the corrected covariance.

    Parameters
    ----------
    X : ndarray, shape (n, k)
        Regressors [their units].
    y : ndarray, shape (n,)
        Observations [any unit].
    names : list of str
        Column names.
    ridge : float
        Tikhonov weight relative to the normalised Gram matrix per sample [-]
        (keeps nearly collinear columns finite).

    Returns
    -------
    LeastSquaresFit
    """
    scale = np.sqrt(np.mean(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    Xs = X / scale
    n, k = Xs.shape
    gram = Xs.T @ Xs
    A = gram + ridge * n * np.eye(k)
    theta_s = np.linalg.solve(A, Xs.T @ y)
    residual = y - Xs @ theta_s
    Ainv = np.linalg.inv(A)
    cov = residual_variance(residual, k) * (Ainv @ gram @ Ainv) / np.outer(scale, scale)
    return LeastSquaresFit(list(names), theta_s / scale, cov, residual, float(residual @ residual))


def variance_inflation(X: np.ndarray) -> np.ndarray:
    """Variance inflation factor of each column (about zero; 1: orthogonal to the others).

    Parameters
    ----------
    X : ndarray, shape (n, k)
        Regressors [their units].

    Returns
    -------
    ndarray
        One factor per column [-] (inf for a singular set).
    """
    scale = np.sqrt(np.mean(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    Xs = X / scale
    G = Xs.T @ Xs / Xs.shape[0]
    try:
        return np.diag(np.linalg.inv(G + 1e-12 * np.eye(G.shape[0])))
    except np.linalg.LinAlgError:
        return np.full(G.shape[0], np.inf)
