"""Reference trajectories: jerk-limited moves sampled at the control rate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory", "constant_feed", "standstill"]


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
                  ramp: float = 0.1, t_stop: float | None = None) -> Trajectory:
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
    """
    t = np.arange(int(round(duration * fs))) / fs
    up, dup = _smooth_step(t, t_start, ramp)
    vel = speed * up
    acc = speed * dup
    cruise_end = duration
    if t_stop is not None:
        down, ddown = _smooth_step(t, t_stop, ramp)
        vel = vel - speed * down
        acc = acc - speed * ddown
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
