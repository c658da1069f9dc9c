"""Chatter stability lobes of milling by the zeroth-order approximation (ZOA).

Altintas & Budak (1995), "Analytical prediction of stability lobes in
milling", CIRP Annals 44(1), and Altintas, *Manufacturing Automation*
(2nd ed., 2012), ch. 4.4 "Chatter stability of milling".  Conventions are
those of :mod:`drivesense.machine.milling` (immersion ``phi`` clockwise from
``+y``, feed along ``+x``, force on the tool ``F_x = -F_t cos phi - F_r sin phi``,
``F_y = F_t sin phi - F_r cos phi``, ``F_r = K_r F_t``, ``K_r = K_rc / K_tc``).

The regenerative chip of a tooth at ``phi`` is ``h = dx sin phi + dy cos phi``
(``d`` the present minus the previous tooth period's tool displacement), so
the dynamic force is ``F(t) = (a K_tc / 2) A(t) d(t)`` with the time-varying
directional matrix ``A(t) = sum_j g(phi_j) a(phi_j)``::

    a_xx = -sin 2phi - K_r (1 - cos 2phi)     a_xy = -(1 + cos 2phi) - K_r sin 2phi
    a_yx = (1 - cos 2phi) - K_r sin 2phi      a_yy = sin 2phi - K_r (1 + cos 2phi)

The ZOA keeps its mean ``A0 = N / (2 pi) [alpha]`` (:func:`directional_factors`).
With ``d = (1 - exp(-i omega_c T)) G(i omega_c) F`` and ``G = diag(G_xx, G_yy)``
the stability border is ``det[I + Lambda [alpha] G] = 0``,
``Lambda = -(N / 4 pi) a K_tc (1 - exp(-i omega_c T))`` (Altintas Eq. 4.80-4.85):
with ``lambda`` an eigenvalue of ``[alpha] G``, ``Lambda = -1 / lambda`` and

* ``a_lim = -2 pi Lambda_R (1 + kappa^2) / (N K_tc) = 2 pi / (N K_tc Re(lambda))``,
  a border only where ``Re(lambda) > 0``;
* ``kappa = Lambda_I / Lambda_R``, ``epsilon = pi - 2 atan(kappa) = pi + 2 arg(lambda)``,
  ``T = (epsilon + 2 k pi) / omega_c``, ``n = 60 / (N T)`` [rev/min] for lobe ``k``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from drivesense.errors import ConfigError
from drivesense.machine.milling import CuttingCoefficients, check_int, check_number
from drivesense.machine.tool_dynamics import ToolDynamics

__all__ = [
    "StabilityLobes",
    "directional_factors",
    "stability_lobes",
    "critical_depth",
    "absolute_depth_limit",
]

_TWO_PI = 2.0 * math.pi
#: Chatter-frequency band swept, relative to the lowest and highest natural frequency.
_BAND = (0.05, 3.0)
#: Half width of the dense sampling around each mode, in damping ratios.
_LOCAL = 6.0


@dataclass(frozen=True, eq=False)
class StabilityLobes:
    """Envelope of the stability lobes of a milling cut.

    Attributes
    ----------
    spindle_rpm : ndarray
        Spindle speeds of the grid [rev/min], increasing.
    depth_limit : ndarray
        Critical axial depth of cut at each speed [m], the minimum over the
        lobes (deeper cuts chatter); NaN where none of the lobes reaches the
        speed, inf where the cut is stable at any depth.
    chatter_frequency_hz : ndarray
        Chatter frequency of the limiting lobe at each speed [Hz] (NaN where
        ``depth_limit`` is not finite).
    """

    spindle_rpm: np.ndarray
    depth_limit: np.ndarray
    chatter_frequency_hz: np.ndarray


# ----------------------------------------------------------------------- checks
def _check_angles(phi_st, phi_ex) -> tuple[float, float]:
    st = check_number(phi_st, "phi_st")
    ex = check_number(phi_ex, "phi_ex")
    tol = 1e-12
    if not -tol <= st <= math.pi + tol:
        raise ConfigError(f"'phi_st' must be in [0, pi] rad, got {st!r}")
    if not -tol <= ex <= math.pi + tol:
        raise ConfigError(f"'phi_ex' must be in [0, pi] rad, got {ex!r}")
    if ex <= st:
        raise ConfigError(f"'phi_ex' ({ex!r} rad) must be greater than 'phi_st' ({st!r} rad)")
    return st, ex


def _check_inputs(dynamics, coefficients, flutes, phi_st, phi_ex):
    if not isinstance(dynamics, ToolDynamics):
        raise ConfigError(f"'dynamics' must be a ToolDynamics, got {type(dynamics).__name__}")
    if not isinstance(coefficients, CuttingCoefficients):
        raise ConfigError(f"'coefficients' must be CuttingCoefficients, got {type(coefficients).__name__}")
    if coefficients.Ktc <= 0.0:
        raise ConfigError(f"'coefficients.Ktc' must be > 0, got {coefficients.Ktc!r}")
    n = check_int(flutes, "flutes")
    st, ex = _check_angles(phi_st, phi_ex)
    return n, directional_factors(st, ex, coefficients.Krc / coefficients.Ktc)


def _check_lobes(lobes) -> np.ndarray:
    try:
        ks = list(lobes)
    except TypeError:
        raise ConfigError(f"'lobes' must be an iterable of lobe numbers, got {lobes!r}") from None
    if not ks or not all(isinstance(k, numbers.Integral) and not isinstance(k, bool) and k >= 0 for k in ks):
        raise ConfigError(f"'lobes' must hold integers >= 0, got {lobes!r}")
    return np.unique(np.asarray(ks, dtype=float))


# ----------------------------------------------------------------------- the model
def directional_factors(phi_st, phi_ex, radial_ratio) -> np.ndarray:
    """Averaged directional factors ``[[alpha_xx, alpha_xy], [alpha_yx, alpha_yy]]`` of the ZOA.

    The integrals of Altintas' directional coefficients ``a(phi)`` over the
    engagement (Altintas 2012, Eq. 4.77; Altintas & Budak 1995)::

        alpha_xx = 1/2 [ cos 2phi - 2 K_r phi + K_r sin 2phi ]
        alpha_xy = 1/2 [-sin 2phi - 2 phi     + K_r cos 2phi ]
        alpha_yx = 1/2 [-sin 2phi + 2 phi     + K_r cos 2phi ]
        alpha_yy = 1/2 [-cos 2phi - 2 K_r phi - K_r sin 2phi ]

    each evaluated from ``phi_st`` to ``phi_ex``; the mean directional
    matrix over a tooth period is ``A0 = N / (2 pi) [alpha]``.

    Parameters
    ----------
    phi_st : float
        Start immersion angle [rad], in [0, pi].
    phi_ex : float
        Exit immersion angle [rad], ``phi_st < phi_ex <= pi``.
    radial_ratio : float
        ``K_r = K_rc / K_tc`` [-].

    Returns
    -------
    ndarray
        Shape (2, 2), dimensionless [-].
    """
    st, ex = _check_angles(phi_st, phi_ex)
    kr = check_number(radial_ratio, "radial_ratio")

    def prim(p: float) -> np.ndarray:
        c, s = math.cos(2 * p), math.sin(2 * p)
        return 0.5 * np.array([[c - 2 * kr * p + kr * s, -s - 2 * p + kr * c],
                               [-s + 2 * p + kr * c, -c - 2 * kr * p - kr * s]])

    return prim(ex) - prim(st)


def _eigenvalues(dynamics: ToolDynamics, alpha: np.ndarray, freq: np.ndarray) -> np.ndarray:
    """Eigenvalues ``lambda`` of ``[alpha] diag(G_xx, G_yy)`` [m/N], shape (2, F), continuous along `freq`."""
    gx, gy = dynamics.receptance(freq)
    m11, m12 = alpha[0, 0] * gx, alpha[0, 1] * gy
    m21, m22 = alpha[1, 0] * gx, alpha[1, 1] * gy
    half = 0.5 * (m11 + m22)
    s = np.sqrt(0.25 * (m11 - m22) ** 2 + m12 * m21)
    if s.size > 1:      # keep each branch on one root: flip where sqrt jumps across its cut
        flip = np.abs(s[1:] - s[:-1]) > np.abs(s[1:] + s[:-1])
        s = s * np.concatenate([[1.0], np.where(np.cumsum(flip) % 2, -1.0, 1.0)])
    return np.stack([half + s, half - s])


def _band(dynamics: ToolDynamics, points: int) -> np.ndarray:
    """Chatter frequencies [Hz]: a geometric sweep of the band plus dense samples around each mode."""
    modes = dynamics.x + dynamics.y
    fn = [m.frequency_hz for m in modes]
    lo, hi = _BAND[0] * min(fn), _BAND[1] * max(fn)
    parts = [np.geomspace(lo, hi, points)]
    for m in modes:
        w = _LOCAL * m.damping_ratio * m.frequency_hz
        parts.append(np.linspace(max(lo, m.frequency_hz - w), min(hi, m.frequency_hz + w), points))
    return np.unique(np.concatenate(parts))


def _border(lam: np.ndarray, flutes: int, ktc: float) -> tuple[np.ndarray, np.ndarray]:
    """Critical depth ``2 pi / (N K_tc Re lambda)`` [m] (NaN where no border) and ``epsilon`` [rad]."""
    re = lam.real
    scale = np.max(np.abs(lam))
    ok = re > 1e-12 * scale
    depth = np.where(ok, _TWO_PI / (flutes * ktc * np.where(ok, re, 1.0)), np.nan)
    eps = math.pi + 2.0 * np.arctan2(lam.imag, np.where(ok, re, 1.0))
    return depth, eps


def _envelope(freq, depth, eps, flutes, ks, grid) -> tuple[np.ndarray, np.ndarray]:
    """Minimum over the lobes ``k`` of the border interpolated onto the speed `grid` [rev/min]."""
    omega = _TWO_PI * freq
    idx_all, a_all, f_all = [], [], []
    for d, e in zip(depth, eps):                                     # the two eigenvalue branches
        seg = np.isfinite(d[:-1]) & np.isfinite(d[1:])
        a0, a1, f0, f1 = d[:-1][seg], d[1:][seg], freq[:-1][seg], freq[1:][seg]
        for k in ks:
            n = 60.0 * omega / (flutes * (e + _TWO_PI * k))
            n0, n1 = n[:-1][seg], n[1:][seg]
            lo = np.searchsorted(grid, np.minimum(n0, n1), side="left")
            count = np.searchsorted(grid, np.maximum(n0, n1), side="right") - lo
            hit = np.flatnonzero(count)
            if hit.size == 0:
                continue
            which = np.repeat(hit, count[hit])
            idx = lo[which] + np.arange(which.size) - np.repeat(np.cumsum(count[hit]) - count[hit], count[hit])
            span = n1[which] - n0[which]
            t = np.where(span != 0.0, (grid[idx] - n0[which]) / np.where(span != 0.0, span, 1.0), 0.0)
            idx_all.append(idx)
            a_all.append(a0[which] + t * (a1[which] - a0[which]))
            f_all.append(f0[which] + t * (f1[which] - f0[which]))
    depth_env = np.full(grid.shape, np.nan)
    freq_env = np.full(grid.shape, np.nan)
    if idx_all:
        idx, a, f = np.concatenate(idx_all), np.concatenate(a_all), np.concatenate(f_all)
        order = np.lexsort((a, idx))
        first_idx, first = np.unique(idx[order], return_index=True)
        depth_env[first_idx] = a[order][first]
        freq_env[first_idx] = f[order][first]
    return depth_env, freq_env


def _auto_lobes(freq, flutes, rpm_min) -> np.ndarray:
    """Every lobe number whose speeds ``60 f / (N (epsilon / 2 pi + k))`` can reach ``rpm_min`` or above."""
    return np.arange(0.0, math.ceil(60.0 * freq[-1] / (flutes * rpm_min)) + 1.0)


def stability_lobes(dynamics, coefficients, flutes, phi_st, phi_ex, *, rpm_range=(1000.0, 20000.0),
                    lobes=None, points=2000) -> StabilityLobes:
    """Stability-lobe envelope of a milling cut by the zeroth-order approximation.

    The chatter frequency is swept over ``0.05 f_min .. 3 f_max`` (the modes'
    natural frequencies; geometric spacing, plus dense samples within
    ``+-6 zeta f_n`` of each mode), the 2x2 eigenvalue problem
    ``det[I + Lambda [alpha] G(i omega_c)] = 0`` is solved at each frequency,
    every positive real border ``a_lim`` is mapped to the speed of each lobe
    ``k`` and the lobes are interpolated (linearly, segment by segment) onto
    the speed grid, keeping the minimum (see the module docstring for the formulas).

    Parameters
    ----------
    dynamics : ToolDynamics
        Tool-tip modes in x (feed) and y; a direction without modes is rigid.
    coefficients : CuttingCoefficients
        Cutting coefficients; ``Ktc`` [N/m^2] (> 0) and ``K_r = Krc / Ktc`` are used.
    flutes : int
        Number of flutes N, >= 1.
    phi_st : float
        Start immersion angle [rad] (:func:`~drivesense.machine.milling.engagement_angles`).
    phi_ex : float
        Exit immersion angle [rad], ``phi_st < phi_ex <= pi``.
    rpm_range : tuple of float, optional
        Lowest and highest spindle speed of the grid [rev/min], ``0 < min < max``.
    lobes : iterable of int, optional
        Lobe numbers k >= 0 to include; default: every lobe that reaches the
        speed range (all ``k <= 60 f_band_max / (N rpm_min)``).  Lobes
        missing from a user-given list leave the envelope too high or NaN.
    points : int, optional
        Number of spindle speeds of the grid (linear) and of chatter
        frequencies per band and per mode, >= 10.

    Returns
    -------
    StabilityLobes
        Speeds [rev/min], the envelope [m] and the chatter frequency [Hz].
    """
    n_fl, alpha = _check_inputs(dynamics, coefficients, flutes, phi_st, phi_ex)
    try:
        r0, r1 = rpm_range
    except (TypeError, ValueError):
        raise ConfigError(f"'rpm_range' must be a (min, max) pair [rev/min], got {rpm_range!r}") from None
    r0 = check_number(r0, "rpm_range[0]", positive=True)
    r1 = check_number(r1, "rpm_range[1]", positive=True)
    if r1 <= r0:
        raise ConfigError(f"'rpm_range' must be increasing, got ({r0!r}, {r1!r})")
    points = check_int(points, "points", minimum=10)
    freq = _band(dynamics, points)
    ks = _auto_lobes(freq, n_fl, r0) if lobes is None else _check_lobes(lobes)
    depth, eps = _border(_eigenvalues(dynamics, alpha, freq), n_fl, coefficients.Ktc)
    grid = np.linspace(r0, r1, points)
    if not np.isfinite(depth).any():                               # Re(lambda) <= 0 everywhere: always stable
        return StabilityLobes(grid, np.full(grid.shape, np.inf), np.full(grid.shape, np.nan))
    env, fc = _envelope(freq, depth, eps, n_fl, ks, grid)
    return StabilityLobes(grid, env, fc)


def critical_depth(dynamics, coefficients, flutes, phi_st, phi_ex, spindle_rpm) -> float:
    """Critical axial depth of cut at one spindle speed: the lobe envelope there.

    Every lobe reaching the speed is included: along each eigenvalue branch
    the samples where ``(60 omega_c / (N n) - epsilon) / (2 pi)`` crosses an
    integer ``k >= 0`` are located on a chatter-frequency grid four times
    finer than :func:`stability_lobes`' default and the border is
    interpolated linearly between the two samples.

    Parameters
    ----------
    dynamics : ToolDynamics
        Tool-tip modes in x and y.
    coefficients : CuttingCoefficients
        Cutting coefficients (``Ktc`` [N/m^2], ``Krc``).
    flutes : int
        Number of flutes N, >= 1.
    phi_st : float
        Start immersion angle [rad].
    phi_ex : float
        Exit immersion angle [rad].
    spindle_rpm : float
        Spindle speed [rev/min], > 0.

    Returns
    -------
    float
        Critical axial depth a_lim [m] (inf: stable at any depth).
    """
    n_fl, alpha = _check_inputs(dynamics, coefficients, flutes, phi_st, phi_ex)
    rpm = check_number(spindle_rpm, "spindle_rpm", positive=True)
    freq = _band(dynamics, 8000)
    depth, eps = _border(_eigenvalues(dynamics, alpha, freq), n_fl, coefficients.Ktc)
    best = math.inf
    for d, e in zip(depth, eps):
        # lobe number at which each sample's border lies at `rpm`: n = 60 omega / (N (eps + 2 k pi))
        kstar = (60.0 * _TWO_PI * freq / (n_fl * rpm) - e) / _TWO_PI
        seg = np.flatnonzero(np.isfinite(d[:-1]) & np.isfinite(d[1:]))
        k0, k1 = kstar[seg], kstar[seg + 1]
        first = np.maximum(np.ceil(np.minimum(k0, k1)), 0.0)       # the integer lobes crossed
        count = np.where(k0 != k1, np.floor(np.maximum(k0, k1)) - first + 1.0, 0.0).clip(min=0.0).astype(int)
        if not count.any():
            continue
        i = np.repeat(seg, count)
        m = np.repeat(first, count) + np.arange(i.size) - np.repeat(np.cumsum(count) - count, count)
        t = (m - kstar[i]) / (kstar[i + 1] - kstar[i])
        best = min(best, float(np.min(d[i] + t * (d[i + 1] - d[i]))))
    return best


def absolute_depth_limit(dynamics, coefficients, flutes, phi_st, phi_ex) -> float:
    """Speed-independent critical depth: the minimum of the lobes over all spindle speeds.

    Every lobe spans the whole chatter-frequency band, so the minimum is
    ``2 pi / (N K_tc max Re(lambda))`` over the frequencies and both
    eigenvalues; it is refined by a bounded scalar search around the best sample.

    Parameters
    ----------
    dynamics : ToolDynamics
        Tool-tip modes in x and y.
    coefficients : CuttingCoefficients
        Cutting coefficients (``Ktc`` [N/m^2], ``Krc``).
    flutes : int
        Number of flutes N, >= 1.
    phi_st : float
        Start immersion angle [rad].
    phi_ex : float
        Exit immersion angle [rad].

    Returns
    -------
    float
        a_lim,min [m] (inf: stable at any depth and speed).
    """
    n_fl, alpha = _check_inputs(dynamics, coefficients, flutes, phi_st, phi_ex)
    freq = _band(dynamics, 4000)

    def re_max(f):
        return np.max(_eigenvalues(dynamics, alpha, np.atleast_1d(f)).real, axis=0)

    re = re_max(freq)
    i = int(np.argmax(re))
    best = re[i]
    if i > 0 and i < freq.size - 1:
        res = minimize_scalar(lambda f: -float(re_max(f)[0]), bounds=(freq[i - 1], freq[i + 1]),
                              method="bounded", options={"xatol": 1e-9 * freq[i]})
        best = max(best, -res.fun)
    if best <= 0.0:
        return math.inf
    return _TWO_PI / (n_fl * coefficients.Ktc * best)
