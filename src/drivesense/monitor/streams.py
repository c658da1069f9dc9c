"""Two streaming pieces of a machine's live pipeline: the fixed-memory history ring and the feed speed.

:class:`Ring` keeps the newest samples of one channel (the dashboard's history and the signal
around events) in constant memory however long the service runs; :class:`FeedSpeedStream` turns the
table positions of each chunk into the path speed the detectors gate on.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["Ring", "FeedSpeedStream"]


class Ring:
    """A fixed-capacity ring buffer of float64 samples (the newest ``capacity`` kept).

    Parameters
    ----------
    capacity : int
        Samples kept.
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = max(1, int(capacity))
        self._data = np.zeros(self.capacity)
        self._end = 0                       # samples ever written

    def extend(self, values: np.ndarray) -> None:
        """Append samples (only the last ``capacity`` of a long chunk are kept).

        Parameters
        ----------
        values : ndarray
            Samples [unit of the channel].
        """
        values = np.asarray(values, dtype=float)
        total = values.size
        values = values[-self.capacity:]
        start = (self._end + total - values.size) % self.capacity
        first = min(values.size, self.capacity - start)
        self._data[start:start + first] = values[:first]
        self._data[:values.size - first] = values[first:]
        self._end += total

    @property
    def written(self) -> int:
        """Samples ever written."""
        return self._end

    def last(self, n: int) -> np.ndarray:
        """The newest ``n`` samples (fewer when fewer are held), oldest first.

        Parameters
        ----------
        n : int
            Samples wanted.
        """
        n = int(min(max(n, 0), self.capacity, self._end))
        idx = (np.arange(self._end - n, self._end)) % self.capacity
        return self._data[idx]


@njit(cache=True, nogil=True)
def _feed_kernel(pos: np.ndarray, last: np.ndarray, ring: np.ndarray, state: np.ndarray,
                 fs: float) -> np.ndarray:  # pragma: no cover - compiled
    """Path speed [m/s] per sample from positions (channels x samples) [m], a running mean over ``ring``."""
    n = pos.shape[1]
    width = ring.size
    out = np.empty(n)
    head, filled, total = int(state[0]), int(state[1]), state[2]
    for i in range(n):
        v2 = 0.0
        for c in range(pos.shape[0]):
            d = pos[c, i] - last[c]
            last[c] = pos[c, i]
            v2 += d * d
        v = math.sqrt(v2) * fs
        if filled == width:
            total -= ring[head]
        else:
            filled += 1
        ring[head] = v
        total += v
        head = (head + 1) % width
        out[i] = max(total, 0.0) / filled
    state[0], state[1], state[2] = head, filled, total
    return out


class FeedSpeedStream:
    """Tool-path speed [m/s] from table positions, causal: a moving average over the last 50 ms.

    The live counterpart of :func:`drivesense.events.pipeline.feed_speed_of` (which centres its window on a
    whole trace): the detectors read it to hold off while the feed changes.  Constant state (a running
    sum over a ring of the window), one compiled pass per chunk.

    Parameters
    ----------
    fs : float
        Sample rate [Hz].
    window_s : float
        Averaging window [s].
    """

    def __init__(self, fs: float, window_s: float = 50e-3) -> None:
        self.fs = float(fs)
        self.width = max(1, int(round(window_s * fs)))
        self._names: list[str] | None = None
        self._last = np.zeros(0)
        self._ring = np.zeros(self.width)
        self._state = np.zeros(3)

    def push(self, positions: dict[str, np.ndarray]) -> np.ndarray:
        """Feed speed per sample of the chunk [m/s].

        Parameters
        ----------
        positions : dict of str to ndarray
            ``*_table_position`` channels [m] (the same ones every chunk).
        """
        names = sorted(positions)
        pos = np.ascontiguousarray(np.vstack([positions[c] for c in names]), dtype=float)
        if self._names != names:                  # the first chunk (or another set of axes): start from here
            self._names = names
            self._last = pos[:, 0].copy()
        return _feed_kernel(pos, self._last, self._ring, self._state, self.fs)
