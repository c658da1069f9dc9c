"""Process forces along a toolpath, shared by the simulated machines' processes.

The force model is :func:`drivesense.machine.milling.milling_forces` (tool
frame: x along the tool's motion relative to the workpiece, y = z x x to the
left of it, z the tool axis); this module adds what a path needs:

* :func:`straight_cut_forces` -- a straight engagement with an entry edge
  (the tool reaching the material) and an exit edge (superposition: the
  forces of an entry at the exit edge are subtracted);
* :func:`workpiece_force` -- tool-frame force on the tool to the force on
  the workpiece in machine axes for a feed direction in the xy plane;
* :func:`plunge_load` -- thrust and torque of an end mill plunging (drilling)
  along -z;
* :func:`material_side_mode` -- up or down milling from the side of the feed
  the material is on.

Used by the linear-motor machine's processes (:mod:`drivesense.sim.machining`)
and the machining centre's part programs (:mod:`drivesense.sim.nc_programs`).
"""

from __future__ import annotations

import math

import numpy as np

from drivesense.errors import ConfigError
from drivesense.machine.milling import CuttingCoefficients, EndMill, MillingCut, milling_forces

__all__ = ["straight_cut_forces", "workpiece_force", "plunge_load", "material_side_mode"]


def straight_cut_forces(tool: EndMill, coefficients: CuttingCoefficients, cut: MillingCut, angle, speed, progress,
                        length, fs: float):
    """Tool-frame forces of an engagement between an entry and an exit edge.

    Parameters
    ----------
    tool : EndMill
        The tool.
    coefficients : CuttingCoefficients
        Cutting [N/m^2] and edge [N/m] coefficients.
    cut : MillingCut
        Radial and axial depth [m] and mode.
    angle : ndarray
        Spindle angle at each sample [rad] (its gradient gives the speed).
    speed : ndarray
        Feed speed along the path [m/s] (its magnitude is used).
    progress : ndarray or None
        How far the tool centre has travelled past the entry edge [m]; None:
        fully entered from the start.
    length : float or None
        Path length between the entry and the exit edge [m]; None: no exit.
    fs : float
        Sample rate of the signals [Hz].

    Returns
    -------
    feed, normal, axial, torque : ndarray
        Force on the tool along the feed, to its left and along the tool
        axis [N]; spindle torque [N*m].
    """
    omega = np.gradient(angle) * fs
    c = 2 * math.pi * np.abs(speed) / (tool.flutes * np.maximum(omega, 1e-9))
    a = milling_forces(tool, coefficients, cut, angle, c, feed_progress=progress)
    if length is None:
        return a.feed, a.normal, a.axial, a.torque
    if progress is None:
        raise ConfigError("straight_cut_forces: an exit edge (length) needs the progress past the entry edge")
    b = milling_forces(tool, coefficients, cut, angle, c, feed_progress=progress - length)
    return a.feed - b.feed, a.normal - b.normal, a.axial - b.axial, a.torque - b.torque


def workpiece_force(feed, normal, axial, dx, dy) -> np.ndarray:
    """Tool-frame force on the tool -> force on the workpiece in machine axes.

    Parameters
    ----------
    feed, normal, axial : ndarray
        Force on the tool along the feed, to its left and along the tool axis [N].
    dx, dy : float or ndarray
        Unit feed direction in the xy plane [-] (constant or per sample).

    Returns
    -------
    ndarray, shape (3, n)
        Force on the workpiece along +x, +y, +z [N].
    """
    return -np.vstack([feed * dx - normal * dy, feed * dy + normal * dx, axial])


def plunge_load(tool: EndMill, coefficients: CuttingCoefficients, feed_per_tooth, engaged):
    """Thrust and spindle torque of an end mill plunging along -z (its end edges cutting).

    The end edges cut from the axis to the radius with the tangential
    coefficient; the thrust takes 1.5 times it (a drilling-like thrust ratio,
    assumed)::

        thrust = e N (D/2) / 2 (1.5 K_tc c + K_te),   torque = e N (D/2)^2 / 4 (K_tc c + K_te)

    Parameters
    ----------
    tool : EndMill
        The tool (diameter [m], flutes).
    coefficients : CuttingCoefficients
        Cutting [N/m^2] and edge [N/m] coefficients.
    feed_per_tooth : ndarray
        Axial feed per tooth [m] (>= 0).
    engaged : ndarray
        Share of the end edges in the material [-] (0..1).

    Returns
    -------
    thrust : ndarray
        Axial force on the tool along +z [N] (the workpiece feels ``-thrust``).
    torque : ndarray
        Spindle torque [N*m].
    """
    d_half = 0.5 * tool.diameter
    k = coefficients
    thrust = engaged * 0.5 * tool.flutes * d_half * (1.5 * k.Ktc * feed_per_tooth + k.Kte)
    torque = engaged * 0.25 * tool.flutes * d_half ** 2 * (k.Ktc * feed_per_tooth + k.Kte)
    return thrust, torque


def material_side_mode(side: str) -> str:
    """Milling mode of a clockwise spindle with the material on ``side`` of the feed.

    Parameters
    ----------
    side : {"left", "right"}
        Side of the feed direction the material is on (seen from +z).

    Returns
    -------
    str
        ``"up"`` (left: conventional milling) or ``"down"`` (right: climb milling).
    """
    if side not in ("left", "right"):
        raise ConfigError(f"material side must be 'left' or 'right', got {side!r}")
    return "up" if side == "left" else "down"
