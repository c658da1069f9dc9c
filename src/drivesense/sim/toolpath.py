"""Reference trajectories: jerk-limited moves sampled at the control rate.

One axis: :func:`constant_feed`, :func:`standstill` (the ball-screw stage).
Three axes: :class:`ToolpathProgram` builds a program of rest-to-rest lines
and xy arcs with raised-cosine velocity ramps (:func:`move_profile`) and
dwells, sampled at the control rate (the linear-motor machine's processes and
the machining centre's part programs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["Trajectory", "constant_feed", "standstill", "move_profile", "Move", "ToolpathProgram"]


@dataclass(frozen=True)
class Trajectory:
    """Position, velocity and acceleration reference of one axis.

    Attributes
    ----------
    position, velocity, acceleration : ndarray
        [m], [m/s], [m/s^2] at the control instants.
    fs : float
        Sample rate [Hz].
    cruise : tuple of float
        Start and end [s] of the constant-velocity part.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    fs: float
    cruise: tuple[float, float]

    @property
    def time(self) -> np.ndarray:
        """Time of each sample [s]."""
        return np.arange(self.position.size) / self.fs


def _smooth_step(t: np.ndarray, t0: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Raised-cosine step from 0 to 1 over ``[t0, t0 + duration]`` and its derivative."""
    u = np.clip((t - t0) / duration, 0.0, 1.0)
    s = 0.5 - 0.5 * np.cos(np.pi * u)
    ds = np.where((u > 0) & (u < 1), 0.5 * np.pi * np.sin(np.pi * u) / duration, 0.0)
    return s, ds


def constant_feed(duration: float, fs: float, speed: float, *, start: float = 0.0, t_start: float = 0.2,
                  ramp: float = 0.1, t_stop: float | None = None, overrides=()) -> Trajectory:
    """Stand, ramp up to ``speed``, cruise, (optionally) ramp down.

    Parameters
    ----------
    duration : float
        Length of the trajectory [s].
    fs : float
        Sample rate [Hz].
    speed : float
        Cruise velocity [m/s] (signed).
    start : float
        Initial position [m].
    t_start : float
        Start of the acceleration ramp [s].
    ramp : float
        Duration of each raised-cosine velocity ramp [s].
    t_stop : float, optional
        Start of the deceleration ramp [s]; ``None`` cruises to the end.
    overrides : sequence of (float, float)
        Feed-rate override changes ``(time [s], factor [-])``, in time order:
        from ``time`` on the velocity ramps (over ``ramp``) to ``factor *
        speed``, as an operator turning the override knob.
    """
    t = np.arange(int(round(duration * fs))) / fs
    up, dup = _smooth_step(t, t_start, ramp)
    vel = speed * up
    acc = speed * dup
    factor = 1.0
    for t_change, new in overrides:
        step, dstep = _smooth_step(t, t_change, ramp)
        vel = vel + speed * (new - factor) * step
        acc = acc + speed * (new - factor) * dstep
        factor = new
    cruise_end = duration
    if t_stop is not None:
        down, ddown = _smooth_step(t, t_stop, ramp)
        vel = vel - speed * factor * down
        acc = acc - speed * factor * ddown
        cruise_end = t_stop
    # exact integral of the velocity (trapezoidal on a fine grid is enough at 10 kHz)
    pos = start + np.concatenate(([0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) / fs)))
    return Trajectory(pos, vel, acc, fs, (t_start + ramp, cruise_end))


def standstill(duration: float, fs: float, *, position: float = 0.0) -> Trajectory:
    """An axis held at ``position`` [m] for ``duration`` [s].

    Parameters
    ----------
    duration : float
        Length of the trajectory [s].
    fs : float
        Sample rate [Hz].
    position : float, optional
        Held position [m].

    Returns
    -------
    Trajectory
    """
    n = int(round(duration * fs))
    return Trajectory(np.full(n, float(position)), np.zeros(n), np.zeros(n), fs, (0.0, duration))


# ------------------------------------------------------------------ programs of several axes
def move_profile(t: np.ndarray, t0: float, length: float, speed: float, ramp: float):
    """Arc length, speed and acceleration of a rest-to-rest move along a path.

    Raised-cosine velocity ramps of ``ramp`` [s] (shortened to ``length /
    speed`` for a move too short to reach ``speed``), cruise in between.

    Parameters
    ----------
    t : ndarray
        Time of each sample [s].
    t0 : float
        Start of the move [s].
    length : float
        Path length [m], > 0.
    speed : float
        Cruise speed [m/s], > 0.
    ramp : float
        Duration of each velocity ramp [s], > 0.

    Returns
    -------
    s, v, a : ndarray
        Arc length [m], speed [m/s] and acceleration [m/s^2] along the path
        (0 before the move, ``length`` after it).
    t_end : float
        End of the move [s].
    """
    ramp = min(ramp, length / speed)
    t1, t2 = t0 + ramp, t0 + length / speed
    t3 = t2 + ramp
    s = np.zeros_like(t)
    v = np.zeros_like(t)
    a = np.zeros_like(t)
    u = np.clip((t - t0) / ramp, 0.0, 1.0)
    up = (t >= t0) & (t < t1)
    s[up] = speed * (u[up] * ramp / 2 - ramp / (2 * math.pi) * np.sin(math.pi * u[up]))
    v[up] = speed * (0.5 - 0.5 * np.cos(math.pi * u[up]))
    a[up] = speed * math.pi / (2 * ramp) * np.sin(math.pi * u[up])
    cr = (t >= t1) & (t < t2)
    s[cr] = speed * ramp / 2 + speed * (t[cr] - t1)
    v[cr] = speed
    w = np.clip((t - t2) / ramp, 0.0, 1.0)
    dn = (t >= t2) & (t < t3)
    s[dn] = length - speed * ramp / 2 + speed * (w[dn] * ramp / 2 + ramp / (2 * math.pi) * np.sin(math.pi * w[dn]))
    v[dn] = speed * (0.5 + 0.5 * np.cos(math.pi * w[dn]))
    a[dn] = -speed * math.pi / (2 * ramp) * np.sin(math.pi * w[dn])
    s[t >= t3] = length
    return s, v, a, t3


class Move(NamedTuple):
    """One rest-to-rest move of a :class:`ToolpathProgram`.

    Attributes
    ----------
    kind : {"line", "arc"}
        Straight line, or circular arc in the xy plane.
    t0 : float
        Start [s].
    t_cruise_end : float
        End of the cruise (start of the deceleration) [s].
    t_end : float
        End (at rest) [s].
    length : float
        Path length [m].
    speed : float
        Cruise speed [m/s].
    ramp : float
        Velocity ramp duration [s] (before shortening for short moves).
    start, end : ndarray
        Position of x, y, z at the start and the end [m].
    direction : ndarray
        Line: unit vector of the motion [-]; arc: offset of the centre from
        ``start`` [m].
    turn : int
        Arc: +1 counter-clockwise, -1 clockwise (seen from +z); line: 0.
    tag : object
        What the caller attached to the move (e.g. its engagement).
    """

    kind: str
    t0: float
    t_cruise_end: float
    t_end: float
    length: float
    speed: float
    ramp: float
    start: np.ndarray
    end: np.ndarray
    direction: np.ndarray
    turn: int
    tag: object


class ToolpathProgram:
    """Reference trajectory of the three axes x, y, z built move by move, each from rest to rest.

    Moves are appended in time order (:meth:`line`, :meth:`arc`,
    :meth:`dwell`) and sampled at the control rate by :meth:`build`.

    Parameters
    ----------
    start : array_like, shape (3,)
        Start position of x, y, z [m].
    fs : float
        Control rate the trajectory is sampled at [Hz].
    """

    def __init__(self, start, fs: float) -> None:
        self.fs = fs
        self.start = np.asarray(start, dtype=float)
        self.here = self.start.copy()
        self.moves: list[Move] = []
        self.t_end = 0.0

    def dwell(self, duration: float) -> None:
        """Stand still for ``duration`` [s].

        Parameters
        ----------
        duration : float
            Standstill [s].
        """
        self.t_end += duration

    def line(self, delta, speed: float, ramp: float, tag: object = "") -> tuple[float, float, float]:
        """Straight move by ``delta``.

        Parameters
        ----------
        delta : array_like, shape (3,)
            Displacement of x, y, z [m] (not all zero).
        speed : float
            Cruise speed along the path [m/s].
        ramp : float
            Duration of each velocity ramp [s].
        tag : object
            Attached to the :class:`Move`.

        Returns
        -------
        tuple of float
            Start, cruise end and end of the move [s].
        """
        delta = np.asarray(delta, dtype=float)
        length = float(np.linalg.norm(delta))
        t0 = self.t_end
        unit = delta / length
        end = self.here + unit * length
        self.t_end = t0 + length / speed + min(ramp, length / speed)
        self.moves.append(Move("line", t0, t0 + length / speed, self.t_end, length, speed, ramp, self.here, end,
                               unit, 0, tag))
        self.here = end
        return t0, t0 + length / speed, self.t_end

    def arc(self, centre_offset, angle: float, speed: float, ramp: float, tag: object = "") -> tuple[float, float, float]:
        """Circular arc in the xy plane about ``current + centre_offset`` (z stands).

        Parameters
        ----------
        centre_offset : array_like, shape (3,)
            Centre relative to the current position [m] (its z is ignored).
        angle : float
            Angle swept [rad]: > 0 counter-clockwise (G3), < 0 clockwise (G2).
        speed : float
            Cruise speed along the path [m/s].
        ramp : float
            Duration of each velocity ramp [s].
        tag : object
            Attached to the :class:`Move`.

        Returns
        -------
        tuple of float
            Start, cruise end and end of the move [s].
        """
        geo = np.asarray(centre_offset, float)
        r = float(np.hypot(*geo[:2]))
        length = r * abs(angle)
        turn = 1 if angle > 0 else -1
        centre = self.here + geo
        th1 = math.atan2(-geo[1], -geo[0]) + turn * length / r
        end = np.array([centre[0] + r * math.cos(th1), centre[1] + r * math.sin(th1), self.here[2]])
        t0 = self.t_end
        self.t_end = t0 + length / speed + min(ramp, length / speed)
        self.moves.append(Move("arc", t0, t0 + length / speed, self.t_end, length, speed, ramp, self.here, end, geo,
                               turn, tag))
        self.here = end
        return t0, t0 + length / speed, self.t_end

    def build(self, tail: float):
        """Sample the program at ``fs`` from 0 to the last move's end plus ``tail``.

        Parameters
        ----------
        tail : float
            Standstill after the last move [s].

        Returns
        -------
        t : ndarray
            Time [s], shape (n,).
        position, velocity, acceleration : ndarray
            Reference of x, y, z [m], [m/s], [m/s^2], shape (3, n).
        """
        n = int(math.ceil((self.t_end + tail) * self.fs))
        t = np.arange(n) / self.fs
        pos = np.repeat(self.start[:, None], n, axis=1)
        vel = np.zeros((3, n))
        acc = np.zeros((3, n))
        for mv in self.moves:     # each move on its own samples; at rest at its end after them
            i0, i3 = np.searchsorted(t, (mv.t0, mv.t_end), side="left")
            w = slice(i0, i3)
            s, v, a, _ = move_profile(t[w], mv.t0, mv.length, mv.speed, mv.ramp)
            geo = mv.direction
            if mv.kind == "line":
                pos[:, w] += geo[:, None] * s
                pos[:, i3:] += geo[:, None] * np.full((1, n - i3), mv.length)
                vel[:, w] += geo[:, None] * v
                acc[:, w] += geo[:, None] * a
                continue
            here = mv.start
            r = float(np.hypot(*geo[:2]))
            centre = here + geo
            th0 = math.atan2(-geo[1], -geo[0])
            th = th0 + mv.turn * np.concatenate((s, np.full(n - i3, mv.length))) / r if mv.turn < 0 else \
                th0 + np.concatenate((s, np.full(n - i3, mv.length))) / r
            pos[0, i0:] += (centre[0] + r * np.cos(th)) - here[0]
            pos[1, i0:] += (centre[1] + r * np.sin(th)) - here[1]
            th = th[:i3 - i0]
            tan_x, tan_y = (-np.sin(th), np.cos(th)) if mv.turn > 0 else (np.sin(th), -np.cos(th))
            vel[0, w] += tan_x * v
            vel[1, w] += tan_y * v
            acc[0, w] += tan_x * a - np.cos(th) * v ** 2 / r
            acc[1, w] += tan_y * a - np.sin(th) * v ** 2 / r
        return t, pos, vel, acc
