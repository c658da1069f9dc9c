"""Tooth breakage and chipping from the per-revolution pattern of a force stream.

Over a sliding window of one spindle revolution (by the spindle angle, the
integral of ``spindle_speed``) the detector keeps the force's harmonics of the
rotation frequency, ``H_k = (1/pi) sum F e^{-i k theta} dtheta``: multiples of
the tooth count ``N`` are the tooth-pass content, the others the
once-per-revolution content that runout and a damaged tooth make.  A baseline
``B`` (an average over revolutions, taken two revolutions back) is learnt in
the first revolutions of each cut, so runout is part of what is normal.  The
statistic is the change of the once-per-revolution content against the
tooth-pass content, with the baseline scaled to the present force level
(a feed change scales both)::

    s = |H_tooth| / |B_tooth|,     d = |H_other - s B_other| / |H_tooth|

It crosses its threshold within one tooth pass of a damaged tooth's first
pass.  The event keeps that sample's time but is named one revolution later:
the force pattern of the whole revolution after the detection against the
baseline's (mean force per angle bin) is fitted with a mechanistic pulse per
tooth, the lost share of one tooth's edge carried as chip to the next
(:mod:`drivesense.events.edge_loss`), which gives ``edge_loss`` (>= 0.9:
``breakage``, else ``chipping``).  Where the cut ends before, the per-tooth
shares of the force at the detection name it.  A one-flute tool
has no once-per-revolution content of its own: there a sudden drop of the
force below ``level_drop`` of the baseline while the feed goes on is a
breakage.

The state has a constant size: a ring of the last revolution's samples
(sized for the slowest spindle, ``min_rpm``), the harmonics, the angle bins
and three baseline snapshots.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import scipy.signal

from drivesense.dsp import median_of, sosfilt_with_state
from drivesense.errors import SignalTooShortError
from drivesense.machine.milling import check_int, check_number
from drivesense.events.breakage_loop import BINS_PER_TOOTH, CUTTING, N_SLOTS, breakage_loop
from drivesense.events.detector import Detector, spindle_speed_of
from drivesense.events.edge_loss import fit_edge_loss, pattern_bins, warm_edge_loss
from drivesense.events.second_look import SecondLook, needs_second_look
from drivesense.events.nc_guard import guard_source, process_steady

__all__ = ["BreakageDetector"]

_TWO_PI = 2.0 * math.pi


class BreakageDetector(Detector):
    """Tooth breakage and chipping from the per-revolution force pattern.

    Parameters
    ----------
    axis : str
        Axis letter of the force channel (``force_{axis}``).
    teeth : int
        Number of teeth (flutes) N.
    spindle_rpm : float, optional
        Fixed spindle speed [min^-1] when the stream has no ``spindle_speed`` channel.
    baseline_revs : int
        Revolutions of each cut the baseline is learnt over (no detection before).
    gate_n : float
        Tooth-pass amplitude [N] above which the tool counts as cutting.
    threshold : float
        Least threshold of the statistic d [-]; the learnt one is the baseline's mean + ``sigmas`` std.
    sigmas : float
        Standard deviations of the baseline's d above its mean for the threshold [-].
    level_drop : float
        A force falling below this share of the baseline's while the feed goes on is a breakage [-].
    min_rpm : float
        Slowest spindle the window is sized for [min^-1].
    breakage_loss : float
        Estimated edge loss at or above which the event is a breakage, below a chipping [-] (the pulse fit
        reads a lost tooth within about 0.1 of 1 and a chip of up to 80 % within about 0.1 of its size).
    """

    name = "breakage"

    def __init__(self, axis: str = "x", teeth: int = 2, *, spindle_rpm: float | None = None, baseline_revs: int = 8,
                 gate_n: float = 1.0, threshold: float = 0.12, sigmas: float = 8.0, level_drop: float = 0.3,
                 min_rpm: float = 500.0, breakage_loss: float = 0.9) -> None:
        self._axis = str(axis)
        self.teeth = check_int(teeth, "teeth")
        self.spindle_rpm = None if spindle_rpm is None else check_number(spindle_rpm, "spindle_rpm", positive=True)
        self.baseline_revs = check_int(baseline_revs, "baseline_revs", minimum=3)
        self.gate_n = check_number(gate_n, "gate_n", positive=True)
        self.threshold = check_number(threshold, "threshold", positive=True)
        self.sigmas = check_number(sigmas, "sigmas", positive=True)
        self.level_drop = check_number(level_drop, "level_drop", positive=True)
        self.min_rpm = check_number(min_rpm, "min_rpm", positive=True)
        self.breakage_loss = check_number(breakage_loss, "breakage_loss", positive=True)
        self.alpha = 0.5
        self.step_ratio = 3.0
        self.min_shift = 0.06

    @property
    def channel_names(self) -> tuple[str, ...]:
        """``force_{axis}`` [N]."""
        return (f"force_{self._axis}",)

    def latency_s(self, fs: float) -> float:
        """Four revolutions at the slowest expected spindle speed [s]: up to two to detect (typically one),
        the whole revolution after the detection that names the event, and one more where the name's fit
        explained little (:mod:`~drivesense.events.second_look`).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        rpm = self.spindle_rpm or self.min_rpm
        return 4 * 60.0 / rpm

    def new_state(self, fs: float) -> dict:
        """Ring of one revolution at ``min_rpm``, harmonics, bins, baselines (constant size).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        cap = int(math.ceil(fs * 60.0 / self.min_rpm)) + 2
        nk = 2 * self.teeth if self.teeth > 1 else 2
        nb = BINS_PER_TOOTH * self.teeth
        nbm = pattern_bins(self.teeth)
        if self.teeth > 1:
            warm_edge_loss(nbm, self.teeth)      # the naming's grid, built now rather than at the first alarm
        return {"sc": np.zeros(N_SLOTS), "levels": np.zeros(16), "ring_v": np.zeros(cap), "ring_r": np.zeros(cap),
                "ring_t": np.zeros(cap), "harm": np.zeros(nk, dtype=complex), "heff": np.zeros(nk, dtype=complex),
                "bins": np.zeros(nb), "ema_h": np.zeros(nk, dtype=complex), "ema_b": np.zeros(nb),
                "snap_h": np.zeros((6, nk), dtype=complex), "snap_b": np.zeros((6, nb)),
                "ring_s": np.zeros(cap), "pat": np.zeros((2, nbm)), "pat_ema": np.zeros((2, nbm)),
                "pat_snap": np.zeros((6, 2, nbm)), "pend_data": np.zeros(5), "pend_base": np.zeros((2, nbm)),
                "fs": float(fs), "armed_ever": False, "cut_seen": False, "second_look": SecondLook(nbm),
                "theta": 0.0}

    def process(self, state: dict, arrays: Mapping[str, np.ndarray], start: int):
        """Events, statistic d and threshold for the next samples (see the module docstring).

        Parameters
        ----------
        state : dict
            From :meth:`new_state`; updated in place.
        arrays : mapping of str to ndarray
            The chunk's channels [SI unit of each channel: N, rad/s, m/s, m], equally long.
        start : int
            Index of the chunk's first sample since the stream began.
        """
        force = np.asarray(arrays[self.channel_names[0]], dtype=float)
        n = force.size
        omega = np.ascontiguousarray(spindle_speed_of(arrays, n, self.spindle_rpm), dtype=float)
        raw = np.ascontiguousarray(force)
        w_median = median_of(omega)
        force = self._highpass(state, force, w_median)
        feed_ok = process_steady(arrays, state)
        if "feed_speed" not in arrays and self.teeth > 1:
            moving = np.zeros(n)       # a drop of all force without a feed signal may be a retract: not judged
        else:
            moving = feed_ok
        stat = np.empty(n)
        thr = np.empty(n)
        ev_index = np.zeros(16, dtype=np.int64)
        ev_data = np.zeros((16, 7))
        ev_pat = np.zeros((16, 4, state["pat"].shape[1]))
        fs = state["fs"]
        persist = max(1, int(round(0.5 * 60.0 / max(w_median * 60 / _TWO_PI, 1.0) / self.teeth * fs))) \
            if n else 1
        # the spindle's own angle at each sample, summed sample by sample as the loop does (the same in any
        # chunks); the loop's pattern bins are by this angle (its count from each cut's start plus its offset)
        theta = np.cumsum(np.concatenate([[state["theta"]], omega / fs]))[1:]
        state["theta"] = float(theta[-1]) if n else state["theta"]
        n_ev = breakage_loop(force, raw, omega, feed_ok, moving, fs, self.teeth, state["harm"].size, self.gate_n,
                              self.min_rpm * _TWO_PI / 60.0, float(self.baseline_revs), self.threshold, self.sigmas,
                              persist, self.level_drop, self.alpha, self.step_ratio, self.min_shift, state["sc"],
                              state["levels"], state["ring_v"], state["ring_r"], state["ring_t"], state["harm"],
                              state["heff"], state["bins"], state["ema_h"], state["ema_b"], state["snap_h"],
                              state["snap_b"], stat, thr, ev_index, ev_data, state["ring_s"], state["pat"],
                              state["pat_ema"], state["pat_snap"], state["pend_data"], state["pend_base"], ev_pat,
                              float(start))
        state["armed_ever"] = state["armed_ever"] or bool(np.any(np.isfinite(thr)))
        state["cut_seen"] = state["cut_seen"] or bool(np.any(np.isfinite(stat))) or state["sc"][CUTTING] > 0
        if state["sc"][CUTTING] == 0.0:
            state["rest_end"] = start + n          # out of a cut here: the state holds one revolution and filters
        events = []
        for e in range(n_ev):
            loss, d, t, tooth, scale, named, delay = ev_data[e]
            fit = fit_edge_loss(*ev_pat[e], self.teeth) if named else None
            if fit is not None:
                loss = fit.edge_loss
            # the level rule (one flute) fires only when the force fell below level_drop: the flute is gone
            kind = "breakage" if loss >= self.breakage_loss or tooth < 0 else "chipping"
            over = d / t if t > 0 else 1.0
            confidence = min(1.0, 0.5 + 0.5 * (over - 1.0)) if tooth >= 0 else min(1.0, 0.5 + loss / 2)
            evidence = {"edge_loss": float(round(loss, 4)), "statistic": float(d), "threshold": float(t),
                        "force_scale": float(scale), "guards": guard_source(state)}
            if tooth >= 0:
                # how the loss was read: the pulse fit over the revolution after the detection, else (the cut
                # ended first) the sector shares at the detection; and when the event was named
                evidence["edge_loss_from"] = "pulse fit" if fit is not None else "sector shares"
                if fit is not None:
                    evidence["fit_residual"] = float(round(fit.residual, 4))
                evidence["named_after_s"] = float(delay / fs)
            if tooth >= 0:
                evidence["tooth_angle_deg"] = float(round(tooth, 1))   # where the damaged tooth's sector starts
            else:
                evidence["rule"] = "force fell below level_drop of the baseline"
            event = (start + int(ev_index[e]), kind, confidence, evidence)
            if fit is not None and needs_second_look(fit.edge_loss, fit.residual):
                # one tooth's loss explains little of the change: a step or a drift?  (second_look.py)
                at = int(ev_index[e] + delay)
                if state["second_look"].hold(event, ev_pat[e, 2], ev_pat[e, 3], float(theta[min(at, n - 1)])):
                    continue
            events.append(event)
        events += state["second_look"].push(raw, theta, fs)
        events.sort(key=lambda ev: ev[0])
        return events, stat, thr

    def unusable(self, fs: float, spindle_rpm: float | None = None) -> str | None:
        """Why the detector cannot run at ``fs`` with the spindle at ``spindle_rpm`` (None when it can).

        Its window reads the harmonics of the rotation up to the tooth-passing one, which must lie below
        0.45 ``fs``.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        spindle_rpm : float, optional
            Spindle speed [min^-1] (default: the detector's own, if any).
        """
        rpm = spindle_rpm or self.spindle_rpm
        f_tooth = self.teeth * rpm / 60.0 if rpm else 0.0
        if f_tooth < 0.45 * fs:
            return None
        return (f"the tooth-passing frequency {f_tooth:.4g} Hz ({self.teeth} teeth at {rpm:.0f} min^-1) is above "
                f"what a trace sampled at {fs:g} Hz resolves: it needs a trace sampled above {f_tooth / 0.45:.0f} Hz")

    def _highpass(self, state: dict, force: np.ndarray, w: float) -> np.ndarray:
        """The force without what is slower than a third of the rotation (a ramp of an overload, the
        estimator's slow errors): it would leak into every harmonic of the window.  ``w``: the chunk's
        median spindle speed [rad/s]."""
        if force.size == 0:
            return np.ascontiguousarray(force)
        corner = max(w / _TWO_PI / 3.0, self.min_rpm / 60.0 / 3.0)
        if corner >= 0.45 * state["fs"]:
            raise SignalTooShortError(f"breakage detector: {self.unusable(state['fs'], w * 60.0 / _TWO_PI)}")
        if state.get("hp_corner") is None or abs(corner - state["hp_corner"]) > 0.05 * state["hp_corner"]:
            state["hp_corner"] = corner
            state["hp_sos"] = scipy.signal.butter(2, corner, btype="high", fs=state["fs"], output="sos")
            state["hp_zi"] = scipy.signal.sosfilt_zi(state["hp_sos"]) * force[0]
        return sosfilt_with_state(state["hp_sos"], np.ascontiguousarray(force, dtype=float), state["hp_zi"])

    def replay_from(self, state: dict) -> int | None:
        """In a cut: one revolution window and a second (the filters) before the cut began; else None.

        The baseline, its spread and the pattern followed are learnt from the cut's first revolutions on.

        Parameters
        ----------
        state : dict
            The stream's state.
        """
        if state["sc"][CUTTING] == 0.0:
            return None
        return max(0, state.get("rest_end", 0) - state["ring_v"].size - int(state["fs"]))

    def check_ready(self, state: dict) -> None:
        """Refuse a trace with a cut too short to learn a baseline (a trace of air passes).

        Parameters
        ----------
        state : dict
            The state after the whole trace.
        """
        if not state["armed_ever"] and state["cut_seen"]:     # air alone is no error (a missing tool is air)
            raise SignalTooShortError(
                f"breakage detector on 'force_{self._axis}': the tool never cut long enough to learn its baseline "
                f"({self.baseline_revs} revolutions of cutting, tooth-pass amplitude > {self.gate_n:g} N); "
                f"use a longer cut or fewer --baseline-revs")
