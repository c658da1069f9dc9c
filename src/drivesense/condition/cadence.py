"""Calibration cadence that follows the wear trend: calibrate sooner when wear speeds up or jumps.

A fixed cadence (calibrate every ``base`` cuts, as the second paper's Table 1 does) spends its
calibration cuts evenly over a life whose interesting part is the end: the accelerating flank-wear
stage and the chips that end carbide lives. :func:`propose_interval` reads the tracked series of the
force per depth ``F_ref = K_tc h_ref + K_te`` and of ``K_tc`` (:class:`~drivesense.condition.wear.WearState`)
and proposes the cut distance to the next calibration:

* **trend**: from the last calibrations, the slope ``b`` and (from four points on) the curvature
  ``c >= 0`` of each signal at the latest one; the interval ``L`` is the distance over which the
  extrapolation ``b L + c L^2`` moves the signal by ``step`` of its new-tool value. A linear trend
  gives a constant interval, an accelerating one a shrinking interval, a flat one the longest.
  ``K_te``'s rise is inside ``F_ref``; ``K_tc`` alone is followed too because chipping raises it
  while it lowers ``K_te``.
* **jump**: a signal above the straight line through the two calibrations before it by more than
  ``z`` standard errors and ``step`` of its level (a chip, a changed edge) brings the next
  calibration in at the shortest interval, to see whether the change goes on.
* **bounds**: between ``shortest`` and ``longest`` times the fixed cadence's interval; the fixed
  interval until there are two calibrations.

The cutting-power signal carries no per-tooth pattern (it is a mean over revolutions), so a change
of the per-tooth force pattern cannot be followed from it; a force or vibration channel with
spindle-angle resolution would be needed (:mod:`drivesense.condition.runout` gives its order 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.condition.wear import check_settings

__all__ = ["CadenceSettings", "CadenceProposal", "propose_interval", "propose_from_states", "AdaptiveCadence"]


@dataclass(frozen=True)
class CadenceSettings:
    """Settings of the adaptive calibration cadence (dimensionless).

    The defaults were chosen on the simulated tool lives of seeds 1000-1199 (``bench wear`` scores
    seeds 0-49): never later than the fixed interval, sooner as the wear speeds up. On those lives
    the alarm came before failure in 0.935 of them (fixed cadence: 0.91) for 10 % more calibration
    cuts. Settings that stretch the interval while the trend is flat (``longest`` 3) saved 3 % of the
    cuts but let more tools fail before their alarm (0.855).

    Parameters
    ----------
    step : float
        Change of a tracked signal between calibrations, as a fraction of its new-tool value [-].
    shortest, longest : float
        Bounds of the interval as multiples of the fixed cadence's interval [-].
    z : float
        Significance of a jump, in standard errors [-].
    window : int
        Calibrations in the slope fit (the curvature uses ``window + 1``), >= 2.
    """

    step: float = 0.10
    shortest: float = 0.25
    longest: float = 1.0
    z: float = 3.0
    window: int = 3

    def __post_init__(self) -> None:
        check_settings(self, "cadence", ("step", "shortest", "longest", "z"), {"window": 2})
        if self.shortest > self.longest:
            raise ConfigError(f"cadence setting 'shortest' ({self.shortest:g}) must not exceed 'longest' "
                              f"({self.longest:g})")


@dataclass(frozen=True)
class CadenceProposal:
    """When to calibrate next.

    Attributes
    ----------
    interval : float
        Cut distance from the latest calibration to the next one [m].
    factor : float
        ``interval`` over the fixed cadence's interval [-].
    reason : str
        Why, in words.
    """

    interval: float
    factor: float
    reason: str

    def cuts(self, cut_length: float) -> int:
        """The interval in whole cuts of ``cut_length`` [m] (at least one).

        Parameters
        ----------
        cut_length : float
            Cut distance per cut (part, pass) [m], > 0.

        Returns
        -------
        int
        """
        if not math.isfinite(cut_length) or cut_length <= 0:
            raise ConfigError(f"the cut length must be > 0 m, got {cut_length!r}")
        return max(1, int(math.floor(self.interval / cut_length + 1e-9)))


def _trend_interval(d: np.ndarray, y: np.ndarray, step: float, window: int) -> float:
    """Distance over which the local trend (slope, curvature >= 0) moves y by ``step``; inf if flat or falling."""
    k = min(window, d.size)
    x = d[-k:] - d[-1]
    if np.ptp(x) <= 0:
        return math.inf
    b = float(np.polyfit(x, y[-k:], 1)[0])
    c = 0.0
    if d.size > window:
        xq = d[-window - 1:] - d[-1]
        if np.ptp(xq) > 0:
            c2, b2, _ = np.polyfit(xq, y[-window - 1:], 2)
            if c2 > 0:              # accelerating: the slope at the latest point and the curvature
                b, c = max(b, float(b2)), float(c2)
    if c > 0:                       # the positive root of c L^2 + b L = step, in its cancellation-free form
        bb = max(b, 0.0)
        return 2 * step / (bb + math.sqrt(bb * bb + 4 * c * step))
    return step / b if b > 0 else math.inf


def _jump(d: np.ndarray, y: np.ndarray, se: np.ndarray, step: float, z: float) -> float:
    """How far the latest point lies above the line through the two before it, in units of the threshold."""
    if d.size < 3 or d[-2] <= d[-3]:
        return 0.0
    slope = (y[-2] - y[-3]) / (d[-2] - d[-3])
    excess = y[-1] - (y[-2] + max(slope, 0.0) * (d[-1] - d[-2]))
    noise = z * math.sqrt(se[-1] ** 2 + se[-2] ** 2)
    threshold = max(noise, step)
    return excess / threshold if threshold > 0 else 0.0


def propose_interval(distance, signals: dict, base: float,
                     settings: CadenceSettings | None = None) -> CadenceProposal:
    """Propose the cut distance to the next calibration from tracked wear signals.

    Parameters
    ----------
    distance : array_like
        Cut distance at each calibration so far [m], non-decreasing.
    signals : dict of str to (array_like, array_like)
        Name -> (values, standard errors) at those calibrations [any unit, the same for both]; each
        signal is scaled by its first value, which must be > 0.
    base : float
        The fixed cadence's interval [m], > 0.
    settings : CadenceSettings, optional
        Step, bounds and significance (defaults documented there).

    Returns
    -------
    CadenceProposal

    Raises
    ------
    ConfigError
        A base interval that is not > 0.
    InvalidSignalError
        Signals and distances of different lengths, a decreasing distance, a first value <= 0.
    """
    s = settings or CadenceSettings()
    if isinstance(base, bool) or not isinstance(base, (int, float)) or not math.isfinite(base) or base <= 0:
        raise ConfigError(f"the fixed calibration interval must be > 0 m, got {base!r}")
    d = np.asarray(distance, dtype=float)
    if np.any(~np.isfinite(d)) or np.any(np.diff(d) < 0):
        raise InvalidSignalError("calibration 'distance' must be finite and non-decreasing")
    lo, hi = s.shortest * base, s.longest * base
    if d.size < 2:
        return CadenceProposal(base, 1.0, "fewer than two calibrations: the fixed interval until there is a trend")
    best, why = hi, "no signal rising: the longest interval"
    for name, (values, errors) in signals.items():
        y = np.asarray(values, dtype=float)
        se = np.asarray(errors, dtype=float)
        if y.shape != d.shape or se.shape != d.shape:
            raise InvalidSignalError(f"cadence signal '{name}' has {y.size} values and {se.size} errors for "
                                     f"{d.size} calibrations")
        if not math.isfinite(y[0]) or y[0] <= 0:
            raise InvalidSignalError(f"cadence signal '{name}' must start at a value > 0, got {y[0]!r}")
        y, se = y / y[0], np.where(np.isfinite(se), se, 0.0) / y[0]
        jump = _jump(d, y, se, s.step, s.z)
        if jump > 1.0:
            return CadenceProposal(lo, s.shortest, f"{name} jumped {100 * (y[-1] - y[-2]):+.0f} % of its new-tool "
                                                   "value since the last calibration: calibrate again soon")
        length = _trend_interval(d, y, s.step, s.window)
        if math.isfinite(length) and (length < best or why.startswith("no signal")):
            best, why = min(length, best), (f"{name} is rising: {100 * s.step:.0f} % of its new-tool value "
                                            f"expected in {length:.3g} m")
    interval = float(min(max(best, lo), hi))
    return CadenceProposal(interval, interval / base, why)


def propose_from_states(states, base: float, settings: CadenceSettings | None = None) -> CadenceProposal:
    """:func:`propose_interval` on a tracker's history (F_ref and K_tc with their standard errors).

    Parameters
    ----------
    states : sequence of WearState
        :attr:`WearTracker.history <drivesense.condition.wear.WearTracker.history>` or
        :attr:`WearReport.states <drivesense.condition.wear.WearReport.states>`.
    base : float
        The fixed cadence's interval [m].
    settings : CadenceSettings, optional

    Returns
    -------
    CadenceProposal
    """
    s = settings or CadenceSettings()
    d = [st.distance for st in states]
    signals = {"F_ref": ([st.force_ref for st in states], [st.force_ref_se for st in states]),
               "K_tc": ([st.Ktc for st in states], [st.Ktc_se for st in states])}
    return propose_interval(d, signals, base, s)


class AdaptiveCadence:
    """A wear tracker that also says when to calibrate next: feed it each calibration as it is measured.

    Parameters
    ----------
    base : float
        The fixed cadence's interval [m].
    settings : CadenceSettings, optional
        Cadence settings.
    tracker_settings : WearTrackerSettings, optional
        Settings of the wear tracker it runs.
    cut_length : float, optional
        Cut distance per cut (part, pass) [m]: the interval is then rounded down to whole cuts, at
        least one (a calibration cannot interrupt a cut).

    Attributes
    ----------
    tracker : WearTracker
        The tracker (its ``history`` and ``alarm``).
    proposals : list of CadenceProposal
        One per calibration.
    """

    def __init__(self, base: float, settings: CadenceSettings | None = None, tracker_settings=None,
                 cut_length: float | None = None) -> None:
        from drivesense.condition.wear import WearTracker

        self.base = float(base)
        self.cut_length = None if cut_length is None else float(cut_length)
        self.settings = settings or CadenceSettings()
        self.tracker = WearTracker(tracker_settings)
        self.proposals: list[CadenceProposal] = []

    def update(self, table, distance: float) -> CadenceProposal:
        """Add one calibration (its cuts and measured cutting power) and propose the next.

        Parameters
        ----------
        table : CutTable
            The calibration's cuts with their cutting power [W].
        distance : float
            Cut distance at the calibration [m].

        Returns
        -------
        CadenceProposal
        """
        from drivesense.identify.coefficients import fit_cut_table

        self.tracker.update(fit_cut_table(table, warn=False), distance)
        proposal = propose_from_states(self.tracker.history, self.base, self.settings)
        self.proposals.append(proposal)
        return proposal

    def __call__(self, table, distance: float) -> float:
        """:meth:`update`, returning the interval [m] in whole cuts (the simulator's ``cadence`` callable)."""
        proposal = self.update(table, distance)
        if self.cut_length is None:
            return proposal.interval
        return proposal.cuts(self.cut_length) * self.cut_length
