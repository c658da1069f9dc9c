"""Production-like part programs of the vertical machining centre and their process forces.

Five programs (:func:`nc_programs`), each 15-40 s at the default cutting
parameters (:data:`DEFAULT_CUT`), on a fresh 80 x 60 mm block of C45 steel
clamped on the table (its top-left-front corner at :data:`PART_ORIGIN`):

``face_zigzag``
    Face milling of a 20 mm band: passes along +-x at depth ``a_p``, stepped
    by ``a_e`` in +y (up milling one way, down milling back).
``pocket``
    A 44 x 32 mm rectangular pocket, two levels of ``a_p``: plunge at the
    centre, a slot along x, then contour-parallel rectangles (ccw, climb)
    stepped out by at most ``a_e``.
``slots``
    Three open full-width slots of depth ``a_p``: along +x, along -y (crossing
    the first: two material spans) and a diagonal +x+y across a corner.
``contour``
    The outside of a 60 x 40 mm boss with 8 mm corner radii (four arcs, cw,
    climb milling, radial depth ``a_e``), tangential lead-in, two laps of
    depth ``a_p``.
``drilling``
    A peck-plunge cycle on Z: six holes, ``6 a_p`` deep in pecks of ``2 a_p``
    at a third of the feed, retracting to the R plane after each peck.

Every move runs from rest to rest (exact stop): rapids (G0) at 0.3 m/s (Z
0.2 m/s) with at most 3 m/s^2, feeds (G1, G2/G3) at ``v_f`` with at most
1 m/s^2; each program starts and ends at a home position with the spindle
running and the axes at rest.

Forces: each cutting move carries its :class:`Engagement` (radial and axial
depth, up or down milling, the path positions where the tool enters and
leaves material); :func:`program_forces` evaluates
:func:`~drivesense.sim.cutting.straight_cut_forces` along the move (the tool
frame turning with the path on arcs) and plunges (:class:`Plunge`) with
:func:`~drivesense.sim.cutting.plunge_load`.  Approximations: the engagement
is constant along a move (no corner or arc thickening), an entry edge is
taken perpendicular to the feed, and features that cross are cut as stated
by their spans (the programs state the gaps).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from drivesense.errors import ConfigError
from drivesense.machine.milling import CuttingCoefficients, EndMill, MillingCut
from drivesense.sim.cutting import plunge_load, straight_cut_forces, workpiece_force
from drivesense.sim.toolpath import ToolpathProgram, move_profile

__all__ = ["Engagement", "Plunge", "PartProgram", "CutParameters", "DEFAULT_CUT", "PART_ORIGIN", "HOME",
           "nc_programs", "describe_nc_program", "build_nc_program", "program_forces"]

#: Machine coordinates of the part's corner at x = y = 0 on its top face [m].
PART_ORIGIN = (0.26, 0.17, 0.15)
#: Where every program starts and ends [m].
HOME = (0.20, 0.10, 0.30)
_RAPID, _RAPID_Z, _RAPID_ACC = 0.3, 0.2, 3.0
_FEED_ACC, _MIN_RAMP = 1.0, 0.04
_MM = 1e-3


class CutParameters(NamedTuple):
    """Cutting parameters of a part program.

    Attributes
    ----------
    a_p : float
        Axial depth of cut per level [m].
    a_e : float
        Radial depth (stepover) [m].
    v_f : float
        Feed speed [m/s].
    n : float
        Spindle speed [min^-1].
    """

    a_p: float
    a_e: float
    v_f: float
    n: float


#: Default cutting parameters: a_p 2 mm, a_e 5 mm, v_f 1 m/min, 4500 min^-1 (12 mm, 4 flutes, C45).
DEFAULT_CUT = CutParameters(a_p=2e-3, a_e=5e-3, v_f=1.0 / 60.0, n=4500.0)


class Engagement(NamedTuple):
    """How a milling move engages the material.

    Attributes
    ----------
    a_e : float
        Radial depth of cut [m] (the tool diameter: a slot).
    a_p : float
        Axial depth of cut [m].
    mode : {"up", "down"}
        Up (material left of the feed) or down (right) milling.
    spans : tuple of (float or None, float or None)
        Path positions along the move [m] where the tool centre crosses the
        material's entry and exit edges; entry None: fully engaged from the
        start; exit None: still engaged at the end.
    """

    a_e: float
    a_p: float
    mode: str
    spans: tuple = ((None, None),)


class Plunge(NamedTuple):
    """A plunge along -z that cuts below ``z_cut``.

    Attributes
    ----------
    z_cut : float
        Height [m] below which the material is uncut (the surface or the
        bottom of the previous peck).
    """

    z_cut: float


class PartProgram:
    """A part program built from G0/G1/G2/G3-like moves on a :class:`~drivesense.sim.toolpath.ToolpathProgram`.

    Parameters
    ----------
    fs : float
        Control rate [Hz].
    start : array_like, shape (3,)
        Start position [m].
    """

    def __init__(self, fs: float, start=HOME) -> None:
        self.path = ToolpathProgram(start, fs)

    @property
    def here(self) -> np.ndarray:
        """Position at the end of the last move [m]."""
        return self.path.here

    def _move(self, target, speed: float, acc: float, tag) -> None:
        delta = np.asarray(target, float) - self.here
        length = float(np.linalg.norm(delta))
        if length < 1e-9:
            return
        ramp = max(_MIN_RAMP, math.pi * speed / (2.0 * acc))
        if length / speed < ramp:       # too short to reach speed: the fastest move within the acceleration
            speed = math.sqrt(2.0 * acc * length / math.pi)
            ramp = math.pi * speed / (2.0 * acc)
        self.path.line(delta, speed, ramp, tag)

    def _target(self, x, y, z) -> np.ndarray:
        h = self.here
        return np.array([h[0] if x is None else x, h[1] if y is None else y, h[2] if z is None else z])

    def g0(self, x: float | None = None, y: float | None = None, z: float | None = None) -> None:
        """Rapid move to absolute coordinates (None keeps an axis).

        Parameters
        ----------
        x, y, z : float or None
            Target [m].
        """
        target = self._target(x, y, z)
        delta = target - self.here
        speed = _RAPID_Z if abs(delta[2]) > 0.5 * float(np.linalg.norm(delta)) else _RAPID
        self._move(target, speed, _RAPID_ACC, None)

    def g1(self, x: float | None = None, y: float | None = None, z: float | None = None, *, feed: float,
           cut: Engagement | Plunge | None = None) -> None:
        """Straight feed move to absolute coordinates.

        Parameters
        ----------
        x, y, z : float or None
            Target [m] (None keeps an axis).
        feed : float
            Feed speed [m/s].
        cut : Engagement or Plunge, optional
            What the move cuts (None: air).
        """
        self._move(self._target(x, y, z), feed, _FEED_ACC, cut)

    def arc(self, centre_offset, angle: float, *, feed: float, cut: Engagement | None = None) -> None:
        """Circular feed move in the xy plane (G2 for ``angle < 0``, G3 for ``angle > 0``).

        Parameters
        ----------
        centre_offset : array_like, shape (2,)
            Centre relative to the current position [m].
        angle : float
            Angle swept [rad], > 0 counter-clockwise.
        feed : float
            Feed speed [m/s].
        cut : Engagement, optional
            What the move cuts (None: air).
        """
        ramp = max(_MIN_RAMP, math.pi * feed / (2.0 * _FEED_ACC))
        self.path.arc(np.array([centre_offset[0], centre_offset[1], 0.0]), angle, feed, ramp, cut)

    def dwell(self, duration: float) -> None:
        """Stand still.

        Parameters
        ----------
        duration : float
            Standstill [s].
        """
        self.path.dwell(duration)


def _p(x_mm: float, y_mm: float, z_mm: float | None = None) -> tuple:
    """Part coordinates [mm] -> machine coordinates [m] (z relative to the part's top)."""
    ox, oy, oz = PART_ORIGIN
    return ox + x_mm * _MM, oy + y_mm * _MM, None if z_mm is None else oz + z_mm * _MM


def _face_zigzag(prog: PartProgram, c: CutParameters, d: float) -> None:
    r = 0.5 * d / _MM
    ae, ap = c.a_e / _MM, c.a_p / _MM
    passes = max(1, math.ceil(20.0 / ae))
    xa, xb = -r - 4.0, 80.0 + r + 4.0
    y0 = -r + ae
    x, y, _ = _p(xa, y0)
    prog.g0(x, y, _p(0, 0, 50)[2])
    prog.g0(z=_p(0, 0, 2)[2])
    prog.g1(z=_p(0, 0, -ap)[2], feed=c.v_f)
    for k in range(passes):
        forward = k % 2 == 0
        cut = Engagement(c.a_e, c.a_p, "up" if forward else "down", (((r + 4.0) * _MM, (80.0 + r + 4.0) * _MM),))
        prog.g1(x=_p(xb if forward else xa, 0)[0], feed=c.v_f, cut=cut)
        if k + 1 < passes:
            prog.g1(y=_p(0, y0 + (k + 1) * ae)[1], feed=c.v_f)
    prog.g0(z=_p(0, 0, 50)[2])


def _pocket(prog: PartProgram, c: CutParameters, d: float) -> None:
    r = 0.5 * d / _MM
    cx, cy = 40.0, 30.0
    hx_f, hy_f = 22.0 - r, 16.0 - r
    half_slot = hx_f - hy_f
    loops = max(1, math.ceil(hy_f / (c.a_e / _MM)))
    step = hy_f / loops
    ap = c.a_p / _MM
    slot = Engagement(d, c.a_p, "down")
    prog.g0(*_p(cx - half_slot, cy, 50))
    for level in range(2):
        top, bottom = -level * ap, -(level + 1) * ap
        prog.g0(z=_p(0, 0, top + (2.0 if level == 0 else 1.0))[2])
        prog.g1(z=_p(0, 0, bottom)[2], feed=c.v_f / 3.0, cut=Plunge(_p(0, 0, top)[2]))
        prog.g1(x=_p(cx + half_slot, 0)[0], feed=c.v_f, cut=slot)
        for k in range(1, loops + 1):
            hx, hy = half_slot + k * step, k * step
            wall = Engagement(step * _MM, c.a_p, "down")
            prog.g1(y=_p(0, cy - hy)[1], feed=c.v_f, cut=slot._replace(spans=((r * _MM, None),)))
            prog.g1(x=_p(cx + hx, 0)[0], feed=c.v_f, cut=wall._replace(spans=((r * _MM, None),)))
            prog.g1(y=_p(0, cy + hy)[1], feed=c.v_f, cut=wall)
            prog.g1(x=_p(cx - hx, 0)[0], feed=c.v_f, cut=wall)
            prog.g1(y=_p(0, cy - hy)[1], feed=c.v_f, cut=wall)
            prog.g1(x=_p(cx + half_slot, 0)[0], feed=c.v_f,
                    cut=wall._replace(spans=((None, (hx + half_slot - r) * _MM),)))
        prog.g1(y=_p(0, cy - hy_f + 1.0)[1], feed=c.v_f)          # off the wall
        prog.g0(z=_p(0, 0, bottom + 1.0)[2])
        if level == 0:
            prog.g0(*_p(cx - half_slot, cy)[:2])
    prog.g0(z=_p(0, 0, 50)[2])


def _slots(prog: PartProgram, c: CutParameters, d: float) -> None:
    r = 0.5 * d / _MM
    ap = c.a_p / _MM
    slot = Engagement(d, c.a_p, "down")
    a = r + 4.0
    diag = math.sqrt(2.0)
    # (start, end, spans [mm]): +x at y = 15; -y at x = 60 across the first slot (y 9..21 cut); +x+y over a corner
    plan = (((-a, 15.0), (80.0 + a, 15.0), ((a, 80.0 + a),)),
            ((60.0, 60.0 + a), (60.0, -a), ((a, 60.0 + a - (15.0 + r)), (60.0 + a - (15.0 - r), 60.0 + a))),
            ((-10.0, 25.0), (30.0, 65.0), ((10.0 * diag, 35.0 * diag),)))
    for (xs, ys), (xe, ye), spans in plan:
        prog.g0(*_p(xs, ys, 50))
        prog.g0(z=_p(0, 0, 2)[2])
        prog.g1(z=_p(0, 0, -ap)[2], feed=c.v_f)
        prog.g1(*_p(xe, ye)[:2], feed=c.v_f, cut=slot._replace(spans=tuple((s * _MM, e * _MM) for s, e in spans)))
        prog.g0(z=_p(0, 0, 50)[2])


def _contour(prog: PartProgram, c: CutParameters, d: float) -> None:
    r = 0.5 * d / _MM
    x0, x1, y0, y1, rc = 10.0, 70.0, 10.0, 50.0, 8.0       # the boss and its corner radius [mm]
    ra = rc + r                                             # tool-centre arc radius
    left = x0 - r
    wall = Engagement(c.a_e, c.a_p, "down")                 # cw around the boss: material on the right
    arc_len = 0.5 * math.pi * ra * _MM
    ap = c.a_p / _MM
    start_y = 0.0
    prog.g0(*_p(left, start_y, 50))
    for lap in range(2):
        prog.g0(z=_p(0, 0, 2.0 - lap * ap)[2])
        prog.g1(z=_p(0, 0, -(lap + 1) * ap)[2], feed=c.v_f)
        prog.g1(y=_p(0, y1 - rc)[1], feed=c.v_f, cut=wall._replace(spans=(((y0 + rc - start_y) * _MM, None),)))
        prog.arc((ra * _MM, 0.0), -0.5 * math.pi, feed=c.v_f, cut=wall)
        prog.g1(x=_p(x1 - rc, 0)[0], feed=c.v_f, cut=wall)
        prog.arc((0.0, -ra * _MM), -0.5 * math.pi, feed=c.v_f, cut=wall)
        prog.g1(y=_p(0, y0 + rc)[1], feed=c.v_f, cut=wall)
        prog.arc((-ra * _MM, 0.0), -0.5 * math.pi, feed=c.v_f, cut=wall)
        prog.g1(x=_p(x0 + rc, 0)[0], feed=c.v_f, cut=wall)
        prog.arc((0.0, ra * _MM), -0.5 * math.pi, feed=c.v_f, cut=wall._replace(spans=((None, arc_len),)))
        prog.g1(x=_p(left - 10.0, 0)[0], feed=c.v_f)       # lead-out, away from the wall
        prog.g0(z=_p(0, 0, 2.0)[2])
        if lap == 0:
            prog.g0(*_p(left, start_y)[:2])
    prog.g0(z=_p(0, 0, 50)[2])


def _drilling(prog: PartProgram, c: CutParameters, d: float) -> None:
    ap = c.a_p / _MM
    depth, peck = 6.0 * ap, 2.0 * ap
    r_plane = _p(0, 0, 2.0)[2]
    holes = ((15.0, 15.0), (40.0, 15.0), (65.0, 15.0), (65.0, 45.0), (40.0, 45.0), (15.0, 45.0))
    for i, (hx, hy) in enumerate(holes):
        if i == 0:
            prog.g0(*_p(hx, hy, 50))
            prog.g0(z=r_plane)
        else:
            prog.g0(*_p(hx, hy)[:2])
        bottom = 0.0
        while bottom > -depth + 1e-9:
            target = max(bottom - peck, -depth)
            if bottom < 0.0:
                prog.g0(z=_p(0, 0, bottom + 0.5)[2])
            prog.g1(z=_p(0, 0, target)[2], feed=c.v_f / 3.0, cut=Plunge(_p(0, 0, bottom)[2]))
            prog.g0(z=r_plane)
            bottom = target
    prog.g0(z=_p(0, 0, 50)[2])


_PROGRAMS = {"face_zigzag": _face_zigzag, "pocket": _pocket, "slots": _slots, "contour": _contour,
             "drilling": _drilling}
_DESCRIPTIONS = {
    "face_zigzag": "face milling zig-zag (passes along +-x, stepover a_e in +y)",
    "pocket": "rectangular pocket 44 x 32 mm, two levels: plunge, slot, contour-parallel loops",
    "slots": "three open slots: +x, -y (crossing), diagonal +x+y",
    "contour": "outside contour of a 60 x 40 mm boss with four arcs (cw, climb), two laps",
    "drilling": "peck-plunge cycle on Z: six holes 6 a_p deep",
}


def nc_programs() -> list[str]:
    """Names of the machining centre's part programs.

    Returns
    -------
    list of str
        ``face_zigzag``, ``pocket``, ``slots``, ``contour``, ``drilling``.
    """
    return list(_PROGRAMS)


def describe_nc_program(name: str) -> str:
    """One line on what program ``name`` machines.

    Parameters
    ----------
    name : str
        One of :func:`nc_programs`.

    Returns
    -------
    str
    """
    return _DESCRIPTIONS[name]


def build_nc_program(name: str, cut: CutParameters, tool: EndMill, fs: float) -> PartProgram:
    """The moves of part program ``name`` from :data:`HOME` back to :data:`HOME`.

    Parameters
    ----------
    name : str
        One of :func:`nc_programs`.
    cut : CutParameters
        Depths [m], feed [m/s] and spindle speed [min^-1].
    tool : EndMill
        The tool (its diameter sets the offsets).
    fs : float
        Control rate [Hz].

    Returns
    -------
    PartProgram
        1 s at rest at the start, the program, 0.5 s at rest at the end.
    """
    if name not in _PROGRAMS:
        raise ConfigError(f"unknown NC program {name!r}; known: {', '.join(_PROGRAMS)}")
    prog = PartProgram(fs)
    prog.dwell(1.0)
    _PROGRAMS[name](prog, cut, tool.diameter)
    prog.g0(*HOME)
    prog.dwell(0.5)
    return prog


def program_forces(program: PartProgram, t: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                   angle: np.ndarray, tool: EndMill, coefficients: CuttingCoefficients, fs: float):
    """Process force on the workpiece and spindle torque of every cutting move of a program.

    Parameters
    ----------
    program : PartProgram
        The program (its moves carry :class:`Engagement` or :class:`Plunge`).
    t : ndarray
        Time [s] of the samples (from ``program.path.build``).
    position, velocity : ndarray, shape (3, n)
        Reference position [m] and velocity [m/s].
    angle : ndarray
        Spindle angle [rad] at each sample.
    tool : EndMill
        The tool.
    coefficients : CuttingCoefficients
        Cutting [N/m^2] and edge [N/m] coefficients.
    fs : float
        Sample rate [Hz].

    Returns
    -------
    force : ndarray, shape (3, n)
        Force on the workpiece along +x, +y, +z [N].
    torque : ndarray
        Spindle torque [N*m].
    """
    n = t.size
    force = np.zeros((3, n))
    torque = np.zeros(n)
    omega = np.gradient(angle) * fs
    for mv in program.path.moves:
        w = np.flatnonzero((t >= mv.t0) & (t < mv.t_end))
        if w.size < 2 or mv.tag is None:
            continue
        if isinstance(mv.tag, Plunge):
            z = position[2, w]
            c_z = 2 * math.pi * np.clip(-velocity[2, w], 0.0, None) / (tool.flutes * np.maximum(omega[w], 1e-9))
            engaged = np.clip((mv.tag.z_cut - z) / 0.3e-3, 0.0, 1.0) * (c_z > 0)
            thrust, tq = plunge_load(tool, coefficients, c_z, engaged)
            force[2, w] -= thrust
            torque[w] += tq
            continue
        eng: Engagement = mv.tag
        s, v, _, _ = move_profile(t[w], mv.t0, mv.length, mv.speed, mv.ramp)
        if mv.kind == "line":
            dx, dy = mv.direction[0], mv.direction[1]
        else:
            geo = mv.direction
            th = math.atan2(-geo[1], -geo[0]) + mv.turn * s / math.hypot(geo[0], geo[1])
            dx, dy = -mv.turn * np.sin(th), mv.turn * np.cos(th)
        cut = MillingCut(eng.a_e, eng.a_p, eng.mode, axial_slices=8)
        for entry, exit_ in eng.spans:
            entry = -tool.diameter if entry is None else entry
            fe, fn, fa, tq = straight_cut_forces(tool, coefficients, cut, angle[w], v, s - entry,
                                                 None if exit_ is None else exit_ - entry, fs)
            force[:, w] += workpiece_force(fe, fn, fa, dx, dy)
            torque[w] += tq
    return force, torque
