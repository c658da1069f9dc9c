"""Presliding distance of the linear-motor axes' friction (step 5 of the identification, beyond the paper).

The Dahl state of :func:`~drivesense.machine.presliding.presliding_direction` turns the friction
over a travel of a few ``x_pre``; with steps 1-4 of :mod:`drivesense.identify.linear_axis` fixed,
``x_pre`` is the bounded scalar minimiser of what remains of the Eq. 2 residual.
"""

from __future__ import annotations

import numpy as np

from drivesense.errors import CoverageError
from drivesense.machine.presliding import presliding_direction

__all__ = ["fit_presliding"]


def fit_presliding(positions, forces, levels, *, bounds: tuple[float, float] = (0.5e-6, 1.0e-3),
                   min_gain: float = 0.01) -> dict:
    """Presliding distance of the Dahl friction state by bounded least squares (step 5).

    Minimises ``sum (f - d(s; x_pre) g)^2`` over ``log x_pre``, where ``d`` is
    :func:`~drivesense.machine.presliding.presliding_direction` of each
    position trace, starting at 0.

    Parameters
    ----------
    positions : sequence of array_like
        Position traces [m] (one per recording, in time order).
    forces : sequence of array_like
        The friction force to explain at each sample [N]: motor force minus
        cogging, restoring, inertial and viscous terms.
    levels : sequence of array_like
        The Stribeck level ``F_C + (F_br - F_C) exp(-|v / v_s|^delta)`` at each sample [N].
    bounds : (float, float)
        Search range of ``x_pre`` [m].
    min_gain : float
        Smallest relative drop of the residual sum of squares between the
        optimum and the search bounds for ``x_pre`` to count as determined [-].

    Returns
    -------
    dict
        ``x_pre`` [m] (0 when not determined), ``determined``, ``rms_n`` (at
        the optimum), ``rms_at_bounds_n``, ``samples``.
    """
    from scipy import optimize as _opt

    pos = [np.ascontiguousarray(p, dtype=np.float64) for p in positions]
    frc = [np.asarray(f, dtype=np.float64) for f in forces]
    lev = [np.asarray(g, dtype=np.float64) for g in levels]
    n = sum(p.size for p in pos)
    if n == 0:
        raise CoverageError("presliding: no samples")

    def sse(log_x: float) -> float:
        x = float(np.exp(log_x))
        return float(sum(np.sum((f - presliding_direction(p, x) * g) ** 2) for p, f, g in zip(pos, frc, lev)))

    lo, hi = np.log(bounds[0]), np.log(bounds[1])
    res = _opt.minimize_scalar(sse, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    best, at_bounds = float(res.fun), (sse(lo), sse(hi))
    gain = 1.0 - best / min(at_bounds) if min(at_bounds) > 0 else 0.0
    determined = bool(gain >= min_gain and lo + 0.05 < res.x < hi - 0.05)
    return {"x_pre": float(np.exp(res.x)) if determined else 0.0, "determined": determined,
            "rms_n": float(np.sqrt(best / n)), "rms_at_bounds_n": [float(np.sqrt(v / n)) for v in at_bounds],
            "relative_gain": float(gain), "samples": int(n)}
