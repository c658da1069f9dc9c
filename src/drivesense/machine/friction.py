"""Friction physics: LuGre dynamic friction with Stribeck curve, position ripple and load.

The LuGre model (Canudas de Wit et al., 1995) gives presliding hysteresis and
stiction: a bristle deflection ``z`` [m] obeys

    dz/dt = v - sigma0 |v| z / g(v),   g(v) = F_c + (F_s - F_c) exp(-(v/v_s)^2)

and the friction force is ``F = sigma0 z + sigma1 dz/dt + sigma2 v``.
drivesense adds what real axes show on top (and what no estimator models):
a Coulomb level that ripples with position (several wavelengths), drifts slowly
along the travel, and grows with the normal load on the guides.

This module holds the one implementation of that physics used by both
simulators (the ball-screw stage, :mod:`drivesense.sim.servo`, and the
linear-motor machine, :mod:`drivesense.sim.linear_machine`):

* :func:`ripple_sum` -- a sum of position-periodic sines (friction ripple,
  cogging, screw lead error);
* :func:`coulomb_level` -- the local Coulomb level with drift, ripple and load,
  under the clamping rule below;
* :func:`lugre_step` -- exact integration of the bristle state over one step.

All three are compiled (numba) and take their parameters as named tuples
(:class:`RippleParams`, :class:`LuGreParams`), built by
:func:`ripple_params` and :meth:`LuGreFriction.params`.

Clamping rule
-------------
The Coulomb level ``F_c + drift x + load_coefficient N + sum ripples`` is
clamped at 0 N from below: friction only ever opposes motion, so ripple,
drift or a guide unloaded by a negative normal force ``N`` may lower the
level to zero, never below (a negative level would make friction drive the
axis).  The static excess ``F_s - F_c`` rides on top of the clamped level
unchanged.  The resulting Stribeck level ``g`` is then floored at
:data:`G_MIN` (1e-9 N): that floor is a guard against dividing by zero in
the bristle equation, not physics -- with ``g`` at the floor the bristles
hold at most a nano-newton.

Everything here is translational: motor-side friction torque is written as a
force through the screw radius (``T_fric / R``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple, Sequence

import numpy as np
from numba import njit

__all__ = ["Ripple", "RippleParams", "LuGreParams", "LuGreFriction", "G_MIN", "ripple_params", "ripple_values",
           "ripple_sum", "coulomb_level", "lugre_step"]

#: Floor of the Stribeck level ``g`` in the bristle equation [N] (a division guard, see the module notes).
G_MIN = 1e-9


@dataclass(frozen=True)
class Ripple:
    """One position-periodic component ``amplitude * sin(2 pi x / wavelength + phase)``.

    Parameters
    ----------
    wavelength : float
        Period along the coordinate [m].
    amplitude : float
        Amplitude in the unit of the quantity it adds to ([N] for friction
        and cogging, [m] for a lead error).
    phase : float
        Phase [rad].
    """

    wavelength: float
    amplitude: float
    phase: float = 0.0


class RippleParams(NamedTuple):
    """Ripple components as arrays for compiled code (see :func:`ripple_params`).

    Attributes
    ----------
    wavelength : ndarray
        Periods along the coordinate [m].
    amplitude : ndarray
        Amplitudes (unit of the quantity they add to: [N] or [m]).
    phase : ndarray
        Phases [rad].
    """

    wavelength: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray


class LuGreParams(NamedTuple):
    """LuGre friction parameters for compiled code (see :meth:`LuGreFriction.params`).

    Attributes
    ----------
    F_c : float
        Coulomb level at coordinate 0 without load [N].
    F_s : float
        Static level at coordinate 0 without load [N]; ``F_s - F_c`` is the
        static excess added to the local Coulomb level.
    v_s : float
        Stribeck velocity [m/s].
    sigma0 : float
        Bristle stiffness [N/m] (> 0).
    sigma1 : float
        Bristle damping [N*s/m].
    sigma2 : float
        Viscous coefficient [N*s/m].
    drift_per_m : float
        Change of the Coulomb level along the coordinate [N/m].
    load_coefficient : float
        Extra Coulomb level per newton of normal load [-].
    ripple : RippleParams
        Position-periodic additions to the Coulomb level [N].
    """

    F_c: float
    F_s: float
    v_s: float
    sigma0: float
    sigma1: float
    sigma2: float
    drift_per_m: float
    load_coefficient: float
    ripple: RippleParams


def ripple_params(ripples: Sequence[Ripple]) -> RippleParams:
    """Pack ripple components into the arrays the compiled code reads.

    Parameters
    ----------
    ripples : sequence of Ripple
        Components (may be empty).

    Returns
    -------
    RippleParams
        Wavelengths [m], amplitudes and phases [rad], float64, C-contiguous.
    """
    return RippleParams(np.array([r.wavelength for r in ripples], dtype=np.float64),
                        np.array([r.amplitude for r in ripples], dtype=np.float64),
                        np.array([r.phase for r in ripples], dtype=np.float64))


@njit(cache=True, inline="always")
def ripple_sum(r: RippleParams, x: float, base: float = 0.0) -> float:
    """Sum of ripple components at coordinate ``x``.

    ``base + sum_k A_k sin(2 pi x / lambda_k + phi_k)``, accumulated in the
    order of the components, starting from ``base``.

    Parameters
    ----------
    r : RippleParams
        Components (wavelengths [m], amplitudes, phases [rad]).
    x : float
        Coordinate [m].
    base : float
        Value the sum starts from (e.g. a linear drift term), in the unit of
        the amplitudes.

    Returns
    -------
    float
        The sum, in the unit of the amplitudes ([N] or [m]).
    """
    s = base
    for k in range(r.wavelength.size):
        s += r.amplitude[k] * math.sin(2.0 * math.pi * x / r.wavelength[k] + r.phase[k])
    return s


@njit(cache=True)
def _ripple_array(r: RippleParams, x: np.ndarray) -> np.ndarray:
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = ripple_sum(r, x[i])
    return out


def ripple_values(ripples: Sequence[Ripple] | RippleParams, x) -> np.ndarray:
    """:func:`ripple_sum` over an array of coordinates (for NumPy callers).

    Parameters
    ----------
    ripples : sequence of Ripple or RippleParams
        Components.
    x : array_like
        Coordinates [m].

    Returns
    -------
    ndarray
        The ripple sum at each coordinate (shape of ``x``; unit of the amplitudes).
    """
    r = ripples if isinstance(ripples, RippleParams) else ripple_params(ripples)
    xa = np.asarray(x, dtype=np.float64)
    return _ripple_array(r, np.ascontiguousarray(xa.ravel())).reshape(xa.shape)


@njit(cache=True, inline="always")
def coulomb_level(p: LuGreParams, x: float, load: float) -> float:
    """Local Coulomb level with drift, ripple and load, clamped at zero.

    ``max(0, F_c + (drift x + sum ripples) + load_coefficient load)``; see the
    module notes for the clamping rule.

    Parameters
    ----------
    p : LuGreParams
        Friction parameters.
    x : float
        Coordinate of the ripple and drift [m].
    load : float
        Extra normal load on the guides [N] (negative: unloaded).

    Returns
    -------
    float
        Coulomb level [N], >= 0.
    """
    level = p.F_c + ripple_sum(p.ripple, x, p.drift_per_m * x) + p.load_coefficient * load
    return level if level > 0.0 else 0.0


@njit(cache=True)
def _coulomb_array(p: LuGreParams, x: np.ndarray, load: np.ndarray) -> np.ndarray:
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = coulomb_level(p, x[i], load[i])
    return out


@njit(cache=True, inline="always")
def lugre_step(p: LuGreParams, z: float, v: float, F_c: float, dt: float):
    """Advance the bristle state over ``dt`` at constant velocity ``v``.

    The bristle equation is integrated exactly for constant ``v`` (an
    exponential approach to the steady deflection ``sgn(v) g / sigma0``),
    which is stable for any ``sigma0``; at ``v = 0`` the bristles hold.

    Parameters
    ----------
    p : LuGreParams
        Friction parameters (``F_s - F_c``, ``v_s``, ``sigma0..2`` are read).
    z : float
        Bristle deflection at the start of the step [m].
    v : float
        Sliding velocity over the step [m/s].
    F_c : float
        Local Coulomb level [N] from :func:`coulomb_level` (position and
        load change little within a step).
    dt : float
        Step [s].

    Returns
    -------
    z_new : float
        Bristle deflection at the end of the step [m].
    force : float
        Friction force opposing motion [N]:
        ``sigma0 z_new + sigma1 (z_new - z) / dt + sigma2 v``.
    """
    g = F_c + (p.F_s - p.F_c) * math.exp(-(v / p.v_s) ** 2)
    if g < G_MIN:
        g = G_MIN
    sigma0 = p.sigma0
    av = abs(v)
    if av > 0.0:
        z_ss = g / sigma0 * (1.0 if v > 0 else -1.0)
        decay = math.exp(-sigma0 * av * dt / g)
        z_new = z_ss + (z - z_ss) * decay
    else:
        z_new = z
    dz = (z_new - z) / dt
    force = sigma0 * z_new + p.sigma1 * dz + p.sigma2 * v
    return z_new, force


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
        Position-periodic additions to the Coulomb level [N].
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

    def params(self) -> LuGreParams:
        """The parameters as the named tuple the compiled simulators read.

        Returns
        -------
        LuGreParams
        """
        return LuGreParams(float(self.F_c), float(self.F_s), float(self.v_s), float(self.sigma0),
                           float(self.sigma1), float(self.sigma2), float(self.drift_per_m),
                           float(self.load_coefficient), ripple_params(self.ripples))

    def coulomb_level(self, position, normal_load=0.0):
        """Coulomb level [N] at ``position`` [m] with extra ``normal_load`` [N] (:func:`coulomb_level`).

        Parameters
        ----------
        position : float or array_like
            Coordinate [m].
        normal_load : float or array_like
            Extra normal load [N] (broadcast against ``position``).

        Returns
        -------
        float or ndarray
            Coulomb level [N], clamped at 0 (module notes).
        """
        x, n = np.broadcast_arrays(np.asarray(position, dtype=np.float64), np.asarray(normal_load, np.float64))
        out = _coulomb_array(self.params(), np.ascontiguousarray(x.ravel()), np.ascontiguousarray(n.ravel()))
        return out.reshape(x.shape)[()]

    def steady_state(self, velocity, position=0.0, normal_load=0.0):
        """Steady sliding friction force at constant ``velocity``.

        ``sgn(v) (F_c(x, N) + (F_s - F_c) exp(-(v / v_s)^2)) + sigma2 v``, the
        limit of :func:`lugre_step` at constant velocity.

        Parameters
        ----------
        velocity : float or array_like
            Sliding velocity [m/s].
        position : float or array_like
            Coordinate of ripple and drift [m].
        normal_load : float or array_like
            Extra normal load [N].

        Returns
        -------
        float or ndarray
            Friction force [N].
        """
        v = np.asarray(velocity, dtype=float)
        g = self.coulomb_level(position, normal_load) + (self.F_s - self.F_c) * np.exp(-((v / self.v_s) ** 2))
        return np.sign(v) * np.maximum(g, G_MIN) + self.sigma2 * v

    def scaled(self, factor: float) -> "LuGreFriction":
        """A copy with Coulomb, static and viscous levels scaled by ``factor`` [-] (run-to-run variation).

        Parameters
        ----------
        factor : float
            Scale of the three levels [-].
        """
        return replace(self, F_c=self.F_c * factor, F_s=self.F_s * factor, sigma2=self.sigma2 * factor)
