"""Tool-wear tracking from the tangential cutting coefficients (second paper, Sec. 5, Figs. 9-13).

Each calibration along a tool's life gives K_tc and K_te (:mod:`drivesense.identify.coefficients`).
The tracker turns that series into

* a **state**: ``new`` -> ``progressing`` -> ``near end of life`` (the alarm, latched);
* a **dominant mode**: ``flank`` wear (K_te rising: rubbing on a growing flank land, K_tc about
  constant) or ``chipping`` (K_tc rising while K_te falls: a chip removes flank land and blunts the
  edge), with the evidence in words;
* the **percent power increase** of one reference cut over its first value — the indicator
  conventional monitors threshold, shown beside the coefficients because its end-of-life value
  moves with the cutting conditions and the wear mode (the paper's Fig. 12 and Sec. 5.4).

Rules (the paper's observations, tested for significance with each fit's standard errors):

* The see-saw makes K_tc and K_te individually noisy, but ``F_ref = K_tc h_ref + K_te`` (the force
  per depth at the calibration's mean chip thickness) is well determined. ``progressing``: F_ref
  has risen by ``progressing_rise`` over the new-tool value, significantly.
* ``near end of life`` (alarm): the wear has entered its accelerating stage — F_ref's growth over
  the last ``window`` calibrations is ``acceleration`` times its growth rate before, significantly
  — or K_tc has risen by ``ktc_rise`` over the new tool, significantly ("somewhat prior to failure,
  the conventional cutting energy increases rapidly").
* ``chipping``: K_te has fallen from its peak by more than ``chip_drop`` of its rise while K_tc has
  risen, or K_tc explains most of the rise of F_ref; otherwise a significant K_te rise is ``flank``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.identify.coefficients import CutTable, TangentialFit, fit_cut_table

__all__ = ["check_settings", "theil_sen_slope", "condition_key", "WearTrackerSettings", "WearState", "WearTracker",
           "WearReport", "track_wear", "percent_power_increase"]

STATES = ("new", "progressing", "near end of life")


@dataclass(frozen=True)
class WearTrackerSettings:
    """Thresholds of the wear tracker (dimensionless unless stated).

    Parameters
    ----------
    baseline : int
        Calibrations averaged as the new-tool reference, >= 1.
    z : float
        Significance, in standard errors [-], that every rise or drop must reach.
    progressing_rise : float
        Relative rise of F_ref [-] that marks ``progressing``.
    acceleration : float
        Ratio of recent to earlier growth rate of F_ref [-] that marks the accelerating stage.
    window : int
        Calibrations in the recent growth-rate fit, >= 2.
    min_history : int
        Calibrations needed before the acceleration test runs.
    ktc_rise : float
        Relative rise of K_tc over the new tool [-] that marks ``near end of life`` under flank wear.
    chip_ktc_rise : float
        The same under chipping [-] (each chip raises K_tc, so the end comes at a larger rise).
    chip_drop : float
        Fraction of its rise K_te must lose from its peak to count as chipping [-].
    excess : float
        Level above the extrapolated straight-line trend, as a fraction of the rise so far [-], that
        marks the accelerating stage.
    """

    baseline: int = 1
    z: float = 3.0
    progressing_rise: float = 0.15
    acceleration: float = 2.0
    window: int = 3
    min_history: int = 6
    ktc_rise: float = 0.40
    chip_ktc_rise: float = 0.35
    chip_drop: float = 0.25
    excess: float = 0.15

    def __post_init__(self) -> None:
        check_settings(self, "wear tracker", ("z", "progressing_rise", "acceleration", "ktc_rise", "chip_ktc_rise",
                                              "chip_drop", "excess"),
                       {"baseline": 1, "window": 2, "min_history": 3})


def check_settings(settings, what: str, positive=(), integers=None) -> None:
    """Refuse settings that are not finite numbers > 0, or integers below their least value.

    Parameters
    ----------
    settings : object
        The settings (a dataclass instance).
    what : str
        How the messages name them (e.g. ``"wear tracker"``).
    positive : sequence of str
        Attributes that must be finite numbers > 0 (not booleans).
    integers : dict of str to int, optional
        Attributes that must be integers, each with its least value.

    Raises
    ------
    ConfigError
        Naming the first setting that is not valid.
    """
    for name in positive:
        value = getattr(settings, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or value <= 0:
            raise ConfigError(f"{what} setting '{name}' must be a number > 0, got {value!r}")
    for name, low in (integers or {}).items():
        value = getattr(settings, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"{what} setting '{name}' must be an integer >= {low}, got {value!r}")


@dataclass(frozen=True)
class WearState:
    """The tracker's view after one calibration.

    Attributes
    ----------
    index : int
        Calibration number (0-based, in order of distance).
    distance : float
        Cut distance at the calibration [m].
    Ktc, Kte, Ktc_se, Kte_se : float
        Coefficients [N/m^2], [N/m] and their standard errors.
    force_ref, force_ref_se : float
        F_ref = K_tc h_ref + K_te and its standard error [N/m].
    state : str
        ``new``, ``progressing`` or ``near end of life``.
    mode : str
        ``flank``, ``chipping`` or ``none`` (no significant wear yet).
    evidence : str
        Why, in words.
    alarm : bool
        True from the first ``near end of life`` on.
    percent_power : float or None
        Percent power increase of the reference cut over its first value [%].
    """

    index: int
    distance: float
    Ktc: float
    Kte: float
    Ktc_se: float
    Kte_se: float
    force_ref: float
    force_ref_se: float
    state: str
    mode: str
    evidence: str
    alarm: bool
    percent_power: float | None = None


def _se(x: float) -> float:
    return x if math.isfinite(x) else 0.0


class WearTracker:
    """Streaming wear tracker: feed it one calibration fit at a time.

    Parameters
    ----------
    settings : WearTrackerSettings, optional
        Thresholds (defaults documented there).
    h_ref : float, optional
        Reference chip thickness [m] of F_ref; default the mean h_avg of the first calibration.

    Examples
    --------
    >>> tracker = WearTracker()                                          # doctest: +SKIP
    >>> state = tracker.update(fit, distance=1.2)                        # doctest: +SKIP
    """

    def __init__(self, settings: WearTrackerSettings | None = None, h_ref: float | None = None) -> None:
        self.settings = settings or WearTrackerSettings()
        if not isinstance(self.settings, WearTrackerSettings):
            raise ConfigError(f"'settings' must be WearTrackerSettings, got {type(self.settings).__name__}")
        self.h_ref = h_ref
        self._rows: list[tuple] = []
        self.history: list[WearState] = []
        self._alarm = False
        self._first_power: float | None = None

    @property
    def alarm(self) -> bool:
        """True once the tracker has raised the end-of-life alarm."""
        return self._alarm

    def update(self, fit: TangentialFit, distance: float, reference_power: float | None = None) -> WearState:
        """Add one calibration and return the new state.

        Parameters
        ----------
        fit : TangentialFit
            The calibration's K_tc, K_te with standard errors.
        distance : float
            Cut distance at the calibration [m], not less than the previous one.
        reference_power : float, optional
            Measured cutting power of the reference cut in this calibration [W], for the percent-power indicator.

        Returns
        -------
        WearState
        """
        if not isinstance(fit, TangentialFit):
            raise ConfigError(f"'fit' must be a TangentialFit, got {type(fit).__name__}")
        d = float(distance)
        if not math.isfinite(d) or d < 0 or (self._rows and d < self._rows[-1][0]):
            raise InvalidSignalError(f"'distance' must be finite, >= 0 and non-decreasing, got {distance!r} m")
        if self.h_ref is None:
            self.h_ref = float(np.mean(fit.h_avg))
        h = self.h_ref
        X = np.column_stack([fit.h_avg, np.ones_like(fit.h_avg)])
        inv = np.linalg.inv(X.T @ X)
        ssr = float(np.sum((fit.force_per_depth - fit.predict(fit.h_avg)) ** 2))
        # design-only variances of K_tc, K_te, F_ref (times the noise variance), the residual and its dof:
        # the noise is a property of the set-up, so it is pooled over the calibrations so far
        v_tc, v_te = inv[0, 0], inv[1, 1]
        v_f = h * h * inv[0, 0] + 2 * h * inv[0, 1] + inv[1, 1]
        self._rows.append((d, fit.Ktc, fit.Kte, v_tc, v_te, fit.Ktc * h + fit.Kte, v_f, ssr, fit.n - 2))
        r = np.array(self._rows)
        dof = float(r[:, 8].sum())
        s2 = float(r[:, 7].sum()) / dof if dof > 0 else float("inf")
        stc, ste, f_ref, f_se = math.sqrt(s2 * v_tc), math.sqrt(s2 * v_te), fit.Ktc * h + fit.Kte, math.sqrt(s2 * v_f)
        pct = None
        if reference_power is not None:
            if self._first_power is None:
                self._first_power = float(reference_power)
            pct = percent_power_increase(reference_power, self._first_power)
        state, mode, evidence = self._assess()
        self._alarm = self._alarm or state == STATES[2]
        if self._alarm:
            state = STATES[2]
        ws = WearState(len(self.history), d, fit.Ktc, fit.Kte, stc, ste, f_ref, f_se, state, mode, evidence,
                       self._alarm, pct)
        self.history.append(ws)
        return ws

    # ------------------------------------------------------------------ rules
    def _assess(self) -> tuple[str, str, str]:
        s = self.settings
        r = np.array(self._rows)
        d, ktc, kte, v_tc, v_te, f, v_f, ssr, dofs = r.T
        dof = float(dofs.sum())
        s2 = float(ssr.sum()) / dof if dof > 0 else float("inf")
        stc, ste, fse = np.sqrt(s2 * v_tc), np.sqrt(s2 * v_te), np.sqrt(s2 * v_f)
        nb = min(s.baseline, len(r))
        k_now = _t_factor(s.z)(dof)
        base_f, base_tc, base_te = f[:nb].mean(), ktc[:nb].mean(), kte[:nb].mean()
        base_fse, base_tcse = fse[:nb].mean() / math.sqrt(nb), stc[:nb].mean() / math.sqrt(nb)
        base_tese = ste[:nb].mean() / math.sqrt(nb)
        rise_f = f[-1] - base_f
        sig_f = rise_f > k_now * math.hypot(fse[-1], base_fse)
        rise_tc = ktc[-1] - base_tc
        sig_tc = rise_tc > k_now * math.hypot(stc[-1], base_tcse)
        notes = [f"F_ref {100 * rise_f / base_f:+.0f} %", f"K_tc {100 * rise_tc / base_tc:+.0f} %",
                 f"K_te {100 * (kte[-1] - base_te) / base_te:+.0f} % since new"]

        # --- mode: flank (K_te up) or chipping (K_te down from its peak while K_tc up)
        smooth = np.convolve(kte, np.ones(2) / 2, mode="valid") if len(kte) > 1 else kte
        peak_i = int(np.argmax(smooth))
        peak, now = smooth[peak_i], smooth[-1]
        rise_te = peak - base_te
        drop = peak - now
        drop_sig = drop > k_now * math.hypot(ste[-1], ste[peak_i]) and drop > s.chip_drop * max(rise_te, 0.0)
        te_sig = (kte[-1] - base_te) > k_now * math.hypot(ste[-1], base_tese)
        share_tc = rise_tc * self.h_ref / rise_f if rise_f > 0 else 0.0
        if drop_sig and sig_tc:
            mode = "chipping"
            notes.append(f"K_te fell {100 * drop / max(rise_te, 1e-12):.0f} % of its rise from its peak at "
                         f"{d[min(peak_i + 1, len(d) - 1)]:.3g} m while K_tc rose: chipping")
        elif sig_f and sig_tc and share_tc > 0.5:
            mode = "chipping"
            notes.append(f"K_tc carries {100 * share_tc:.0f} % of the rise: shearing, not rubbing (chipping)")
        elif te_sig:
            mode = "flank"
            notes.append("K_te rising with K_tc about constant: flank wear (rubbing)")
        else:
            mode = "none"

        # --- state
        state = STATES[1] if (sig_f and rise_f > s.progressing_rise * base_f) else STATES[0]
        limit = s.chip_ktc_rise if mode == "chipping" else s.ktc_rise
        if sig_tc and rise_tc > limit * base_tc:
            state = STATES[2]
            notes.append(f"K_tc up {100 * rise_tc / base_tc:.0f} % (> {100 * limit:.0f} %): near end of life")
        elif len(r) >= s.min_history:
            w = s.window
            signal, se, label = (ktc, stc, "K_tc") if mode == "chipping" else (f, fse, "F_ref")
            earlier = theil_sen_slope(d[1:-w + 1], signal[1:-w + 1])
            recent = _slope(d[-w:], signal[-w:])
            recent_se = _slope_se(d[-w:], se[-w:]) * k_now
            # level above the straight-line trend of the earlier calibrations (robust line, extrapolated)
            x0, y0 = d[1:-w + 1], signal[1:-w + 1]
            trend = float(np.median(y0 - earlier * x0)) + earlier * d[-1] if math.isfinite(earlier) else np.nan
            excess = signal[-1] - trend
            grown = trend - signal[:nb].mean()
            if earlier > 0 and recent > s.acceleration * earlier and recent - earlier > recent_se:
                state = STATES[2]
                notes.append(f"wear accelerating: {label} grows {recent / earlier:.1f}x faster than before: "
                             "near end of life")
            elif math.isfinite(trend) and grown > 0 and excess > s.excess * grown and excess > k_now * se[-1]:
                state = STATES[2]
                notes.append(f"wear accelerating: {label} is {100 * excess / grown:.0f} % of its rise above the "
                             "straight-line trend: near end of life")
        return state, mode, "; ".join(notes)


def _t_factor(z: float):
    """Student-t quantile with the normal tail probability of `z`, as a function of the degrees of freedom."""
    from scipy.stats import norm, t

    p = float(norm.cdf(z))
    return lambda dof: float(t.ppf(p, max(dof, 1.0))) if math.isfinite(dof) else z


def theil_sen_slope(x: np.ndarray, y: np.ndarray) -> float:
    """Median of the pairwise slopes (robust to the break-in and to single outliers); NaN under 2 points.

    Parameters
    ----------
    x : ndarray
        Abscissae [their unit], e.g. cut distance [m].
    y : ndarray
        Values [their unit].

    Returns
    -------
    float
        The slope [unit of y per unit of x].
    """
    i, j = np.triu_indices(x.size, 1)
    dx = x[j] - x[i]
    ok = dx > 0
    return float(np.median((y[j] - y[i])[ok] / dx[ok])) if np.any(ok) else float("nan")


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y on x (NaN if x does not vary)."""
    if x.size < 2 or np.ptp(x) <= 0:
        return float("nan")
    xc = x - x.mean()
    return float(xc @ (y - y.mean()) / (xc @ xc))


def _slope_se(x: np.ndarray, se: np.ndarray) -> float:
    """Standard error of the least-squares slope for independent errors `se`."""
    if x.size < 2 or np.ptp(x) <= 0:
        return float("inf")
    xc = x - x.mean()
    return float(math.sqrt(np.sum((xc * se) ** 2)) / (xc @ xc))


def percent_power_increase(power, baseline):
    """Percent increase of cutting power over its first (new-tool) value, ``100 (P / P0 - 1)``.

    Parameters
    ----------
    power : float or array_like
        Cutting power [W].
    baseline : float
        New-tool cutting power of the same cut [W], > 0.

    Returns
    -------
    float or ndarray
        Increase [%].
    """
    p0 = float(baseline)
    if not math.isfinite(p0) or p0 <= 0:
        raise InvalidSignalError(f"'baseline' power must be > 0 W, got {baseline!r}")
    p = np.asarray(power, dtype=float)
    out = 100.0 * (p / p0 - 1.0)
    return float(out) if out.ndim == 0 else out


@dataclass(eq=False)
class WearReport:
    """A whole session tracked: one :class:`WearState` per calibration and the verdict.

    Attributes
    ----------
    states : list of WearState
        In order of distance.
    fits : list of TangentialFit
        The calibrations.
    h_ref : float
        Reference chip thickness of F_ref [m].
    reference_cut : int or None
        Index (in the table) of the first calibration's reference cut of the percent-power indicator.
    name : str
        Session label.
    """

    states: list
    fits: list = field(repr=False)
    h_ref: float = 0.0
    reference_cut: int | None = None
    name: str = ""

    @property
    def alarm_index(self) -> int | None:
        """Calibration index of the first end-of-life alarm (None: no alarm)."""
        return next((s.index for s in self.states if s.alarm), None)

    @property
    def alarm_distance(self) -> float | None:
        """Cut distance of the first alarm [m] (None: no alarm)."""
        i = self.alarm_index
        return None if i is None else self.states[i].distance

    @property
    def mode(self) -> str:
        """Dominant mode: the latest definite one (flank / chipping); ``none`` when no calibration had one.

        A calibration whose changes are not significant says nothing new about the mode, so it does
        not erase what the earlier ones showed.
        """
        return next((s.mode for s in reversed(self.states) if s.mode != "none"), "none")

    @property
    def state(self) -> str:
        """State after the last calibration."""
        return self.states[-1].state

    def to_dict(self) -> dict:
        """JSON-ready report (SI units; coefficients also in N/mm^2 and N/mm).

        Returns
        -------
        dict
        """
        rows = []
        for s, f in zip(self.states, self.fits):
            row = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(s).items()}
            row.update({"Ktc_n_mm2": s.Ktc * 1e-6, "Kte_n_mm": s.Kte * 1e-3, "cuts": f.n, "see_saw": f.see_saw})
            rows.append(row)
        return {"session": self.name, "calibrations": len(self.states), "state": self.state, "mode": self.mode,
                "alarm": self.alarm_index is not None, "alarm_index": self.alarm_index,
                "alarm_distance_m": self.alarm_distance, "h_ref_m": self.h_ref,
                "evidence": self.states[-1].evidence,
                "alarm_evidence": None if self.alarm_index is None else self.states[self.alarm_index].evidence,
                "history": rows}


def condition_key(cut) -> tuple:
    """What makes two cuts the same cut condition (tool, depths, speed, feed, engagement), for matching.

    Parameters
    ----------
    cut : CutConditions
        The cut [SI units].
    """
    return tuple(round(v, 12) for v in (cut.diameter, cut.flutes, cut.axial_depth, cut.spindle_speed,
                                        cut.feed_per_tooth, cut.entry_angle, cut.exit_angle))


def track_wear(table: CutTable, settings: WearTrackerSettings | None = None, *,
               reference: int | None = None, warn: bool = False, runout=None) -> WearReport:
    """Track a tool's wear through a session of calibrations.

    Parameters
    ----------
    table : CutTable
        Calibration cuts with a ``calibration`` number or ``distance`` per cut.
    settings : WearTrackerSettings, optional
        Tracker thresholds.
    reference : int, optional
        Index, within the first calibration, of the cut used for the percent-power indicator
        (default: its middle cut); later calibrations use the cut with the same conditions.
    warn : bool
        Issue see-saw warnings for each calibration (they are in the report either way).
    runout : ToolRunout, optional
        The tool's measured runout, used in every calibration (see
        :func:`~drivesense.identify.coefficients.calibrate_from_power`).

    Returns
    -------
    WearReport

    Raises
    ------
    InvalidSignalError
        An empty session.
    IdentificationError
        A calibration whose cuts cannot separate K_tc from K_te (naming it).
    """
    if not isinstance(table, CutTable):
        raise ConfigError(f"'table' must be a CutTable, got {type(table).__name__}")
    groups = table.groups()
    if table.calibration is None and table.distance is None:
        raise ConfigError(f"session {table.name!r} has neither a 'calibration' nor a 'distance' column: "
                          "there is no wear clock to track against")
    tracker = WearTracker(settings)
    first = groups[0][1]
    ref_local = len(first) // 2 if reference is None else int(reference)
    if not 0 <= ref_local < len(first):
        raise ConfigError(f"'reference' must index a cut of the first calibration (0..{len(first) - 1}), "
                          f"got {reference!r}")
    ref_key = condition_key(table.cuts[first[ref_local]])
    fits = []
    from drivesense.errors import IdentificationError

    for k, (d, idx) in enumerate(groups):
        try:
            fit = fit_cut_table(table, idx, warn=warn, runout=runout)
        except IdentificationError as exc:
            raise IdentificationError(f"calibration {k} (distance {d:.4g} m): {exc}") from None
        match = [i for i in idx if condition_key(table.cuts[i]) == ref_key]
        tracker.update(fit, d, float(table.cutting_power[match[0]]) if match else None)
        fits.append(fit)
    return WearReport(tracker.history, fits, float(tracker.h_ref), int(first[ref_local]), table.name)
