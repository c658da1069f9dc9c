"""How much of its edge a damaged tooth lost: a mechanistic fit of the force pattern before and after.

The breakage detector (:mod:`drivesense.events.breakage`) hands over two
patterns of the force along one axis over one spindle revolution, each the
mean force per angle bin: ``base`` from revolutions before the event and
``after`` from a whole revolution after it.  Both are modelled as the sum over
the ``N`` teeth of one tooth's force pulse, shifted by the tooth pitch
``2 pi / N``.  The pulse is the mechanistic one: with the tooth angle ``phi``
and the chip ``h = f_z sin phi``, a tooth's force along any axis is a sum of
a cutting part in ``sin phi cos phi`` and ``sin^2 phi`` (proportional to the
chip) and an edge part in ``cos phi`` and ``sin phi`` (not), nonzero over the
engagement ``[phi_st, phi_ex]`` and spread over the helix lag ``lag`` (the
axial slices enter one after the other).  A tooth that loses the share ``L``
of its edge loses ``L`` of both parts, and the next tooth takes the chip it
leaves: its cutting part grows by ``L`` times the lost tooth's::

    base  = sum_m S^m (b_m C + E)
    after = base + L (-S^j (b_j C + E) + S^(j+1) b_j C)

(``S`` a shift by one pitch, ``C`` and ``E`` the cutting and edge pulses;
runout gives each tooth's chip a constant offset, ``(sin phi + rho_m)`` in feeds
per tooth, which ``b_m C`` stands for here).  The engagement,
the lag and the tooth's place are searched on a grid (every other engagement
limit first, then the neighbours of the best), the four coefficients of
``C`` and ``E`` and the loss ``L`` by least squares on both patterns together
(for every grid point and loss the normal equations' inverse does not depend
on the data and is kept);
then the chip offsets and the rest are refined in turn.  The tooth-pass
sum alone (``base``) cannot tell one tooth's pulse from its overlap with the
others' (slotting, many teeth); the loss of one tooth and the chip carried to
the next break that symmetry, and the mechanistic pulse closes the rest.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["EdgeLossFit", "fit_edge_loss", "pattern_bins", "pattern_means", "warm_edge_loss"]

_TWO_PI = 2.0 * math.pi
#: The grids searched: engagement limits [deg] (every pair), helix lags [deg], losses [-].
_ANGLE_STEP_DEG = 15.0
_LAGS_DEG = (0.0, 10.0, 20.0, 35.0, 50.0)
_LOSSES = np.linspace(0.0, 1.3, 14)
_SUB = 8
#: The engagement grid is searched coarse first (every other limit): around this many of its best points
#: the fine grid's neighbours (one step of each limit and of the lag) are tried.
_COARSE_KEEP = 4


@dataclass(frozen=True)
class EdgeLossFit:
    """The result of :func:`fit_edge_loss`.

    Attributes
    ----------
    edge_loss : float
        Share of the damaged tooth's edge lost, 0..1 [-].
    tooth_angle_deg : float
        Spindle angle at which the damaged tooth's angle is zero (modulo a revolution) [deg].
    engagement_deg : tuple of float
        The engagement ``(phi_st, phi_ex)`` the fit found [deg].
    lag_deg : float
        The helix lag the fit found [deg].
    residual : float
        RMS of what the model leaves of both patterns over their RMS [-].
    """

    edge_loss: float
    tooth_angle_deg: float
    engagement_deg: tuple
    lag_deg: float
    residual: float


def pattern_bins(teeth: int, target: int = 72) -> int:
    """Bins of a revolution for the patterns: a multiple of ``teeth`` near ``target``.

    Parameters
    ----------
    teeth : int
        Number of teeth.
    target : int
        Wanted number of bins.
    """
    return int(teeth * max(2, round(target / teeth)))


def warm_edge_loss(bins: int, teeth: int) -> None:
    """Build (once per process) the grid :func:`fit_edge_loss` searches for ``bins`` bins and ``teeth`` teeth.

    A live detector calls it when it starts, so that its first alarm is not held up by it.

    Parameters
    ----------
    bins : int
        Bins of a revolution (:func:`pattern_bins`).
    teeth : int
        Number of teeth (>= 2).
    """
    _grid_tables(int(bins), int(teeth))


def pattern_means(sums, counts) -> np.ndarray:
    """Mean per angle bin of a revolution, empty bins interpolated (circularly) from their neighbours.

    Parameters
    ----------
    sums : array_like
        Per bin, the sum of the force [N].
    counts : array_like
        Per bin, the number (or weight) of the samples [-].
    """
    sums = np.asarray(sums, dtype=float)
    counts = np.asarray(counts, dtype=float)
    ok = counts > 0
    out = np.zeros(sums.size)
    out[ok] = sums[ok] / counts[ok]
    if 0 < ok.sum() < sums.size:
        x = np.arange(sums.size)
        out = np.interp(x, x[ok], out[ok], period=sums.size)
    return out


def _bases(nb: int, lo: float, hi: float, lag: float) -> np.ndarray:
    """The four pulses (cutting: ``sin cos``, ``sin^2``; edge: ``cos``, ``sin``) of a tooth at angle 0, (4, nb)."""
    theta = (np.arange(nb) + 0.5) / nb * _TWO_PI
    out = np.zeros((4, nb))
    for q in range(_SUB):
        phi = (theta - lag * (q + 0.5) / _SUB) % _TWO_PI
        inside = (phi >= lo) & (phi <= hi)
        s, c = np.sin(phi), np.cos(phi)
        out += np.stack([s * c, s * s, c, s]) * inside / _SUB
    return out


def _design(g: np.ndarray, teeth: int, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Columns of the model for both patterns: the part without the loss and the part per unit loss.

    Tooth ``m``'s chip is ``sin phi + offsets[m]`` (runout moves each tooth's edge in or out by a constant,
    in feeds per tooth), its force that chip times the cutting pulse plus the edge pulse.
    """
    nb = g.shape[-1]
    per = nb // teeth
    turned = g[..., (np.arange(nb)[None, :] - per * np.arange(teeth)[:, None]) % nb]   # (..., 4, teeth, nb)
    tot = turned.sum(axis=-2)
    tot[..., :2, :] += np.einsum("...ktn,t->...kn", turned[..., 2:, :, :], offsets)
    t0 = g.copy()
    t0[..., :2, :] += offsets[0] * g[..., 2:, :]
    lost = -t0
    lost[..., :2, :] += np.roll(t0[..., :2, :], per, axis=-1)
    m0 = np.swapaxes(np.concatenate([tot, tot], axis=-1), -1, -2)
    m1 = np.swapaxes(np.concatenate([np.zeros_like(tot), lost], axis=-1), -1, -2)
    return m0, m1


def _scan(m0, m1, y, losses):
    """Least squares over the coefficients for every loss and every column of ``y``: (residual, coefficients).

    ``m0`` and ``m1`` may carry leading batch axes (one per grid point); the results then carry them too.
    """
    t = np.swapaxes
    a00, a01, a11 = t(m0, -1, -2) @ m0, t(m0, -1, -2) @ m1, t(m1, -1, -2) @ m1
    b0, b1 = t(m0, -1, -2) @ y, t(m1, -1, -2) @ y
    ls = losses[:, None, None]
    ridge = 1e-9 * (np.trace(a00, axis1=-2, axis2=-1)[..., None, None, None] + 1e-300) * np.eye(4)
    k = a00[..., None, :, :] + ls * (a01 + t(a01, -1, -2))[..., None, :, :] + ls ** 2 * a11[..., None, :, :] + ridge
    rhs = b0[..., None, :, :] + ls * b1[..., None, :, :]
    coef = np.linalg.solve(k, rhs)
    res = np.sum(y * y, axis=0) - np.sum(rhs * coef, axis=-2)
    return res, coef


def fit_edge_loss(base_sums, base_counts, after_sums, after_counts, teeth: int) -> EdgeLossFit | None:
    """The damaged tooth's edge loss from the force pattern before and after (see the module docstring).

    Parameters
    ----------
    base_sums : array_like
        Per angle bin of a revolution (spindle angle from 0), the sum of the force before the event [N];
        ``pattern_bins(teeth)`` bins.
    base_counts : array_like
        Per bin, the number (or weight) of the samples summed [-].
    after_sums : array_like
        The same sums over a whole revolution after the event [N].
    after_counts : array_like
        Their counts [-].
    teeth : int
        Number of teeth (>= 2).

    Returns
    -------
    EdgeLossFit or None
        None when a pattern is empty or flat (nothing to fit).
    """
    base = pattern_means(base_sums, base_counts)
    after = pattern_means(after_sums, after_counts)
    nb = base.size
    if teeth < 2 or nb % teeth or not np.any(np.asarray(after_counts) > 0) or not np.any(np.asarray(base_counts) > 0):
        return None
    scale = float(np.sqrt(np.mean(base ** 2) + np.mean(after ** 2)))
    if not scale > 0.0:
        return None
    base = base / scale
    after = after / scale
    idx = (np.arange(nb)[:, None] + np.arange(nb)[None, :]) % nb     # column r: the patterns turned by r bins
    y = np.concatenate([base[idx], after[idx]], axis=0)
    offsets = np.zeros(teeth)
    fine = np.linspace(0.0, 1.3, 131)
    order = None
    points, bases = _grid_tables(nb, teeth)[:2]
    for _ in range(2):
        # the grid with the chip offsets held, then the offsets, the pulse and the loss refined in turn
        p, r, loss, res, order = _grid(y, nb, teeth, offsets, order)
        g = bases[p]
        yr = y[:, r:r + 1]
        for _ in range(3):
            _, coef = _scan(*_design(g, teeth, offsets), yr, np.array([loss]))
            offsets = _fit_offsets(g, coef[0, :, 0], teeth, loss, yr[:, 0], offsets)
            rr, coef = _scan(*_design(g, teeth, offsets), yr, fine)
            li = int(np.argmin(rr[:, 0]))
            loss, res = float(fine[li]), float(rr[li, 0])
    lo, hi, lag = points[p]
    resid = math.sqrt(max(res, 0.0) / max(float(np.sum(yr ** 2)), 1e-300))
    return EdgeLossFit(edge_loss=float(min(max(loss, 0.0), 1.0)), tooth_angle_deg=float(r * 360.0 / nb),
                       engagement_deg=(float(np.rad2deg(lo)), float(np.rad2deg(hi))), lag_deg=float(np.rad2deg(lag)),
                       residual=resid)


_PAIRS = np.triu_indices(8)


@functools.lru_cache(maxsize=16)
def _grid_tables(nb: int, teeth: int):
    """Every grid point's engagement and lag with its design for equal teeth (no runout), kept per (nb, teeth).

    The residual of the least squares at loss ``l`` is ``y'y - c' A_l c`` with ``c = (M0'y, M1'y)`` and
    ``A_l`` built from ``K_l^-1``; ``K_l`` does not depend on the data, so the weights of the 36 products
    of ``c`` are kept here for every point and loss.
    """
    angles = np.deg2rad(np.arange(0.0, 180.0 + 1e-9, _ANGLE_STEP_DEG))
    steps = [(a, b, c) for a, b in itertools.combinations(range(angles.size), 2) for c in range(len(_LAGS_DEG))]
    points = [(angles[a], angles[b], np.deg2rad(_LAGS_DEG[c])) for a, b, c in steps]
    at = {s: p for p, s in enumerate(steps)}
    coarse = np.array([p for p, (a, b, c) in enumerate(steps) if a % 2 == 0 and b % 2 == 0])
    near = [np.array(sorted({at[(a + i, b + j, c + k)] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                             if (a + i, b + j, c + k) in at})) for a, b, c in steps]
    zero = np.zeros(teeth)
    bases = np.stack([_bases(nb, lo, hi, lag) for lo, hi, lag in points])           # (P, 4, nb)
    m0s, m1s = zip(*(_design(g, teeth, zero) for g in bases))
    m0, m1 = np.stack(m0s), np.stack(m1s)                                 # (P, 2nb, 4)
    t = np.swapaxes
    a00, a01, a11 = t(m0, 1, 2) @ m0, t(m0, 1, 2) @ m1, t(m1, 1, 2) @ m1
    ls = _LOSSES[None, :, None, None]
    ridge = 1e-9 * (np.trace(a00, axis1=1, axis2=2)[:, None, None, None] + 1e-300) * np.eye(4)
    ki = np.linalg.inv(a00[:, None] + ls * (a01 + t(a01, 1, 2))[:, None] + ls ** 2 * a11[:, None] + ridge)
    a = np.concatenate([np.concatenate([ki, ls * ki], axis=3), np.concatenate([ls * ki, ls ** 2 * ki], axis=3)],
                       axis=2)                                            # (P, L, 8, 8)
    i, j = _PAIRS
    w = a[:, :, i, j] * np.where(i == j, 1.0, 2.0)                        # (P, L, 36)
    cols = np.ascontiguousarray(np.concatenate([t(m0, 1, 2), t(m1, 1, 2)], axis=1))   # (P, 8, 2nb)
    return points, bases, cols, np.ascontiguousarray(w), coarse, near


def _residuals(y, cols, w, sub):
    """Residuals (S, L, nb) of the grid points ``sub`` for every loss and every turn (column of ``y``)."""
    c = np.swapaxes((cols[sub] @ y), 0, 1)                                # (8, S, nb)
    prod = np.empty((len(_PAIRS[0]), len(sub), y.shape[1]))
    for k, (i, j) in enumerate(zip(*_PAIRS)):
        np.multiply(c[i], c[j], out=prod[k])
    return np.sum(y * y, axis=0) - w[sub] @ np.swapaxes(prod, 0, 1)


def _grid(y, nb, teeth, offsets, order=None, keep=12):
    """The engagement, lag, turn and loss of least residual on the grids (chip offsets held), and the grid
    points in the order of their fit.

    With offsets (runout) only the ``keep`` best grid points of the fit without them (``order``) are tried.
    """
    points, bases, cols, w, coarse, near = _grid_tables(nb, teeth)
    if order is not None and np.any(offsets):
        tried = order[:keep]
        r2, _ = _scan(*_design(bases[tried], teeth, offsets), y, _LOSSES)        # (keep, L, nb)
        k, li, r = np.unravel_index(int(np.argmin(r2)), r2.shape)
        return int(tried[k]), int(r), float(_LOSSES[li]), float(r2[k, li, r]), order
    rough = _residuals(y, cols, w, coarse).reshape(coarse.size, -1)
    best = coarse[np.argsort(rough.min(axis=1))[:_COARSE_KEEP]]
    sub = np.setdiff1d(np.concatenate([near[p] for p in best]), coarse)
    flat = np.concatenate([rough, _residuals(y, cols, w, sub).reshape(sub.size, -1)])
    ids = np.concatenate([coarse, sub])
    ranked = np.argsort(flat.min(axis=1))
    order, row = ids[ranked], flat[ranked[0]]
    p = int(order[0])
    li, r = np.unravel_index(int(np.argmin(row)), (len(_LOSSES), nb))
    return p, int(r), float(_LOSSES[li]), float(row.min()), order


def _fit_offsets(g, coef, teeth, loss, y, offsets):
    """Each tooth's chip offset (runout) by least squares with the pulse and the loss held (mean zero)."""
    nb = g.shape[1]
    per = nb // teeth
    cut0 = coef[0] * g[0] + coef[1] * g[1]
    cut1 = coef[0] * g[2] + coef[1] * g[3]          # what a unit offset of the chip adds
    edge = coef[2] * g[2] + coef[3] * g[3]
    cols = np.zeros((2 * nb, teeth))
    fixed = np.zeros(2 * nb)
    for m in range(teeth):
        c1 = np.roll(cut1, m * per)
        cols[:nb, m] = c1
        cols[nb:, m] = c1
        f = np.roll(cut0 + edge, m * per)
        fixed[:nb] += f
        fixed[nb:] += f
    # the loss: tooth 0 keeps (1 - loss) of its chip and edge, tooth 1 takes loss of tooth 0's chip
    cols[nb:, 0] += -loss * cut1 + loss * np.roll(cut1, per)
    fixed[nb:] += -loss * (cut0 + edge) + loss * np.roll(cut0, per)
    if not np.any(cols):
        return offsets
    b, *_ = np.linalg.lstsq(cols, y - fixed, rcond=None)
    if not np.all(np.isfinite(b)):
        return offsets
    return np.clip(b - np.mean(b), -3.0, 3.0)
