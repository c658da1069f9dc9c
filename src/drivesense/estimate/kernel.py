"""Compiled single-pass kernel shared by batch and streaming estimation.

The kernel runs, sample by sample: the current-loop model on the current
reference, a friction-map lookup at the table position, one FIR per channel,
their sum, and the common IIR cascade.  All state lives in
:class:`KernelState`, so a trace processed in one call or chunk by chunk gives
bit-identical results.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drivesense.estimate.design import ObserverDesign

__all__ = ["FrictionTable", "KernelState", "run_kernel"]


class FrictionTable:
    """Friction to subtract, as a function of table position, on a uniform grid.

    Parameters
    ----------
    values : ndarray
        Friction (as the uncompensated estimator reads it) at each grid point [N];
        a single value is a position-independent tare.
    x0 : float
        Position of the first grid point [m].
    dx : float
        Grid spacing [m].
    """

    __slots__ = ("values", "x0", "dx")

    def __init__(self, values, x0: float = 0.0, dx: float = 1.0) -> None:
        self.values = np.ascontiguousarray(np.atleast_1d(np.asarray(values, dtype=np.float64)))
        self.x0 = float(x0)
        self.dx = float(dx)

    @classmethod
    def zero(cls) -> "FrictionTable":
        """No compensation."""
        return cls([0.0])

    def __call__(self, x) -> np.ndarray:
        """Friction at positions ``x`` [m] (clamped at the ends), in N."""
        if self.values.size == 1:
            return np.full(np.shape(x), self.values[0])
        grid = self.x0 + self.dx * np.arange(self.values.size)
        return np.interp(x, grid, self.values)


class KernelState:
    """Filter state of one estimator run (constant size, whatever the trace length).

    Parameters
    ----------
    design : ObserverDesign
        Discrete observer.
    friction : FrictionTable
        Friction to subtract.
    """

    def __init__(self, design: ObserverDesign, friction: FrictionTable) -> None:
        self.taps = np.ascontiguousarray(design.padded())
        self.sos = np.ascontiguousarray(design.sos)
        self.h_pole = float(design.h_pole)
        self.friction = friction
        n = self.taps.shape[1]
        self.hist = np.zeros((4, 2 * n))
        self.zi = np.zeros((self.sos.shape[0], 2))
        self.scalars = np.zeros(3)  # [head, current-model output, previous current]
        self.started = False
        # steady-state IIR response to a unit constant input (for a transient-free start)
        self.zi_unit = _sos_zi(self.sos)


def _sos_zi(sos: np.ndarray) -> np.ndarray:
    from scipy import signal as sps

    return sps.sosfilt_zi(sos)


def run_kernel(state: KernelState, current, angle, table) -> np.ndarray:
    """Process aligned samples and return the force estimate [N] for each.

    Parameters
    ----------
    state : KernelState
        Carried state (modified in place).
    current, angle, table : ndarray
        Current reference [A], motor angle [rad], table position [m].
    """
    current = np.ascontiguousarray(current, dtype=np.float64)
    angle = np.ascontiguousarray(angle, dtype=np.float64)
    table = np.ascontiguousarray(table, dtype=np.float64)
    out = np.empty(current.size)
    if current.size == 0:
        return out
    f = state.friction
    if not state.started:
        _prime(state.taps, state.hist, state.scalars, state.zi, state.zi_unit, state.h_pole,
               current[0], angle[0], table[0], f.values, f.x0, f.dx)
        state.started = True
    _kernel(state.taps, state.sos, state.h_pole, f.values, f.x0, f.dx,
            state.hist, state.scalars, state.zi, current, angle, table, out)
    return out


@njit(cache=True)
def _lookup(values, x0, dx, x):
    n = values.size
    if n == 1:
        return values[0]
    u = (x - x0) / dx
    if u <= 0.0:
        return values[0]
    if u >= n - 1:
        return values[n - 1]
    i = int(u)
    fr = u - i
    return values[i] + fr * (values[i + 1] - values[i])


@njit(cache=True)
def _prime(taps, hist, scalars, zi, zi_unit, h_pole, i0, th0, x0, fvals, fx0, fdx):
    """Fill the state as if the signals had been constant at their first values."""
    n = taps.shape[1]
    f0 = _lookup(fvals, fx0, fdx, x0)
    for k in range(2 * n):
        hist[0, k] = i0
        hist[1, k] = th0
        hist[2, k] = x0
        hist[3, k] = f0
    scalars[0] = 0.0
    scalars[1] = i0
    scalars[2] = i0
    r = 0.0
    for k in range(n):
        r += taps[0, k] * i0 + taps[1, k] * th0 + taps[2, k] * x0 + taps[3, k] * f0
    for s in range(zi.shape[0]):
        zi[s, 0] = zi_unit[s, 0] * r
        zi[s, 1] = zi_unit[s, 1] * r


@njit(cache=True, fastmath=True)
def _kernel(taps, sos, h_pole, fvals, fx0, fdx, hist, scalars, zi, cur, ang, tab, out):
    n = taps.shape[1]
    nsec = sos.shape[0]
    head = int(scalars[0])
    y_h = scalars[1]
    u_prev = scalars[2]
    use_h = h_pole > 0.0
    for i in range(cur.size):
        if use_h:
            y_h = h_pole * y_h + (1.0 - h_pole) * u_prev
            u_prev = cur[i]
        else:
            y_h = cur[i]
        head -= 1
        if head < 0:
            head = n - 1
        fv = _lookup(fvals, fx0, fdx, tab[i])
        hist[0, head] = y_h
        hist[0, head + n] = y_h
        hist[1, head] = ang[i]
        hist[1, head + n] = ang[i]
        hist[2, head] = tab[i]
        hist[2, head + n] = tab[i]
        hist[3, head] = fv
        hist[3, head + n] = fv
        r = 0.0
        for k in range(n):
            j = head + k
            r += taps[0, k] * hist[0, j] + taps[1, k] * hist[1, j] + taps[2, k] * hist[2, j] + taps[3, k] * hist[3, j]
        x = r
        for s in range(nsec):
            b0 = sos[s, 0]
            b1 = sos[s, 1]
            b2 = sos[s, 2]
            a1 = sos[s, 4]
            a2 = sos[s, 5]
            y = b0 * x + zi[s, 0]
            zi[s, 0] = b1 * x - a1 * y + zi[s, 1]
            zi[s, 1] = b2 * x - a2 * y
            x = y
        out[i] = x
    scalars[0] = head
    scalars[1] = y_h
    scalars[2] = u_prev
