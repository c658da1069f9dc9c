"""Friction physics: LuGre dynamic friction with Stribeck curve, position ripple and load.

The LuGre model (Canudas de Wit et al., 1995) gives presliding hysteresis and
stiction: a bristle deflection ``z`` [m] obeys

    dz/dt = v - sigma0 |v| z / g(v),   g(v) = F_c + (F_s - F_c) exp(-(v/v_s)^2)

and the friction force is ``F = sigma0 z + sigma1 dz/dt + sigma2 v``.
drivesense adds what real axes show on top (and what no estimator models):
a Coulomb level that ripples with position (several wavelengths), drifts slowly
along the travel, and grows with the normal load on the guides.

Everything here is translational: motor-side friction torque is written as a
force through the screw radius (``T_fric / R``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

__all__ = ["Ripple", "LuGreFriction", "lugre_step", "ripple_value", "coulomb_level"]


@dataclass(frozen=True)
class Ripple:
    """One position-periodic friction component.

    Parameters
    ----------
    wavelength : float
        Period along the coordinate [m].
    amplitude : float
        Force amplitude [N].
    phase : float
        Phase [rad].
    """

    wavelength: float
    amplitude: float
    phase: float = 0.0


@dataclass(frozen=True)
class LuGreFriction:
    """LuGre friction with ripple, drift and load dependence.

    Parameters
    ----------
    F_c : float
        Coulomb (kinetic) friction level [N].
    F_s : float
        Static (breakaway) friction level [N], ``>= F_c``.
    v_s : float
        Stribeck velocity [m/s].
    sigma0 : float
        Bristle (presliding) stiffness [N/m].
    sigma1 : float
        Bristle damping [N*s/m].
    sigma2 : float
        Viscous coefficient [N*s/m] (on top of the linear model's damping).
    ripples : tuple of Ripple
        Position-periodic additions to the Coulomb level.
    drift_per_m : float
        Linear change of the Coulomb level along the travel [N/m].
    load_coefficient : float
        Extra Coulomb friction per newton of extra normal load [-].
    """

    F_c: float
    F_s: float
    v_s: float
    sigma0: float
    sigma1: float
    sigma2: float = 0.0
    ripples: tuple[Ripple, ...] = field(default_factory=tuple)
    drift_per_m: float = 0.0
    load_coefficient: float = 0.0

    def coulomb_level(self, position, normal_load=0.0):
        """Coulomb level at ``position`` [m] with extra ``normal_load`` [N], in N."""
        x = np.asarray(position, dtype=float)
        level = self.F_c + self.drift_per_m * x + self.load_coefficient * np.asarray(normal_load, float)
        for r in self.ripples:
            level = level + r.amplitude * np.sin(2.0 * math.pi * x / r.wavelength + r.phase)
        return level

    def steady_state(self, velocity, position=0.0, normal_load=0.0):
        """Steady sliding friction force at constant ``velocity`` [m/s], in N."""
        v = np.asarray(velocity, dtype=float)
        g = self.coulomb_level(position, normal_load) + (self.F_s - self.F_c) * np.exp(-((v / self.v_s) ** 2))
        return np.sign(v) * g + self.sigma2 * v

    def scaled(self, factor: float) -> "LuGreFriction":
        """A copy with Coulomb, static and viscous levels scaled by ``factor`` (run-to-run variation)."""
        return replace(self, F_c=self.F_c * factor, F_s=self.F_s * factor, sigma2=self.sigma2 * factor)

    def pack(self) -> np.ndarray:
        """Parameters as a flat float array for the compiled simulator.

        Layout: ``[F_c, F_s, v_s, sigma0, sigma1, sigma2, drift, load_coef, n, (wl, amp, phase)*n]``.
        """
        head = [self.F_c, self.F_s, self.v_s, self.sigma0, self.sigma1, self.sigma2,
                self.drift_per_m, self.load_coefficient, float(len(self.ripples))]
        for r in self.ripples:
            head += [r.wavelength, r.amplitude, r.phase]
        return np.asarray(head, dtype=np.float64)


@njit(cache=True, fastmath=False)
def ripple_value(p: np.ndarray, x: float) -> float:
    """Coulomb-level addition from drift and ripples of packed parameters ``p`` at ``x`` [m]."""
    value = p[6] * x
    n = int(p[8])
    for k in range(n):
        wl = p[9 + 3 * k]
        value += p[10 + 3 * k] * math.sin(2.0 * math.pi * x / wl + p[11 + 3 * k])
    return value


@njit(cache=True, fastmath=False)
def coulomb_level(p: np.ndarray, x: float, load: float) -> float:
    """Coulomb level [N] of packed parameters ``p`` at position ``x`` [m] with extra normal ``load`` [N]."""
    level = p[0] + ripple_value(p, x) + p[7] * load
    return level if level > 0.0 else 0.0


@njit(cache=True, fastmath=False)
def lugre_step(p: np.ndarray, z: float, v: float, F_c: float, dt: float):
    """Advance the bristle state over ``dt`` at velocity ``v`` and return ``(z_new, force)``.

    ``F_c`` is the local Coulomb level from :func:`coulomb_level` (position
    and load change little within a sub-step).  The bristle equation is
    integrated exactly for constant ``v`` over the step (exponential approach
    to the steady deflection), which is stable for any ``sigma0``.  ``force``
    is the friction force [N] opposing motion.
    """
    g = F_c + (p[1] - p[0]) * math.exp(-(v / p[2]) ** 2)
    if g < 1e-12:
        g = 1e-12
    sigma0 = p[3]
    av = abs(v)
    if av > 0.0:
        z_ss = g / sigma0 * (1.0 if v > 0 else -1.0)
        decay = math.exp(-sigma0 * av * dt / g)
        z_new = z_ss + (z - z_ss) * decay
    else:
        z_new = z
    dz = (z_new - z) / dt
    force = sigma0 * z_new + p[4] * dz + p[5] * v
    return z_new, force
