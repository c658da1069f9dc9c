"""Presliding (Dahl) friction state of a feed axis, beyond the third paper's Eq. 4.

The paper's friction ``F_fr(v) = sgn(v) (F_C + (F_br - F_C) exp(-|v / v_s|^delta)) + sigma v``
(:meth:`~drivesense.machine.linear_motor.LinearMotorAxis.friction_force`) may
take, instead of ``sgn(v)``, a presliding state ``d`` in [-1, 1] that follows
the position: over a travel ``ds`` it relaxes towards ``sgn(ds)`` as
``exp(-|ds| / x_pre)`` (:func:`presliding_direction`).  Sliding, ``d = sgn(v)``
and Eq. 4 is unchanged; at standstill and through reversals the friction
becomes a stiff, hysteretic spring of stiffness about ``F_br / x_pre`` instead
of a sign that flips with the velocity noise.  The state is rate-independent,
so it can be computed from a position trace alone, in one piece or in stream
chunks (:func:`carried_presliding_direction`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from drivesense.errors import ConfigError
from drivesense.machine.validation import signal_array

__all__ = ["presliding_direction", "carried_presliding_direction"]


@njit(cache=True)
def _dahl_direction(position, x_pre, s_prev, d0, decay):
    out = np.empty(position.size)
    d = d0
    prev = s_prev
    for k in range(position.size):
        ds = position[k] - prev
        prev = position[k]
        d *= decay
        if ds > 0.0:
            d = 1.0 + (d - 1.0) * math.exp(-ds / x_pre)
        elif ds < 0.0:
            d = -1.0 + (d + 1.0) * math.exp(ds / x_pre)
        out[k] = d
    return out


def presliding_direction(position, x_pre: float, *, previous_position: float | None = None,
                         direction: float = 0.0, decay: float = 1.0) -> np.ndarray:
    """Presliding friction state ``d`` in [-1, 1] along a position trace (Dahl model, rate-independent).

    Over each step ``ds`` between samples ``d`` relaxes exactly towards
    ``sgn(ds)``: ``d <- sgn(ds) + (d - sgn(ds)) exp(-|ds| / x_pre)``.  Sliding
    over a few ``x_pre`` saturates it at the direction of motion; position
    noise at standstill moves it by about ``noise / x_pre``.

    Parameters
    ----------
    position : array_like
        Axis position [m], 1-D.
    x_pre : float
        Presliding distance [m] (> 0).
    previous_position : float, optional
        Position of the sample before the first [m] (streaming); default: the
        first sample (no step into it).
    direction : float
        State before the first sample [-] (0: unknown, no friction held).
    decay : float
        Factor [-] in (0, 1] on the state at every sample before its step:
        friction held at standstill relaxing under the servo's dither
        (``exp(-dt / tau)`` for a relaxation time ``tau``; 1: none, the pure Dahl model).

    Returns
    -------
    ndarray
        ``d`` per sample.
    """
    s = np.ascontiguousarray(signal_array(position, "position"), dtype=np.float64).ravel()
    if not x_pre > 0:
        raise ConfigError(f"presliding distance 'x_pre' must be > 0 [m], got {x_pre!r}")
    if not -1.0 <= direction <= 1.0:
        raise ConfigError(f"presliding state 'direction' must lie in [-1, 1], got {direction!r}")
    if not 0.0 < decay <= 1.0:
        raise ConfigError(f"presliding 'decay' must lie in (0, 1], got {decay!r}")
    if s.size == 0:
        return s.copy()
    prev = float(s[0]) if previous_position is None else float(previous_position)
    return _dahl_direction(s, float(x_pre), prev, float(direction), float(decay))


def carried_presliding_direction(position, x_pre: float, state: dict | None, key, decay: float = 1.0) -> np.ndarray:
    """:func:`presliding_direction` continued across stream chunks.

    Parameters
    ----------
    position : array_like
        Axis position of this chunk [m], 1-D.
    x_pre : float
        Presliding distance [m] (> 0).
    state : dict or None
        ``{key: (last position [m], direction [-])}`` from the previous chunk,
        updated in place; None: a fresh start, nothing kept.
    key : hashable
        This axis's entry in ``state``.
    decay : float
        Per-sample relaxation factor of the state [-] (see :func:`presliding_direction`).

    Returns
    -------
    ndarray
        ``d`` per sample.
    """
    prev, d0 = state.get(key, (None, 0.0)) if state is not None else (None, 0.0)
    d = presliding_direction(position, x_pre, previous_position=prev, direction=d0, decay=decay)
    if state is not None and d.size:
        state[key] = (float(np.ravel(position)[-1]), float(d[-1]))
    return d
