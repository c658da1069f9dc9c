"""Collision and overload: the force crosses a limit, and the machine must stop now.

The detector compares every sample of a force channel with a limit [N] (the
machine's or fixture's rating, or a taught limit: :mod:`drivesense.events.teach`)
and raises a stop event on the first sample past it; it declares no delay of
its own (the estimator's latency is the whole delay).  The event is a
``collision`` when the force rose from below half the limit within
``collision_rise_s`` (an impact), else an ``overload`` (a ramp: a growing
chip load, a blunt tool).  After an event the detector re-arms once the force
has stayed below ``rearm`` times the limit for ``rearm_s``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numba import njit

from drivesense.errors import ConfigError
from drivesense.machine.milling import check_number
from drivesense.events.detector import Detector

__all__ = ["OverloadDetector"]


@njit(cache=True, nogil=True)
def _overload_loop(force, limit, rise_n, rearm_level, rearm_n, sc, ev_index, ev_data):  # pragma: no cover
    # sc: 0 samples since |F| was below half the limit, 1 latched, 2 samples below the re-arm level
    n_ev = 0
    for i in range(force.size):
        a = abs(force[i])
        if a < 0.5 * limit:
            sc[0] = 0.0
        else:
            sc[0] += 1.0
        if sc[1] != 0.0:
            if a < rearm_level * limit:
                sc[2] += 1.0
                if sc[2] >= rearm_n:
                    sc[1] = 0.0
            else:
                sc[2] = 0.0
            continue
        if a > limit and n_ev < ev_index.size:
            ev_index[n_ev] = i
            ev_data[n_ev, 0] = force[i]
            ev_data[n_ev, 1] = 1.0 if sc[0] <= rise_n else 0.0
            ev_data[n_ev, 2] = sc[0]
            n_ev += 1
            sc[1] = 1.0
            sc[2] = 0.0
    return n_ev


class OverloadDetector(Detector):
    """Stop on the first sample whose force magnitude exceeds a limit.

    Parameters
    ----------
    axis : str
        Axis letter of the force channel.
    limit_n : float
        Force limit [N] (magnitude), > 0.
    collision_rise_s : float
        A crossing reached within this time from below half the limit is a collision [s].
    rearm : float
        Share of the limit the force must fall below to re-arm [-].
    rearm_s : float
        How long it must stay there [s].
    """

    name = "overload"

    def __init__(self, axis: str = "x", limit_n: float = 100.0, *, collision_rise_s: float = 5e-3,
                 rearm: float = 0.5, rearm_s: float = 0.5) -> None:
        self._axis = str(axis)
        self.limit_n = check_number(limit_n, "limit_n", positive=True)
        self.collision_rise_s = check_number(collision_rise_s, "collision_rise_s", positive=True)
        self.rearm = check_number(rearm, "rearm", positive=True)
        if self.rearm >= 1.0:
            raise ConfigError(f"'rearm' is a share of the limit below 1, got {rearm!r}")
        self.rearm_s = check_number(rearm_s, "rearm_s", positive=True)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """``force_{axis}`` [N]."""
        return (f"force_{self._axis}",)

    def latency_s(self, fs: float) -> float:
        """Zero: the event is the first sample past the limit.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return 0.0

    def new_state(self, fs: float) -> dict:
        """Three numbers.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return {"sc": np.zeros(3), "fs": float(fs)}

    def process(self, state: dict, arrays: Mapping[str, np.ndarray], start: int):
        """Stop events, |F| and the limit for the next samples.

        Parameters
        ----------
        state : dict
            From :meth:`new_state`; updated in place.
        arrays : mapping of str to ndarray
            The chunk's channels [SI unit of each channel: N, rad/s, m/s, m], equally long.
        start : int
            Index of the chunk's first sample since the stream began.
        """
        force = np.ascontiguousarray(arrays[self.channel_names[0]], dtype=float)
        fs = state["fs"]
        ev_index = np.zeros(16, dtype=np.int64)
        ev_data = np.zeros((16, 3))
        n_ev = _overload_loop(force, self.limit_n, self.collision_rise_s * fs, self.rearm,
                              max(1.0, self.rearm_s * fs), state["sc"], ev_index, ev_data)
        events = []
        for e in range(n_ev):
            value, collision, rise = ev_data[e]
            over = abs(value) / self.limit_n
            events.append((start + int(ev_index[e]), "collision" if collision else "overload",
                           min(1.0, 0.5 + (over - 1.0)),
                           {"force_n": float(value), "limit_n": self.limit_n, "stop": True,
                            "rise_s": float(rise / fs)}))
        return events, np.abs(force), np.full(force.size, self.limit_n)
