"""Which candidate terms of the controller-rate model the traces excite at all (before any fit).

A term the motion never excites is left out with the reason (no reversal in
one direction, one speed only, too little travel for a spring or a ripple
period, no slow motion for a Stribeck curve, another axis that never
accelerates); the ripple's spatial period is searched on the residual of the
base fit.  Used by :mod:`drivesense.identify.controller`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.machine.controller_model import friction_direction

__all__ = ["unexcited_terms", "best_period", "STRIBECK_SPEEDS", "PERIODS", "SLIDING_SPEED"]

#: Stribeck velocities tried [m/s].
STRIBECK_SPEEDS = (0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3, 20e-3)
#: Spatial periods searched for the ripple terms [m].
PERIODS = np.geomspace(3e-3, 60e-3, 240)
#: Speed above which an axis slides for the force constant's fit [m/s].
SLIDING_SPEED = 2e-3


def unexcited_terms(axis: str, others: Sequence[str], arrays: Mapping[str, np.ndarray], window_s: float, v_eps: float,
                    fs: float) -> dict[str, str]:
    """Candidate terms the traces do not excite, with the reason.

    Parameters
    ----------
    axis : str
        Axis letter.
    others : sequence of str
        The other axes (their accelerations are cross-inertia candidates).
    arrays : mapping of str to ndarray
        The concatenated traces [A, m, m/s, m/s^2].
    window_s : float
        Logging window [s].
    v_eps : float
        Standstill velocity noise [m/s].
    fs : float
        Trace rate [Hz].
    """
    arr = arrays
    v = arr[f"{axis}_velocity"]
    d = friction_direction(v, arr[f"{axis}_acceleration"], window_s, v_eps)
    moving = np.abs(d) > 0.5
    out = {}
    for name, count in (("coulomb_pos", np.sum(d > 0.5)), ("coulomb_neg", np.sum(d < -0.5))):
        if count < 10:
            out[name] = f"not excited: {count} samples move in the {name[-3:]} direction (need 10)"
    if moving.sum() < 10 or float(np.std(np.abs(v[moving]))) < 1e-3:
        out["viscous"] = "not excited: the axis moves at (almost) one speed only"
    if f"{axis}_position" in arr:
        span = float(np.ptp(arr[f"{axis}_position"]))
        if span < 5e-3:
            out["position"] = f"not excited: the axis travels {span * 1e3:.2g} mm (need 5 mm)"
    else:
        out["position"] = f"no channel {axis}_position"
    slow = moving & (np.abs(v) < 2 * STRIBECK_SPEEDS[-1])
    if slow.sum() < 20:
        out["stribeck"] = f"not excited: {int(slow.sum())} moving samples below {2 * STRIBECK_SPEEDS[-1] * 1e3:g} mm/s"
    for b in others:
        a_b = arr[f"{b}_acceleration"]
        if float(np.max(np.abs(a_b), initial=0.0)) < 0.05:
            out[f"inertia_{b}"] = f"not excited: axis {b} never accelerates above 0.05 m/s^2"
    travelled = float(np.sum(np.abs(v[moving]))) / fs
    if f"{axis}_position" not in arr or travelled < 0.05:
        out["ripple"] = f"not excited: {travelled * 1e3:.3g} mm of travel (need 50 mm for a position-periodic term)"
    return out


def best_period(axis: str, arrays: Mapping[str, np.ndarray], window_s: float, v_eps: float, residual: np.ndarray,
                given: float | None) -> tuple[float, str]:
    """Spatial period [m] of the strongest position-periodic residual, or (0, reason).

    Parameters
    ----------
    axis : str
        Axis letter.
    arrays : mapping of str to ndarray
        The concatenated traces [A, m, m/s, m/s^2].
    window_s : float
        Logging window [s].
    v_eps : float
        Standstill velocity noise [m/s].
    residual : ndarray
        Current residual of the base fit [A].
    given : float, optional
        The period to test instead of searching [m].
    """
    moving = np.abs(arrays[f"{axis}_velocity"]) > max(50.0 * v_eps, SLIDING_SPEED)
    if moving.sum() < 50:
        return 0.0, f"not excited: {int(moving.sum())} samples slide (need 50 for a position-periodic term)"
    s = arrays[f"{axis}_position"][moving]      # sliding samples: at standstill the held friction hides it
    v = arrays[f"{axis}_velocity"][moving]
    periods = np.array([given]) if given else PERIODS
    gains = np.empty(periods.size)
    r = residual[moving] - residual[moving].mean()
    base = float(r @ r)
    for i, lam in enumerate(periods):
        w = np.sinc(v * window_s / lam)
        ph = 2 * math.pi * s / lam
        X = np.column_stack([np.sin(ph) * w, np.cos(ph) * w])
        coef, *_ = np.linalg.lstsq(X, r, rcond=None)
        gains[i] = float(np.sum((X @ coef) ** 2)) / base
    best = int(np.argmax(gains))
    span = float(np.ptp(s))
    if span < 2 * periods[best]:
        return 0.0, f"not excited: {span * 1e3:.3g} mm of travel cover less than two periods of {periods[best] * 1e3:.3g} mm"
    if not given and gains[best] < max(3.0 * float(np.median(gains)), 0.02):
        return 0.0, (f"not determined: no position-periodic residual stands out (best {periods[best] * 1e3:.3g} mm "
                     f"explains {gains[best] * 100:.2g} % of the residual)")
    return float(periods[best]), ""
