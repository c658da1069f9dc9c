"""A second revolution for a breakage the pulse fit cannot explain: a tooth's loss is a step, an exit a drift.

The breakage detector names each event from the revolution after its
detection (:mod:`drivesense.events.edge_loss`).  A tooth that lost part of its
edge explains that revolution well: the fit leaves a small residual.  Where the
tool leaves the part, the engagement of every tooth changes at once, revolution
after revolution; the breakage statistic can cross its threshold there, but the
fit of one tooth's loss leaves more of the change unexplained and finds less
than a chip lost (bench events, NC context: every breakage-detector false alarm
was such an exit, named chipping with an edge loss of 0.05-0.32 and a residual
of 0.18-0.31, on the programs the gate was set on and on 10 h of others).

Such an event is not raised at once.  :class:`SecondLook` holds it for one more
revolution and compares that revolution's force pattern (mean per angle bin,
the detector's own bins) with the one the event was named from.  A tooth stays
broken: the pattern repeats, and the event is raised (one revolution later).
An exit goes on changing the pattern (or the cut ends in air): no event::

    change = |a2 - a1| / |a1|      (a1, a2 without their means; raised when change <= max_change)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivesense.events.edge_loss import pattern_means

__all__ = ["SecondLook", "UNEXPLAINED_RESIDUAL", "SMALLEST_CHIP", "needs_second_look"]

_TWO_PI = 2.0 * math.pi
#: A fit residual above this leaves the change not well explained by one tooth's loss (true losses on the
#: bench: median 0.10, 90 % below 0.18) [-].
UNEXPLAINED_RESIDUAL = 0.18
#: Below this share of an edge lost the fit's name is checked: the smallest chip the detector reports (0.3)
#: and the fit's spread about it [-].
SMALLEST_CHIP = 0.4


def needs_second_look(edge_loss: float, residual: float) -> bool:
    """Whether a named event waits a revolution: the fit found less than a chip and explained little.

    Parameters
    ----------
    edge_loss : float
        The fit's edge loss [-].
    residual : float
        The fit's relative residual [-].
    """
    return edge_loss < SMALLEST_CHIP and residual > UNEXPLAINED_RESIDUAL


@dataclass
class _Held:
    event: tuple                      # (sample, kind, confidence, evidence)
    named: np.ndarray                 # the named revolution's pattern, mean per bin, without its mean [N]
    theta_from: float                 # spindle angle where the second revolution starts [rad]
    sums: np.ndarray                  # the second revolution's force per bin so far [N]
    counts: np.ndarray                # its samples per bin [-]


class SecondLook:
    """Events held for one more revolution; released when the force pattern repeats, dropped when it drifts.

    Parameters
    ----------
    bins : int
        Angle bins of a revolution (the named pattern's).
    max_change : float
        Largest relative change of the pattern from one revolution to the next of a step [-].
    capacity : int
        Most events held at once (the state stays bounded; more are raised without a second look).
    """

    def __init__(self, bins: int, max_change: float = 0.1, capacity: int = 8) -> None:
        self.bins = int(bins)
        self.max_change = float(max_change)
        self.capacity = int(capacity)
        self._held: list[_Held] = []
        self.dropped = 0

    def __len__(self) -> int:
        return len(self._held)

    def hold(self, event: tuple, named_sums: np.ndarray, named_counts: np.ndarray, theta_from: float) -> bool:
        """Hold ``event`` until the revolution from ``theta_from`` is seen; False when full (raise it now).

        Parameters
        ----------
        event : tuple
            ``(sample, kind, confidence, evidence)`` as the detector returns it.
        named_sums : ndarray
            Per bin, the sum of the force over the named revolution [N].
        named_counts : ndarray
            Per bin, the number of samples [-].
        theta_from : float
            The spindle's angle at the naming sample [rad] (the angle the named pattern is binned by:
            bin ``floor((theta mod 2 pi) / 2 pi * bins)``).
        """
        if len(self._held) >= self.capacity:
            return False
        named = pattern_means(named_sums, named_counts)
        self._held.append(_Held(event, named - named.mean(), float(theta_from), np.zeros(self.bins),
                                np.zeros(self.bins)))
        return True

    def push(self, force: np.ndarray, theta: np.ndarray, fs: float) -> list[tuple]:
        """Add a chunk; the events whose second revolution ended in it and repeated the named one.

        Parameters
        ----------
        force : ndarray
            The chunk's force [N] (as the detector bins it).
        theta : ndarray
            The spindle's angle at each sample [rad].
        fs : float
            Sample rate [Hz].
        """
        out = []
        keep = []
        for h in self._held:
            end = h.theta_from + _TWO_PI
            inside = (theta > h.theta_from) & (theta <= end)
            b = (np.mod(theta[inside], _TWO_PI) / _TWO_PI * self.bins).astype(int) % self.bins
            h.sums += np.bincount(b, force[inside], self.bins)
            h.counts += np.bincount(b, None, self.bins)
            if theta.size == 0 or theta[-1] < end:
                keep.append(h)
                continue
            second = pattern_means(h.sums, h.counts) if h.counts.any() else np.zeros(self.bins)
            second = second - second.mean()
            scale = float(np.linalg.norm(h.named))
            change = float(np.linalg.norm(second - h.named) / scale) if scale > 0 else math.inf
            if change <= self.max_change:
                sample, kind, confidence, evidence = h.event
                evidence = {**evidence, "second_look_change": round(change, 4),
                            "named_after_s": float(evidence.get("named_after_s", 0.0))
                            + float(h.counts.sum()) / fs}
                out.append((sample, kind, confidence, evidence))
            else:
                self.dropped += 1
        self._held = keep
        return out
