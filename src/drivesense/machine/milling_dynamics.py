"""Time-domain milling with tool vibration (regenerative chatter) and edge damage (chipping, breakage).

The static model of :mod:`drivesense.machine.milling` takes the chip of flute
``j`` from the surface the previous flute left.  Here the surface is the
deepest of the last ``N`` passes and the tool tip vibrates (Altintas 2000,
ch. 4; the multiple-regeneration form of Kline & DeVor for runout)::

    h_j(t) = min_{k=1..N} [ k c sin(phi) + r_j - r_{j-k}
                            + (x(t) - x(t - k tau)) sin(phi) + (y(t) - y(t - k tau)) cos(phi) ]

``tau`` the tooth period, ``(x, y)`` the tool-tip deflection the cutting force
on the tool drives through the modes of a
:class:`~drivesense.machine.tool_dynamics.ToolDynamics` (each mode advanced by
its exact zero-order-hold discretisation).  A chip below zero means the edge is
out of the cut (the nonlinearity that bounds chatter).  ``r_j`` is per flute
*and* axial slice, so a chipped corner (:class:`EdgeDamage`) removes part of
one flute's edge from a given sample on: the lost edge cuts nothing and the
next flute takes the chip it leaves.  With a rigid tool and no damage the
result equals :func:`~drivesense.machine.milling.milling_forces` wherever the
previous flute cut (tested).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numba import njit

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.machine.milling import (CuttingCoefficients, EndMill, MillingCut, MillingForces, check_int,
                                        check_number, edge_immersion, engagement_angles)
from drivesense.machine.tool_dynamics import ToolDynamics

__all__ = ["EdgeDamage", "DynamicMillingResult", "dynamic_milling_forces"]

_TWO_PI = 2.0 * math.pi
#: Radius an edge loses where it chips or breaks [m]: far more than any chip, so that part cuts nothing.
_LOST_EDGE_DEPTH = 0.5e-3
#: Deepest chip a vibrating flute takes, in feeds per tooth: chatter grows until the flutes leave and dig
#: this deep into the cut, which bounds its amplitude (a real tool would break beyond it).
_CHIP_CAP = 4.0


@dataclass(frozen=True)
class EdgeDamage:
    """A flute loses (part of) its cutting edge at a given sample.

    Parameters
    ----------
    flute : int
        Index of the damaged flute (0-based).
    edge_loss : float
        Share of the engaged edge length lost, from the tool tip up [-],
        in (0, 1]; 1 is a broken tooth.
    sample : int
        First sample (of the simulation grid) with the damage.
    """

    flute: int
    edge_loss: float
    sample: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "flute", check_int(self.flute, "flute", minimum=0))
        loss = check_number(self.edge_loss, "edge_loss", positive=True)
        if loss > 1.0:
            raise ConfigError(f"'edge_loss' is a share of the edge in (0, 1], got {loss!r}")
        object.__setattr__(self, "edge_loss", loss)
        object.__setattr__(self, "sample", check_int(self.sample, "sample", minimum=0))


@dataclass(frozen=True, eq=False)
class DynamicMillingResult:
    """Forces and tool-tip deflection of a time-domain milling simulation.

    Attributes
    ----------
    forces : MillingForces
        F_x, F_y, F_z on the tool [N] and the spindle torque [N*m].
    deflection_x, deflection_y : ndarray
        Tool-tip deflection along x and y [m] (zero for a rigid direction).
    """

    forces: MillingForces
    deflection_x: np.ndarray
    deflection_y: np.ndarray


@njit(cache=True, nogil=True)
def _layered_chip(surf, s, b, pass_id, reach, centre, sn, virgin_chip):  # pragma: no cover - numba
    """Chip of a visit to bin (s, b) by pass ``pass_id``; updates the bin.  ``surf[s, b]`` holds
    (writer pass, reach, travel of the writer's cut, reach and travel before that pass, valid-before flag)."""
    if surf[s, b, 0] != pass_id:
        # a new pass: what the last pass left is the surface before this one
        surf[s, b, 3] = surf[s, b, 1]
        surf[s, b, 4] = surf[s, b, 2]
        # only the pass just before counts: a bin it never reached (the edge of the engagement arc, of the
        # part) holds an older surface, and there the rigid cut's chip is taken
        if surf[s, b, 0] != pass_id - 1:
            surf[s, b, 3] = reach - virgin_chip
            surf[s, b, 4] = centre
        surf[s, b, 5] = 1.0
        surf[s, b, 0] = pass_id
        surf[s, b, 1] = reach
        surf[s, b, 2] = centre
        cut_now = False
    else:
        cut_now = True
    h = reach - surf[s, b, 3] + (centre - surf[s, b, 4]) * sn
    if h > 0.0:
        # the surface after this pass is its deepest visit to the bin
        if not cut_now or reach - surf[s, b, 1] + (centre - surf[s, b, 2]) * sn > 0.0:
            surf[s, b, 1] = reach
            surf[s, b, 2] = centre
    elif not cut_now:
        # no cut on this visit: the surface stays what it was
        surf[s, b, 1] = surf[s, b, 3]
        surf[s, b, 2] = surf[s, b, 4]
    return h


@njit(cache=True, nogil=True)
def _dynamic_loop(angle, c, fp, use_fp, exit_length, off, cos_off, sin_off, rad_a, rad_b, switch,
                  phi_st, phi_ex, half_d, k, dz, nflutes_c, h_cap, surf, surf_nom,
                  modes, phis, gams, nmodes, dt,
                  fx, fy, fz, tq, dx, dy):  # pragma: no cover - numba
    two_pi = 2.0 * math.pi
    ktc, krc, kac, kte, kre, kae = k[0], k[1], k[2], k[3], k[4], k[5]
    nf, ns = off.shape
    nbins = surf.shape[1]
    n = angle.size
    q = np.zeros((nmodes, 2))
    centre = 0.0                      # tool centre's travel along the feed [m]
    for i in range(n):
        # the deflection now (recorded) and half a step on (cut with): the force is held over the step,
        # and taking it from the step's start would act as a delay that removes damping from the modes
        xi = 0.0
        yi = 0.0
        xs = 0.0
        ys = 0.0
        for m in range(nmodes):
            if modes[m, 0] == 0.0:
                xs += q[m, 0]
                xi += q[m, 0] + 0.5 * dt * q[m, 1]
            else:
                ys += q[m, 0]
                yi += q[m, 0] + 0.5 * dt * q[m, 1]
        dx[i] = xs
        dy[i] = ys
        if i > 0:
            centre += c[i] * nflutes_c * (angle[i] - angle[i - 1])
        rad = rad_a if i < switch else rad_b
        a = angle[i]
        sa = math.sin(a)
        ca = math.cos(a)
        a_mod = a - two_pi * math.floor(a / two_pi)
        ci = c[i]
        sx = 0.0
        sy = 0.0
        sz = 0.0
        st = 0.0
        for j in range(nf):
            for s in range(ns):
                phi, sn, co = edge_immersion(a_mod, sa, ca, off[j, s], cos_off[j, s], sin_off[j, s])
                if phi < phi_st or phi > phi_ex:
                    continue
                if use_fp:
                    edge = fp[i] + half_d * sn
                    if edge < 0.0 or edge > exit_length:
                        continue
                # the edge point's reach along the radial direction, in the tool's frame: with the vibrating
                # tool (the chip that shears) and on the nominal path (where the edge rubs).  A surface bin
                # keeps the reach and the feed travel of the pass that cut it last, and of the pass before:
                # the chip is measured against the surface as it was before this pass (a pass may visit a
                # bin on several samples); a bin no pass has cut yet holds the rigid cut's surface.
                b = int(phi / two_pi * nbins)
                if b >= nbins:
                    b = nbins - 1
                # successive visits to a bin come one tooth period apart: number them by it
                pass_id = float(round((a - phi) * nf / two_pi))
                reach = rad[j, s] + xi * sn + yi * co
                static = ci * sn          # a bin the previous pass never reached: one feed per tooth of chip
                h = _layered_chip(surf, s, b, pass_id, reach, centre, sn, static + xi * sn + yi * co)
                h_nom = _layered_chip(surf_nom, s, b, pass_id, rad[j, s], centre, sn, static)
                if h_nom <= 0.0 and h <= 0.0:
                    continue
                if h <= 0.0:
                    h = 0.0
                elif h > h_cap * ci:
                    h = h_cap * ci                # a flute digs at most a few chips deep (it would break first)
                # the edge (ploughing) force follows the nominal engagement: it does not regenerate (the
                # stability lobes leave it out too), so a barely cutting flute cannot self-excite through it
                ramp = 1.0 if h_nom > 0.0 else 0.0
                dft = (ktc * h + kte * ramp) * dz
                dfr = (krc * h + kre * ramp) * dz
                sx += -dft * co - dfr * sn
                sy += dft * sn - dfr * co
                sz += (kac * h + kae * ramp) * dz
                st += dft * rad[j, s]
        fx[i] = sx
        fy[i] = sy
        fz[i] = sz
        tq[i] = st
        for m in range(nmodes):
            f = sx if modes[m, 0] == 0.0 else sy
            q0 = phis[m, 0, 0] * q[m, 0] + phis[m, 0, 1] * q[m, 1] + gams[m, 0] * f
            q1 = phis[m, 1, 0] * q[m, 0] + phis[m, 1, 1] * q[m, 1] + gams[m, 1] * f
            q[m, 0] = q0
            q[m, 1] = q1


def _zoh(modes: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH transition matrices (M, 2, 2) and input vectors (M, 2) of the modes over ``dt`` [s]."""
    phis = np.zeros((len(modes), 2, 2))
    gams = np.zeros((len(modes), 2))
    for m, (_, wn, zeta, stiffness) in enumerate(modes):
        mass = stiffness / wn ** 2
        a = np.array([[0.0, 1.0], [-wn ** 2, -2 * zeta * wn]])
        b = np.array([0.0, 1.0 / mass])
        big = np.zeros((3, 3))
        big[:2, :2] = a
        big[:2, 2] = b
        e = scipy.linalg.expm(big * dt)
        phis[m] = e[:2, :2]
        gams[m] = e[:2, 2]
    return phis, gams


def _radius_table(tool: EndMill, slices: int, damage: EdgeDamage | None) -> tuple[np.ndarray, np.ndarray]:
    """Flute radius per flute and axial slice before and after the damage [m]."""
    before = np.repeat(tool.flute_radii[:, None], slices, axis=1)
    after = before.copy()
    if damage is not None:
        if damage.flute >= tool.flutes:
            raise ConfigError(f"'flute' {damage.flute} does not exist: the tool has {tool.flutes} flute(s)")
        lost = int(math.ceil(damage.edge_loss * slices - 1e-9))
        after[damage.flute, :lost] -= _LOST_EDGE_DEPTH
    return before, after


def dynamic_milling_forces(tool: EndMill, coefficients: CuttingCoefficients, cut: MillingCut, spindle_angle,
                           feed_per_tooth, fs: float, *, feed_progress=None, exit_length: float | None = None,
                           dynamics: ToolDynamics | None = None, damage: EdgeDamage | None = None
                           ) -> DynamicMillingResult:
    """Cutting force of a helical end mill with a vibrating tool tip and edge damage, sample by sample.

    Parameters
    ----------
    tool : EndMill
        The tool (diameter [m], flutes, helix [deg], runout [m]).
    coefficients : CuttingCoefficients
        Cutting [N/m^2] and edge [N/m] coefficients.
    cut : MillingCut
        Radial and axial depth [m], mode, number of axial slices.
    spindle_angle : array_like, shape (n,)
        Spindle angle [rad] at each sample, at a constant speed (the
        regeneration delay is one tooth period of the mean speed).
    feed_per_tooth : float or array_like, shape (n,)
        Feed per tooth [m], >= 0 (a feed override changes it).
    fs : float
        Sample rate of the simulation grid [Hz] (at least 20 samples per
        period of the fastest mode).
    feed_progress : array_like, shape (n,), optional
        How far the tool centre has travelled past the workpiece's entry edge [m].
    exit_length : float, optional
        Length of the workpiece along the feed [m] (the tool exits its far
        edge); None: no exit.
    dynamics : ToolDynamics, optional
        Tool-tip modes; None: a rigid tool.
    damage : EdgeDamage, optional
        A chipped or broken flute from a given sample on.

    Returns
    -------
    DynamicMillingResult
        Forces on the tool [N], spindle torque [N*m] and the tool-tip deflection [m].

    Raises
    ------
    ConfigError
        Bad tool, cut, damage or a grid too coarse for the modes.
    InvalidSignalError
        Non-finite or mis-sized signals, a non-increasing spindle angle.
    """
    if not isinstance(tool, EndMill) or not isinstance(coefficients, CuttingCoefficients) \
            or not isinstance(cut, MillingCut):
        raise ConfigError("dynamic_milling_forces takes an EndMill, CuttingCoefficients and a MillingCut")
    fs = check_number(fs, "fs", positive=True)
    phi_st, phi_ex = engagement_angles(tool.diameter, cut.radial_depth, cut.mode)
    angle = np.ascontiguousarray(spindle_angle, dtype=float)
    if angle.ndim != 1 or angle.size < 2 or not np.all(np.isfinite(angle)):
        raise InvalidSignalError("'spindle_angle' must be a finite 1-D array of at least 2 samples")
    n = angle.size
    omega = (angle[-1] - angle[0]) / (n - 1) * fs
    if not omega > 0:
        raise InvalidSignalError("'spindle_angle' must increase (a turning spindle)")

    def per_sample(value, name):
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 1 and arr.size != n:
            raise InvalidSignalError(f"'{name}' has {arr.size} samples, 'spindle_angle' has {n}")
        if not np.all(np.isfinite(arr)):
            raise InvalidSignalError(f"'{name}' holds NaN or inf")
        return np.ascontiguousarray(np.broadcast_to(arr, (n,)), dtype=float)

    c = per_sample(feed_per_tooth, "feed_per_tooth")
    if np.any(c < 0):
        raise InvalidSignalError("'feed_per_tooth' must be >= 0")
    use_fp = feed_progress is not None
    fp = per_sample(feed_progress, "feed_progress") if use_fp else np.zeros(1)
    exit_len = math.inf if exit_length is None else check_number(exit_length, "exit_length", positive=True)
    nf, ns = tool.flutes, cut.axial_slices
    half_d = 0.5 * tool.diameter
    dz = cut.axial_depth / ns
    z = (np.arange(ns) + 0.5) * dz
    lag = z * math.tan(math.radians(tool.helix_deg)) / half_d
    off = np.mod(np.arange(nf)[:, None] * (_TWO_PI / nf) - lag[None, :], _TWO_PI)
    off = np.where(off >= _TWO_PI, 0.0, off)
    rad_a, rad_b = _radius_table(tool, ns, damage)
    switch = damage.sample if damage is not None else n
    if dynamics is not None:
        if not isinstance(dynamics, ToolDynamics):
            raise ConfigError(f"'dynamics' must be a ToolDynamics, got {type(dynamics).__name__}")
        modes = dynamics.modal_arrays()
        if np.max(modes[:, 1]) / _TWO_PI * 20 > fs:
            raise ConfigError(f"the simulation grid ({fs:g} Hz) is too coarse for a {np.max(modes[:, 1]) / _TWO_PI:g}"
                              f" Hz mode: it needs 20 samples per period")
    else:
        modes = np.zeros((0, 4))
    phis, gams = _zoh(modes, 1.0 / fs)
    k = np.array([coefficients.Ktc, coefficients.Krc, coefficients.Kac,
                  coefficients.Kte, coefficients.Kre, coefficients.Kae])
    # per axial slice and immersion bin, the surfaces (see _layered_chip); a bin no wider than one sample's
    # rotation, so a pass visits every bin it sweeps
    step = omega / fs
    nbins = int(max(16, math.floor(_TWO_PI / step)))
    surf = np.zeros((ns, nbins, 6))
    surf[:, :, 0] = -1e18                    # no pass yet
    out = [np.zeros(n) for _ in range(6)]
    _dynamic_loop(angle, c, fp, use_fp, exit_len, off, np.cos(off), np.sin(off), rad_a, rad_b, switch,
                  phi_st, phi_ex, half_d, k, dz, nf / _TWO_PI, _CHIP_CAP, surf, surf.copy(), modes, phis, gams,
                  len(modes), 1.0 / fs, *out)
    return DynamicMillingResult(MillingForces(feed=out[0], normal=out[1], axial=out[2], torque=out[3]),
                                out[4], out[5])
