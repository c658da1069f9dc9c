"""Wear as a live event: every production cut's spindle power against the last calibration's model.

The calibration tracker (:mod:`drivesense.condition.wear`) sees the tool only at its calibrations.
Between them the machine cuts, and each cut's mean spindle power is measured anyway. The live
monitor compares it with what the last calibration predicts:

* **residual** ``r = P / P_last - 1`` of one cut: measured cutting power ``P`` [W] (spindle minus
  air-cut power) over ``P_last = K_tc Q + K_te A_c`` of the last calibration's K_tc, K_te at that
  cut's conditions (Eq. 2). About 0 for the tool the calibration saw; it grows with the wear since.
* **level** ``L = (1 + r) (P_last / P_first) / beta - 1``: the residual chained through the
  calibrations back to the first one (``P_first``: the first calibration's model at the same cut),
  over ``beta``, the median of ``P / P_first`` over the first ``baseline`` cuts — the relative rise
  of cutting power since new at this cut's conditions, whatever offset separates production from
  calibration (another workpiece material, a model error of the cut).
* **trend** of the level over cut distance: robust (Theil-Sen) slopes of the last ``window`` cuts
  and of the cuts before them, the noise of one cut from the earlier line (MAD).

A ``wear`` event (:class:`drivesense.event.Event`, the record every detector raises) is raised, once,
when

* the wear **accelerates**: the recent slope is ``acceleration`` times the earlier one, significantly;
* or the recent level stands ``excess`` of the rise so far above the earlier straight line,
  significantly (the accelerating stage, seen as a level);
* or the calibration tracker (:class:`~drivesense.condition.wear.WearTracker`, fed the same
  calibrations) raises its alarm (a chip's K_tc jump shows in the coefficients, not in one power).

Each event carries the remaining life the recent trend gives: the distance (and the cuts of the
recent mean length) until the level reaches ``failure_rise``, by the straight line of the last
``window`` cuts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivesense.condition.wear import (WearTracker, WearTrackerSettings, check_settings, condition_key,
                                       theil_sen_slope)
from drivesense.event import Event
from drivesense.errors import ConfigError, InvalidSignalError, MissingChannelError, NotFittedError
from drivesense.identify.coefficients import TangentialFit, fit_cut_table
from drivesense.machine.cutting_power import CutConditions, CutTable

__all__ = ["LiveWearSettings", "CutResidual", "LiveWearMonitor", "LiveWearReport", "track_wear_live",
           "cut_power", "remaining_life"]

_MAX_EARLY = 120      # cuts kept (evenly thinned) in the earlier Theil-Sen fit


@dataclass(frozen=True)
class LiveWearSettings:
    """Thresholds of the live wear monitor (dimensionless unless stated).

    The defaults were chosen on the simulated tool lives of seeds 1000-1099 (``bench wear`` scores
    seeds 0-49). One cut's power scatters by 2-3 % (workpiece hardness, the model's error between
    conditions), and chips make the level jump both ways, so the trend rules need strict significance
    to stay quiet in mid-life; on those lives, looser rules (z 4, acceleration 2.5) raised the alarm
    before 80 % of life far more often than they caught a tool the calibrations missed.

    Parameters
    ----------
    baseline : int
        Cuts after the first calibration whose median ``P / P_first`` is the new-tool level, >= 1 (each
        condition's own: the first cut of a condition not among them is its new-tool level).
    window : int
        Cuts in the recent slope, >= 3.
    min_cuts : int
        Cuts after the baselines before the trend rules run (the earlier slope needs some history),
        >= 2 * window.
    recent : float
        Part of the distance so far [-] the recent slope covers (at least ``window`` cuts).
    break_in : float
        Part of the distance so far [-] left out of the earlier slope (the sharp edge's break-in).
    acceleration : float
        Ratio of recent to earlier slope of the level [-] that marks accelerating wear.
    excess : float
        Recent level above the earlier straight line, as a fraction of the rise so far [-].
    z : float
        Significance, in standard errors [-], the slope and level rules must reach.
    failure_rise : float
        Level (relative power rise since new) [-] the remaining-life prediction extrapolates to.
    use_tracker : bool
        Also raise the event when the calibration tracker raises its alarm.
    """

    baseline: int = 5
    window: int = 10
    min_cuts: int = 20
    recent: float = 0.15
    break_in: float = 0.2
    acceleration: float = 4.0
    excess: float = 0.5
    z: float = 6.0
    failure_rise: float = 1.0
    use_tracker: bool = True

    def __post_init__(self) -> None:
        check_settings(self, "live wear", ("acceleration", "excess", "z", "failure_rise", "recent", "break_in"),
                       {"baseline": 1, "window": 3, "min_cuts": 2 * self.window})


@dataclass(frozen=True)
class CutResidual:
    """The monitor's view of one production cut.

    Attributes
    ----------
    index : int
        Cut number (0-based, in the order pushed).
    distance : float
        Cut distance of the tool at the cut [m].
    calibration : int
        Index of the calibration whose model predicted it.
    measured, predicted : float
        Measured cutting power and the last calibration's prediction [W].
    residual : float
        ``measured / predicted - 1`` [-].
    level : float
        Relative rise of cutting power since new at this cut's conditions [-], over the new-tool ratio known
        at the cut (the final levels, over the whole baseline, are what the rules use).
    slope : float
        Recent Theil-Sen slope of the level [1/m] (NaN before ``window`` levels).
    remaining_distance : float
        Distance until the recent line reaches ``failure_rise`` [m] (inf when not rising).
    """

    index: int
    distance: float
    calibration: int
    measured: float
    predicted: float
    residual: float
    level: float
    slope: float
    remaining_distance: float


def remaining_life(distance, level, failure_rise: float) -> tuple[float, float, float]:
    """Extrapolate the straight (Theil-Sen) line of a level series to a failure level.

    Parameters
    ----------
    distance : array_like
        Cut distance of each point [m], non-decreasing.
    level : array_like
        The level at each point [-].
    failure_rise : float
        Level of failure [-].

    Returns
    -------
    remaining : float
        Distance from the last point until the line reaches ``failure_rise`` [m]; 0 when it is
        there already, inf when the line does not rise.
    slope : float
        Slope of the line [1/m].
    now : float
        The line's value at the last point [-].
    """
    x, y = np.asarray(distance, dtype=float), np.asarray(level, dtype=float)
    if x.size != y.size or x.size < 2:
        raise InvalidSignalError(f"remaining life needs two or more points with a level each, got {x.size} "
                                 f"distances and {y.size} levels")
    slope = theil_sen_slope(x, y)
    if not math.isfinite(slope):
        return math.inf, slope, float(np.median(y))
    now = float(np.median(y - slope * x)) + slope * float(x[-1])
    if now >= failure_rise:
        return 0.0, slope, now
    return (float(failure_rise - now) / slope if slope > 0 else math.inf), slope, now


class LiveWearMonitor:
    """Streaming live wear monitor: calibrations and production cuts, in the order they happen.

    Parameters
    ----------
    settings : LiveWearSettings, optional
        Thresholds (defaults documented there).
    tracker_settings : WearTrackerSettings, optional
        Settings of the calibration tracker run beside it.
    detector : str
        Name the events carry.

    Examples
    --------
    >>> mon = LiveWearMonitor()                                          # doctest: +SKIP
    >>> mon.calibrate(fit, distance=0.0)                                 # doctest: +SKIP
    >>> cut, events = mon.push(conditions, cutting_power=812.0, distance=0.3)   # doctest: +SKIP
    """

    def __init__(self, settings: LiveWearSettings | None = None, *,
                 tracker_settings: WearTrackerSettings | None = None, detector: str = "live_wear") -> None:
        self.settings = settings or LiveWearSettings()
        if not isinstance(self.settings, LiveWearSettings):
            raise ConfigError(f"'settings' must be LiveWearSettings, got {type(self.settings).__name__}")
        self.tracker = WearTracker(tracker_settings)
        self.detector = str(detector)
        self.fits: list[TangentialFit] = []
        self.history: list[CutResidual] = []
        self.events: list[Event] = []
        self._ratios: list[float] = []
        self._x: list[float] = []
        self._keys: list[tuple] = []
        self._in_base: list[bool] = []
        self._y: np.ndarray | None = None
        self._beta: dict[tuple, list] = {}
        self._last_distance = -math.inf

    @property
    def alarm(self) -> bool:
        """True once a ``wear`` event has been raised."""
        return bool(self.events)

    def _clock(self, distance) -> float:
        d = float(distance)
        if not math.isfinite(d) or d < 0 or d < self._last_distance:
            raise InvalidSignalError(f"'distance' must be finite, >= 0 and non-decreasing, got {distance!r} m "
                                     f"(last {self._last_distance:.6g} m)")
        self._last_distance = d
        return d

    def calibrate(self, fit: TangentialFit, distance: float, time_s: float = math.nan) -> list[Event]:
        """Take a new calibration: later cuts are predicted from its K_tc, K_te.

        Parameters
        ----------
        fit : TangentialFit
            The calibration's coefficients.
        distance : float
            Cut distance at the calibration [m].
        time_s : float
            Time of the calibration [s] (for the event).

        Returns
        -------
        list of Event
            The event, when the calibration tracker raises its alarm here (and no event came before).
        """
        if not isinstance(fit, TangentialFit):
            raise ConfigError(f"'fit' must be a TangentialFit, got {type(fit).__name__}")
        d = self._clock(distance)
        before = self.tracker.alarm
        state = self.tracker.update(fit, d)
        self.fits.append(fit)
        if self.settings.use_tracker and state.alarm and not before and not self.events:
            return self._raise(time_s, 1.0, {"rule": "calibration", "distance_m": d,
                                             "calibration": len(self.fits) - 1, "tracker": state.evidence,
                                             **self._prediction()})
        return []

    def push(self, cut: CutConditions, cutting_power: float, distance: float,
             time_s: float = math.nan) -> tuple[CutResidual, list[Event]]:
        """Add one production cut.

        Parameters
        ----------
        cut : CutConditions
            The cut's conditions.
        cutting_power : float
            Its measured mean cutting power [W] (spindle minus air-cut power: :func:`cut_power`).
        distance : float
            Cut distance of the tool at the cut [m], not less than the last one.
        time_s : float
            Time of the cut [s] (for the event).

        Returns
        -------
        CutResidual
            The cut's residual, level and trend.
        list of Event
            The event when this cut raised it (at most one per tool).

        Raises
        ------
        NotFittedError
            No calibration yet.
        InvalidSignalError
            A power that is not a finite number > 0, a distance going back.
        """
        if not self.fits:
            raise NotFittedError("live wear: no calibration yet: call calibrate() with the tool's K_tc/K_te "
                                 "before pushing production cuts")
        if not isinstance(cut, CutConditions):
            raise ConfigError(f"'cut' must be CutConditions, got {type(cut).__name__}")
        p = float(cutting_power)
        if not math.isfinite(p) or p <= 0:
            raise InvalidSignalError(f"'cutting_power' must be a finite number > 0 W, got {cutting_power!r}")
        d = self._clock(distance)
        s = self.settings
        pred, first = float(self.fits[-1].predict_power(cut)), float(self.fits[0].predict_power(cut))
        if pred <= 0 or first <= 0:
            raise InvalidSignalError(f"the calibration predicts {pred:.4g} W for this cut: its K_tc, K_te cannot "
                                     "compare power")
        residual = p / pred - 1.0
        slope = math.nan
        remaining = math.inf
        key = condition_key(cut)
        base = self._beta.setdefault(key, [])
        in_base = not base or len(self._x) < s.baseline    # the first cuts, and the first cut of each condition
        if in_base:
            base.append(p / first)
        self._in_base.append(in_base)
        level = p / first / float(np.median(base)) - 1.0          # = (1 + residual) (pred / first) / beta - 1
        self._x.append(d)
        self._ratios.append(p / first)
        self._keys.append(key)
        self._y = None
        if len(self._x) >= s.window:
            x, y = self._series(s.window)
            remaining, slope, _ = remaining_life(x, y, s.failure_rise)
        row = CutResidual(len(self.history), d, len(self.fits) - 1, p, pred, residual, level, slope, remaining)
        self.history.append(row)
        events = [] if self.events else self._rules(row, time_s)
        return row, events

    # ------------------------------------------------------------------ rules
    def _levels(self) -> np.ndarray:
        """The level of every cut so far, each over its condition's new-tool ratio (cached until the next push)."""
        if self._y is None:
            beta = {k: float(np.median(v)) for k, v in self._beta.items()}
            self._y = np.array(self._ratios) / np.array([beta[k] for k in self._keys]) - 1.0
        return self._y

    def _series(self, last: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        x, y = np.array(self._x), self._levels()
        return (x, y) if last is None else (x[-last:], y[-last:])

    def _recent(self) -> int:
        """Cuts in the recent window: ``window``, or more when ``recent`` of the distance so far holds more."""
        x = np.array(self._x)
        return max(self.settings.window, int(np.sum(x >= x[-1] * (1.0 - self.settings.recent))))

    def _prediction(self) -> dict:
        """Remaining life from the recent cuts (empty before ``window`` levels)."""
        if len(self._x) < self.settings.window:
            return {}
        w = self._recent()
        x, y = self._series(w)
        remaining, slope, now = remaining_life(x, y, self.settings.failure_rise)
        span = (x[-1] - x[0]) / (w - 1)
        cuts = remaining / span if span > 0 and math.isfinite(remaining) else math.inf
        return {"remaining_distance_m": remaining, "remaining_cuts": cuts, "level": now, "slope_per_m": slope,
                "failure_rise": self.settings.failure_rise}

    def _rules(self, row: CutResidual, time_s: float) -> list[Event]:
        s = self.settings
        n = len(self._x)
        if n - sum(self._in_base) < s.min_cuts:
            return []
        x, y = self._series()
        w = self._recent()
        lo = int(np.searchsorted(x, s.break_in * x[-1]))          # the break-in stage is not the trend
        xe, ye = x[lo:n - w], y[lo:n - w]
        if xe.size < s.window:
            return []
        if xe.size > _MAX_EARLY:
            keep = np.unique(np.linspace(0, xe.size - 1, _MAX_EARLY).round().astype(int))
            xe, ye = xe[keep], ye[keep]
        xr, yr = x[-w:], y[-w:]
        early = theil_sen_slope(xe, ye)
        recent = theil_sen_slope(xr, yr)
        if not (math.isfinite(early) and math.isfinite(recent)):
            return []
        icpt = float(np.median(ye - early * xe))
        free = y[~np.array(self._in_base)]                   # one cut's noise, from the cuts after the baselines
        sigma = max(1.4826 * float(np.median(np.abs(np.diff(free)))) / math.sqrt(2.0), 1e-6)
        xc = xr - xr.mean()
        recent_se = sigma / math.sqrt(float(xc @ xc)) if float(xc @ xc) > 0 else math.inf
        trend = icpt + early * xr
        excess = float(np.mean(yr - trend))
        grown = float(np.mean(trend)) - float(np.median(y[:s.baseline]))
        base = {"distance_m": row.distance, "residual": row.residual, "calibration": row.calibration,
                "earlier_slope_per_m": early, "recent_slope_per_m": recent, "noise": sigma, "cuts": n}
        if early > 0 and recent > s.acceleration * early and recent - early > s.z * recent_se:
            conf = min(1.0, (recent / early - s.acceleration) / s.acceleration)
            return self._raise(time_s, conf, {"rule": "acceleration", **base, **self._prediction(),
                                              "note": f"level grows {recent / early:.1f}x faster than before"})
        if grown > s.z * sigma and excess > s.excess * grown and excess > s.z * sigma / math.sqrt(w):
            conf = min(1.0, (excess / grown - s.excess) / s.excess)
            return self._raise(time_s, conf, {"rule": "excess", **base, "excess": excess, **self._prediction(),
                                              "note": f"level {100 * excess / grown:.0f} % of its rise above the "
                                                      "straight-line trend"})
        return []

    def _raise(self, time_s: float, confidence: float, evidence: dict) -> list[Event]:
        event = Event("wear", float(time_s), "spindle", float(min(max(confidence, 0.0), 1.0)), 0.0,
                          self.detector, evidence)
        self.events.append(event)
        return [event]


@dataclass(eq=False)
class LiveWearReport:
    """A tool's session run through the live monitor.

    Attributes
    ----------
    cuts : list of CutResidual
        Every production cut, in order.
    events : list of Event
        The ``wear`` events (at most one).
    calibrations : list of float
        Distance of each calibration [m].
    name : str
        Session label.
    """

    cuts: list
    events: list
    calibrations: list
    name: str = ""

    @property
    def alarm_distance(self) -> float | None:
        """Cut distance of the first event [m] (None: no event)."""
        return self.events[0].evidence["distance_m"] if self.events else None

    def to_dict(self) -> dict:
        """JSON-ready report.

        Returns
        -------
        dict
        """
        fin = (lambda v: float(v) if math.isfinite(v) else None)  # noqa: E731
        return {"session": self.name, "calibrations": len(self.calibrations), "cuts": len(self.cuts),
                "alarm": bool(self.events), "alarm_distance_m": self.alarm_distance,
                "events": [e.to_json() for e in self.events],
                "history": [{"distance_m": c.distance, "calibration": c.calibration, "measured_w": c.measured,
                             "predicted_w": c.predicted, "residual": fin(c.residual), "level": fin(c.level),
                             "slope_per_m": fin(c.slope), "remaining_distance_m": fin(c.remaining_distance)}
                            for c in self.cuts]}


def track_wear_live(calibrations: CutTable, production: CutTable | None = None,
                    settings: LiveWearSettings | None = None, *, tracker_settings: WearTrackerSettings | None = None,
                    runout=None) -> LiveWearReport:
    """Run a tool's session through the live monitor, in order of cut distance.

    Parameters
    ----------
    calibrations : CutTable
        Calibration cuts with ``calibration`` or ``distance``; each calibration takes effect after its last cut.
    production : CutTable, optional
        Production cuts with ``distance`` [m] and measured cutting power. Without it, every cut of a later
        calibration is also a production cut against the calibration before (continuous calibration).
    settings : LiveWearSettings, optional
        Thresholds.
    tracker_settings : WearTrackerSettings, optional
        Settings of the calibration tracker beside it.
    runout : ToolRunout, optional
        The tool's measured runout, used in every calibration fit.

    Returns
    -------
    LiveWearReport

    Raises
    ------
    ConfigError
        Production cuts without a ``distance`` column, or a session without calibrations before its first cut.
    """
    if not isinstance(calibrations, CutTable):
        raise ConfigError(f"'calibrations' must be a CutTable, got {type(calibrations).__name__}")
    if calibrations.calibration is None and calibrations.distance is None:
        raise ConfigError(f"session {calibrations.name!r} has neither a 'calibration' nor a 'distance' column: "
                          "there is no wear clock to track against")
    groups = calibrations.groups()
    dist = calibrations.distance if calibrations.distance is not None else np.zeros(len(calibrations))
    steps = []                                   # (distance, order, kind, payload)
    for k, (_, idx) in enumerate(groups):
        steps.append((float(dist[idx].max()), 1, "cal", idx))
        if production is None and k > 0:
            steps += [(float(dist[i]), 0, "cut", (calibrations.cuts[i], float(calibrations.cutting_power[i])))
                      for i in idx]
    if production is not None:
        if not isinstance(production, CutTable):
            raise ConfigError(f"'production' must be a CutTable, got {type(production).__name__}")
        if production.distance is None:
            raise ConfigError(f"production cuts {production.name!r} need a 'distance' column (the wear clock)")
        steps += [(float(d), 2, "cut", (c, float(p)))
                  for c, p, d in zip(production.cuts, production.cutting_power, production.distance)]
    steps.sort(key=lambda s: (s[0], s[1]))
    first_cal = next(i for i, s in enumerate(steps) if s[2] == "cal")
    if any(s[2] == "cut" for s in steps[:first_cal]):
        raise ConfigError(f"session {calibrations.name!r}: production cuts at {steps[0][0]:.4g} m come before the "
                          "first calibration: there is no model to compare them with")
    mon = LiveWearMonitor(settings, tracker_settings=tracker_settings)
    for d, _, kind, payload in steps:
        if kind == "cal":
            mon.calibrate(fit_cut_table(calibrations, payload, warn=False, runout=runout), d)
        else:
            mon.push(payload[0], payload[1], d)
    return LiveWearReport(mon.history, mon.events, [d for d, _ in groups], calibrations.name)


def cut_power(recording, cut: tuple[float, float], air: tuple[float, float], channel: str = "spindle_power") -> float:
    """Mean cutting power of one cut from a spindle-power trace: the cut's window minus the air cut's.

    Parameters
    ----------
    recording : Recording
        Trace with the power channel [W].
    cut, air : tuple of float
        ``(start, end)`` windows [s] of the steady cut and of the air cut before it.
    channel : str
        The power channel.

    Returns
    -------
    float
        Cutting power [W].

    Raises
    ------
    MissingChannelError
        The recording has no such channel.
    """
    from drivesense.identify.coefficients import average_power

    if channel not in recording.channels:
        raise MissingChannelError(f"live wear needs the spindle power: {recording.name!r} has no channel "
                                  f"{channel!r} (channels: {', '.join(recording.channels) or 'none'})")
    return average_power(recording, *cut, channel=channel) - average_power(recording, *air, channel=channel)
