"""Regenerative chatter: force content at frequencies that are not harmonics of the spindle rotation.

A stable cut repeats every spindle revolution (runout included), so the
double once-per-revolution comb ``e(t) = F(t) - 2 F(t - T_rev) + F(t - 2 T_rev)``
(4-point Lagrange fractional delays) cancels all of its harmonics -- the
tooth-pass frequency's and the spindle's -- and, to first order, a pattern
that drifts slowly (an entry, wear).  Chatter vibrates at a frequency near a
tool mode that is no such harmonic and passes the comb.  After a band-pass
(``highpass_hz`` to ``highest_hz``) the detector compares the comb's RMS over
``window_revs`` (whole tooth passes; less the noise floor it learnt in air) with the RMS of the
repeating part ``(F(t) + F(t - T) + F(t - 2T)) / 3`` (the forced response)::

    r = sqrt((ms(e_bp) - noise) / 6) / rms(forced)

``r`` is about zero in a stable cut and about one for chatter as strong as the
forced force.  A candidate needs ``r`` above the threshold for ``hold_revs``
revolutions, after ``settle_revs`` of cutting at a steady feed (``feed_speed``)
and a forced level that moved by < ``level_change`` over them.  It becomes an
event when the last ~0.4 s of force hold a spectral line of its own between the
spindle harmonics (``prominence`` times their median), found again at the same
frequency a revolution (``recheck_revs``, at least ``recheck_s``) later (the
line of a transient moves or goes); that line's frequency is the chatter
frequency reported.

Chatter grows from the noise over revolutions.  A step of the force (a
breakage, a feed change) makes the comb jump within a revolution and passes it
for two revolutions; a transient (the tool leaving the part) jumps too and then
dies away.  A comb that jumped (3.5 times from one revolution to the next, or 9
times over two, within the last ten) is confirmed no sooner than three
revolutions and the RMS window into its run and only while it holds 0.8 of its
peak; any candidate whose comb RMS has fallen below ``transient_decay`` of its
peak over the last ten revolutions is no chatter.  With the NC's context
(:mod:`~drivesense.events.nc_guard`), its word replaces the guards read from the
drive signals: the forced level's change and the measured feed, which chatter
itself shakes, do not hold the detector there.

The drive's own lines are no chatter: a measuring error that repeats every
``p`` of the axis's travel (the motor encoder's signal period, ``pitches_m``)
is a line at ``|v| / p`` in a force estimate, and a feed override moves it into
the chatter band.  Where the axis speed is known, the share of the comb's power
in those lines (and their tooth-pass sidebands) is taken off the statistic,
and a spectral line there confirms nothing (:func:`drive_lines`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import scipy.signal
from numba import njit

from drivesense.errors import ConfigError, SignalTooShortError
from drivesense.machine.milling import check_int, check_number
from drivesense.events.detector import Detector, RecentSamples, spindle_speed_of
from drivesense.events.chatter_spectrum import drive_lines, drive_share, spectral_line
from drivesense.events.nc_guard import guard_source, process_steady

__all__ = ["ChatterDetector", "drive_lines", "drive_share"]

_TWO_PI = 2.0 * math.pi
_FREQ_RING = 4096
#: Revolutions back over which a transient's peak counts (an exit's comb dies away over about ten).
_PEAK_REVS = 10
#: A comb RMS that rose this many times from one revolution to the next jumped (a step, an exit), it did not
#: grow: chatter grows by 3x per revolution at most on the bench's cuts [-].
_JUMP = 3.5
#: ... or this many times over two revolutions (chatter: 7x at most) [-].
_JUMP_2 = 9.0
#: After a jump, chatter is confirmed no sooner than this many revolutions (and the RMS window) into the run
#: above the threshold: a step has passed the double comb (2) and a transient's comb has died away [rev].
_AFTER_JUMP_REVS = 3.0
#: ... and its comb RMS must still be this share of its peak over the last _PEAK_REVS revolutions [-].
_AFTER_JUMP_KEEP = 0.8
#: With the NC's context, the forced level's change that still holds the detector: the last part of an exit,
#: where the forced force fades under the noise and the drive's lines (``level_change`` without context) [-].
_CONTEXT_LEVEL = 0.5
(_HEAD, _COUNT, _EE, _MF, _HOLD, _LATCH, _W_REF, _Z0, _Z1, _FHEAD, _ARMED, _EP, _EN, _CUTFOR,
 _QUIET, _LEN, _SUM, _AIRFOR, _REVPH, _LHEAD, _LEVEL, _Z2, _Z3, _RUNAT, _PEAK, _INRUN) = range(26)
#: What the guard codes :meth:`ChatterDetector.process` returns per sample mean (0: judged).
GUARDS = {1: "settling (a cut's start, a feed or spindle-speed change)",
          2: "forced level changing (an exit, an abrupt engagement change)",
          3: "above the threshold for less than hold_revs, or no spectral line of its own",
          4: "a transient: the comb's output has fallen from a peak in the last 10 revolutions (an exit, a step)"}


@njit(cache=True, nogil=True)
def _unconfirmed(sc, held, start, upto):  # pragma: no cover - numba
    """The run above the threshold that ends here without an event: code 3 over its samples in this chunk
    (``start``: the chunk's first sample since the stream began; ``upto``: the chunk index it ends at)."""
    if sc[_INRUN] != 0.0 and sc[_LATCH] == 0.0:
        for j in range(max(int(sc[_RUNAT]) - start, 0), upto):
            if held[j] == 0.0:
                held[j] = 3.0
    sc[_INRUN] = 0.0


@njit(cache=True, nogil=True)
def _delayed(ring, head, delay):  # pragma: no cover - numba
    """The ring's value ``delay`` samples before ``head`` (4-point Lagrange: a linear interpolation would
    leak the tooth-pass harmonics through the comb)."""
    cap = ring.size
    pos = head - delay
    while pos < 0:
        pos += cap
    i0 = int(pos)
    fr = pos - i0
    jm = (i0 - 1) % cap
    j0 = i0 % cap
    j1 = (i0 + 1) % cap
    j2 = (i0 + 2) % cap
    return (-fr * (fr - 1.0) * (fr - 2.0) / 6.0 * ring[jm] + (fr + 1.0) * (fr - 1.0) * (fr - 2.0) / 2.0 * ring[j0]
            - (fr + 1.0) * fr * (fr - 2.0) / 2.0 * ring[j1] + (fr + 1.0) * fr * (fr - 1.0) / 6.0 * ring[j2])


@njit(cache=True, nogil=True)
def _peak_history(sc, peaks):  # pragma: no cover - numba
    """The comb's largest power in each of the last ``_PEAK_REVS`` revolutions (oldest first) and in the
    present one so far."""
    done = int(sc[_LHEAD])
    m = min(done, _PEAK_REVS)
    out = np.empty(m + 1)
    for q in range(m):
        out[q] = peaks[(done - m + q) % peaks.size]
    out[m] = sc[_PEAK]
    return out


@njit(cache=True, nogil=True)
def _chatter_loop(force, omega, fs, sos, lp, gate, threshold, hold_revs, window_revs, settle_revs, decay, level_max,
                  feed_ok, sc, ring, fring, levels, peaks, stat, thr_out, held, off, start,
                  cand):  # pragma: no cover - numba
    """The comb and its guards over ``force[off:]`` (``held``: the whole chunk's guard codes, ``start``: the
    chunk's first sample since the stream began); returns the samples done (fewer at a candidate)."""
    n = force.size - off
    cap = ring.size
    nfr = fring.size
    b0, b1, b2, a1, a2 = sos[0], sos[1], sos[2], sos[4], sos[5]
    for m in range(n):
        i = off + m
        w = omega[i]
        f = force[i]
        head = int(sc[_HEAD])
        ring[head] = f
        sc[_HEAD] = (head + 1) % cap
        if sc[_COUNT] < cap:
            sc[_COUNT] += 1
        stat[i] = np.nan
        thr_out[i] = np.nan
        if w <= 0.0:
            sc[_ARMED] = 0.0
            continue
        delay = _TWO_PI / w * fs
        # a spindle-speed change invalidates the comb for a revolution
        if abs(w - sc[_W_REF]) > 0.01 * max(w, 1e-9):
            _unconfirmed(sc, held, start, i)
            sc[_W_REF] = w
            sc[_ARMED] = 0.0
            sc[_HOLD] = 0.0
        if 2.0 * delay + 3 >= sc[_COUNT] or 2.0 * delay + 3 >= cap:
            continue
        past1 = _delayed(ring, head, delay)
        past2 = _delayed(ring, head, 2.0 * delay)
        # the double comb cancels every spindle harmonic and, to first order, a pattern that drifts
        # slowly (an entry, wear, a feed ramp); chatter repeats at no revolution and passes
        e = f - 2.0 * past1 + past2
        per = (f + past1 + past2) / 3.0 - sc[_MF]        # the part that repeats: the forced response
        # high-pass (one biquad, direct form II transposed)
        y = b0 * e + sc[_Z0]
        sc[_Z0] = b1 * e - a1 * y + sc[_Z1]
        sc[_Z1] = b2 * e - a2 * y
        u = y                               # and the low-pass (direct form II transposed)
        y = lp[0] * u + sc[_Z2]
        sc[_Z2] = lp[1] * u - lp[4] * y + sc[_Z3]
        sc[_Z3] = lp[2] * u - lp[5] * y
        fh = int(sc[_FHEAD])
        fring[fh] = y
        sc[_FHEAD] = (fh + 1) % nfr
        a = 1.0 / (window_revs * delay)
        sc[_MF] += a * (f - sc[_MF])
        # the comb's mean square over exactly window_revs (a moving window: a step of the force leaves
        # it as soon as the double comb has passed it, two revolutions on)
        length = max(1, int(window_revs * delay))
        if length != int(sc[_LEN]) or length >= nfr:
            sc[_LEN] = min(length, nfr - 1)
            sc[_SUM] = 0.0
            for k in range(int(sc[_LEN])):
                v = fring[(fh - k) % nfr]
                sc[_SUM] += v * v
        else:
            old = fring[(fh - length) % nfr]
            sc[_SUM] += y * y - old * old
        sc[_EE] = max(sc[_SUM], 0.0) / sc[_LEN]
        sc[_EP] += a * (per * per - sc[_EP])
        sc[_ARMED] += 1.0
        if sc[_ARMED] < 2.0 * delay or sc[_EP] <= 0.0:
            continue
        rf = math.sqrt(sc[_EP])
        if rf < gate:
            # not cutting: learn the comb's noise floor (the estimate's own noise), to subtract it in the cut
            sc[_AIRFOR] += 1.0
            if sc[_AIRFOR] > settle_revs * delay:      # well away from a cut's start or end
                sc[_EN] += 0.1 * a * (sc[_EE] - sc[_EN])
            _unconfirmed(sc, held, start, i)
            sc[_HOLD] = 0.0
            sc[_LATCH] = 0.0
            sc[_CUTFOR] = 0.0
            continue
        sc[_AIRFOR] = 0.0
        comb = max(sc[_EE] - sc[_EN], 0.0)
        sc[_PEAK] = max(sc[_PEAK], comb)
        r = math.sqrt(comb / 6.0) / rf
        stat[i] = r
        thr_out[i] = threshold
        # the tool must have cut for settle_revs at a steady feed (the first revolutions of an entry and a
        # feed-override ramp change the pattern itself)
        sc[_CUTFOR] += 1.0
        if feed_ok[i] < 0.5:
            sc[_CUTFOR] = 0.0
        # the forced level, once per revolution: a level that fell by > 15 % (or rose by > 60 %) over
        # settle_revs (an exit, an abrupt change of engagement) is no steady cut to judge
        sc[_REVPH] += w / fs
        if sc[_REVPH] >= _TWO_PI:
            sc[_REVPH] -= _TWO_PI
            k = int(sc[_LHEAD]) % levels.size       # _LHEAD counts revolutions; the ring wraps
            levels[k] = rf
            peaks[k] = sc[_PEAK]                    # the comb's largest power in that revolution
            sc[_PEAK] = 0.0
            sc[_LHEAD] += 1.0
            old_k = (k - int(settle_revs) + levels.size) % levels.size
            if sc[_LHEAD] > settle_revs and levels[old_k] > 0.0:
                # a falling level is the tool leaving the part; a rising one is judged only when abrupt
                # (an entry fills in steadily, and chatter often starts on the way in)
                ratio = rf / levels[old_k]
                sc[_LEVEL] = 1.0 - ratio if ratio < 1.0 else (ratio - 1.0) / 4.0
        if sc[_LEVEL] > level_max:
            _unconfirmed(sc, held, start, i)
            sc[_HOLD] = 0.0
            held[i] = 2.0
        if sc[_CUTFOR] < settle_revs * delay:
            _unconfirmed(sc, held, start, i)
            sc[_HOLD] = 0.0
            held[i] = 1.0
            continue
        if r > threshold:
            if sc[_INRUN] == 0.0:                   # a run above the threshold begins
                sc[_RUNAT] = start + i
                sc[_INRUN] = 1.0
            sc[_HOLD] += 1.0
            sc[_QUIET] = 0.0
        else:
            _unconfirmed(sc, held, start, i)
            sc[_HOLD] = 0.0
            sc[_QUIET] += 1.0
            if r < 0.5 * threshold and sc[_QUIET] > max(settle_revs * delay, fs):
                sc[_LATCH] = 0.0          # re-armed only once the chatter has clearly gone
        if sc[_HOLD] >= hold_revs * delay and sc[_LATCH] == 0.0 and decay > 0.0:
            # a transient (a part's exit, a step of the pattern) jumps within a revolution and then dies
            # away; chatter grows from the noise and holds: a comb below decay^2 of its power's peak over
            # the last _PEAK_REVS revolutions is no chatter
            if comb < decay * decay * _peak_history(sc, peaks).max():
                _unconfirmed(sc, held, start, i)
                sc[_HOLD] = 0.0
                held[i] = 4.0
                continue
        if sc[_HOLD] >= hold_revs * delay and sc[_LATCH] == 0.0:
            # a candidate: the caller checks the spectrum and sets the latch (or the hold back to zero)
            cand[0] = r
            cand[1] = rf
            cand[2] = w
            return m + 1
    return n


def _jumped(sc: np.ndarray, peaks: np.ndarray, forced_rms: float, threshold: float) -> bool:
    """Whether the comb's RMS rose more than ``_JUMP`` times from one revolution to the next (``_JUMP_2`` over
    two) within the last ``_PEAK_REVS`` (each revolution's largest, the present one's so far; below a fifth
    of the threshold counts as that much: the noise)."""
    floor = 6.0 * (0.2 * threshold * forced_rms) ** 2
    seq = [max(v, floor) for v in _peak_history(sc, peaks)]
    # a jump that straddles two revolutions' boundary shows over two
    return any(b > _JUMP ** 2 * a for a, b in zip(seq[:-1], seq[1:])) or \
        any(b > _JUMP_2 ** 2 * a for a, b in zip(seq[:-2], seq[2:]))


def _below_peak(sc: np.ndarray, peaks: np.ndarray, share: float) -> bool:
    """Whether the comb's RMS now is below ``share`` of its largest over the last ``_PEAK_REVS`` revolutions."""
    return max(sc[_EE] - sc[_EN], 0.0) < share ** 2 * _peak_history(sc, peaks).max()


class ChatterDetector(Detector):
    """Regenerative chatter from the force's content between the spindle harmonics.

    Parameters
    ----------
    axis : str
        Axis letter of the force channel.
    spindle_rpm : float, optional
        Fixed spindle speed [min^-1] when the stream has no ``spindle_speed`` channel.
    threshold : float
        Alarm level of ``r`` [-] (non-harmonic RMS over forced RMS).
    hold_revs : float
        How long ``r`` must stay above the threshold (> 2 so that a step of the force does not alarm)
        [revolutions].
    window_revs : float
        Averaging time of the RMS values [revolutions], at least (:attr:`window`).
    highpass_hz : float
        Corner of the high-pass on the comb output [Hz] (below the chatter band, above the estimator's
        slow errors).
    gate_n : float
        Forced RMS [N] below which the tool is not cutting (no judgement).
    min_rpm : float
        Slowest spindle the delay line is sized for [min^-1].
    settle_revs : float
        Cutting at a steady feed before the detector judges (an entry, an override) [revolutions].
    prominence : float
        A candidate is confirmed when the largest spectral line between the spindle harmonics stands this
        many times above their median (the last ~0.2 s of force) [-].
    exclude_hz : sequence of float
        The feed drive's own mode frequencies [Hz] (a line within 10 % of one is not chatter).
    highest_hz : float, optional
        Top of the chatter band [Hz]: set it below the estimator's low-pass, above which its force is
        not to be trusted (default 0.45 fs).
    recheck_s : float
        The spectral line must be found again, at the same frequency, at least this much later [s].
    recheck_revs : float
        ... and at least this many spindle revolutions later [revolutions].
    pitches_m : sequence of float
        Travel over which the drive's measuring error repeats [m] (the motor encoder's signal period,
        :meth:`~drivesense.machine.signal_chain.SignalParams.drive_pitches`): a line where the axis speed
        (its ``{axis}_table_position``, else ``feed_speed``) puts that error is not chatter
        (:func:`drive_lines`).
    teeth : int, optional
        Teeth of the tool: the tooth passes' sidebands of those lines are not chatter either.
    transient_decay : float
        A candidate whose comb RMS has fallen below this share of its peak over the last 10 revolutions is a
        transient, not chatter (0: no such check) [-].
    level_change : float
        The forced level's fall over ``settle_revs`` (a rise counts a quarter) above which the detector holds
        (an exit, an abrupt change of engagement) [-].
    """

    name = "chatter"
    #: Guard codes :meth:`process` returns per sample (0: judged).
    GUARDS = GUARDS

    def __init__(self, axis: str = "x", *, spindle_rpm: float | None = None, threshold: float = 0.05,
                 hold_revs: float = 1.0, window_revs: float = 0.5, highpass_hz: float = 150.0, gate_n: float = 2.0,
                 min_rpm: float = 500.0, settle_revs: float = 10.0, prominence: float = 8.0,
                 exclude_hz=(), highest_hz: float | None = None, recheck_s: float = 0.02,
                 recheck_revs: float = 1.0, pitches_m=(),
                 teeth: int | None = None, transient_decay: float = 0.5, level_change: float = 0.15) -> None:
        self._axis = str(axis)
        self.spindle_rpm = None if spindle_rpm is None else check_number(spindle_rpm, "spindle_rpm", positive=True)
        self.threshold = check_number(threshold, "threshold", positive=True)
        self.hold_revs = check_number(hold_revs, "hold_revs", positive=True)
        self.window_revs = check_number(window_revs, "window_revs", positive=True)
        self.highpass_hz = check_number(highpass_hz, "highpass_hz", positive=True)
        self.gate_n = check_number(gate_n, "gate_n", positive=True)
        self.min_rpm = check_number(min_rpm, "min_rpm", positive=True)
        self.settle_revs = check_number(settle_revs, "settle_revs", positive=True)
        if not 1.0 <= self.settle_revs <= 60.0:
            raise ConfigError(f"'settle_revs' must be within 1-60 revolutions, got {settle_revs!r}")
        self.prominence = check_number(prominence, "prominence", positive=True)
        self.recheck_s = check_number(recheck_s, "recheck_s", positive=True)
        self.recheck_revs = check_number(recheck_revs, "recheck_revs", nonneg=True)
        self.exclude_hz = tuple(check_number(f, "exclude_hz", positive=True) for f in exclude_hz)
        self.highest_hz = None if highest_hz is None else check_number(highest_hz, "highest_hz", positive=True)
        self.pitches_m = tuple(check_number(p, "pitches_m", positive=True) for p in pitches_m)
        self.teeth = None if teeth is None else check_int(teeth, "teeth")
        self.transient_decay = check_number(transient_decay, "transient_decay", nonneg=True)
        self.level_change = check_number(level_change, "level_change", positive=True)
        if self.transient_decay >= 1.0:
            raise ConfigError(f"'transient_decay' must be within 0-1 (0: off), got {transient_decay!r}")

    def recheck(self, omega: float) -> float:
        """How much later the spectral line must be found again [s]: ``recheck_s`` or ``recheck_revs`` spindle
        revolutions, the longer.

        Parameters
        ----------
        omega : float
            Spindle speed [rad/s].
        """
        return max(self.recheck_s, self.recheck_revs * _TWO_PI / omega if omega > 0 else 0.0)

    @property
    def window(self) -> float:
        """The RMS values' averaging time [revolutions]: ``window_revs`` rounded up to whole tooth passes (one
        revolution when the teeth are not known), so that a tool cutting only part of each revolution does not
        drop the statistic below the threshold between its teeth."""
        z = self.teeth or 1
        return math.ceil(self.window_revs * z - 1e-9) / z

    @property
    def channel_names(self) -> tuple[str, ...]:
        """``force_{axis}`` [N]."""
        return (f"force_{self._axis}",)

    def highest(self, fs: float) -> float:
        """Top of the chatter band [Hz]: ``highest_hz`` or 0.45 fs.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return min(self.highest_hz or 0.45 * fs, 0.45 * fs)

    @property
    def min_fs_hz(self) -> float:
        """The sample rate [Hz] the chatter band needs: above it, 0.45 fs clears 1.5 ``highpass_hz``."""
        return 1.5 * self.highpass_hz / 0.45

    def unusable(self, fs: float, spindle_rpm: float | None = None) -> str | None:
        """Why the detector cannot run on a stream at ``fs`` (None when it can), in words a user acts on.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        spindle_rpm : float, optional
            Not used (the chatter band does not depend on it) [min^-1].
        """
        if fs <= self.min_fs_hz:
            return (f"the chatter detector needs a trace sampled above {self.min_fs_hz:.0f} Hz (it looks for "
                    f"chatter from {self.highpass_hz:g} Hz up), this one is sampled at {fs:g} Hz")
        if self.highest(fs) <= 1.5 * self.highpass_hz:
            return (f"the chatter detector looks for chatter from {self.highpass_hz:g} Hz up, but the force "
                    f"estimate is trusted only below {self.highest(fs):g} Hz (its bandwidth)")
        return None

    def spectrum_samples(self, fs: float) -> int:
        """Samples of the confirming spectrum: the power of two at or above 0.4 s (the delay line holds it).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return int(2 ** int(math.ceil(math.log2(max(0.4 * fs, 64)))))

    def latency_s(self, fs: float) -> float:
        """The hold, the averaging window and the re-check at the slowest expected spindle speed [s].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        rpm = self.spindle_rpm or self.min_rpm
        return (self.hold_revs + self.window) * 60.0 / rpm + self.recheck(rpm * _TWO_PI / 60.0)

    def new_state(self, fs: float) -> dict:
        """Delay line of one revolution at ``min_rpm``, filter states, RMS values (constant size).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        why = self.unusable(fs)
        if why:
            raise (SignalTooShortError if fs <= self.min_fs_hz else ConfigError)(why)
        cap = max(2 * int(math.ceil(fs * 60.0 / self.min_rpm)) + 8, self.spectrum_samples(fs))
        sos = scipy.signal.butter(2, self.highpass_hz, btype="high", fs=fs, output="sos")[0]
        top = self.highest(fs)
        lp = scipy.signal.butter(2, top, btype="low", fs=fs, output="sos")[0]
        return {"sc": np.zeros(26), "levels": np.zeros(64), "peaks": np.zeros(64), "ring": np.zeros(cap),
                "fring": np.zeros(_FREQ_RING),
                "sos": np.ascontiguousarray(sos, dtype=float),
                "lp": np.ascontiguousarray(lp, dtype=float), "fs": float(fs)}

    def process(self, state: dict, arrays: Mapping[str, np.ndarray], start: int):
        """Events, statistic r, threshold and guard codes (:data:`GUARDS`) for the next samples.

        See the module docstring.  The guard code is 3 over a run above the threshold that ended without an
        event (its samples in this chunk; a run that began in an earlier chunk keeps its codes there).

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
        n = force.size
        omega = np.ascontiguousarray(spindle_speed_of(arrays, n, self.spindle_rpm), dtype=float)
        # with the NC's context its word replaces the slow guards read from the drive signals: the measured
        # feed (which chatter itself shakes) and all but a large change of the forced level (exits: the
        # transient checks)
        feed_ok = process_steady(arrays, state, measured_feed=False)
        level_max = self.level_change if guard_source(state) != "nc_context" else _CONTEXT_LEVEL
        hold = state.get("nc_hold")              # the hold after the NC's commanded changes (None: no context)
        unsteady = np.flatnonzero(hold < 0.5) if hold is not None else ()
        if len(unsteady):                        # the last sample of a commanded change's hold
            state["last_unsteady"] = start + int(unsteady[-1])
        stat = np.empty(n)
        thr = np.empty(n)
        held = np.zeros(n)
        stat[:] = np.nan
        thr[:] = np.nan
        cand = np.zeros(3)
        events = []
        sc = state["sc"]
        fs = state["fs"]
        drive = self._drive(arrays)
        pos = 0
        while pos < n:
            done = pos + _chatter_loop(force, omega, fs, state["sos"], state["lp"], self.gate_n, self.threshold,
                                       self.hold_revs, self.window, self.settle_revs, self.transient_decay,
                                       level_max, feed_ok,
                                       sc, state["ring"], state["fring"], state["levels"], state["peaks"], stat, thr,
                                       held, pos, start, cand)
            if done < n or cand[0] > 0.0:
                if cand[0] > 0.0:
                    bands = self._drive_bands(state, drive, done, cand[2])
                    # the statistic without the drive's lines: what is left must still be above the threshold
                    share = drive_share(state["fring"], int(sc[_FHEAD]), fs, bands, _FREQ_RING // 2)
                    here = start + done - 1
                    pending = state.get("pending")
                    df = fs / self.spectrum_samples(fs)
                    recheck = self.recheck(cand[2]) * fs
                    if pending is not None and here - pending[1] > 4 * recheck:
                        pending = None
                    line = (state["ring"], int(sc[_HEAD]), fs, cand[2], self.highpass_hz, self.highest(fs),
                            self.spectrum_samples(fs), self.prominence, self.exclude_hz, bands)
                    # the line found before, looked for again (it need not be the largest now: a second one
                    # may grow beside it); else the largest line
                    ok, freq, prom = spectral_line(*line, near_hz=pending[0], tol_hz=3 * df) if pending \
                        else (False, 0.0, 0.0)
                    again = ok
                    if not ok:
                        ok, freq, prom = spectral_line(*line)
                    ok = ok and cand[0] * math.sqrt(max(1.0 - share, 0.0)) > self.threshold
                    # a spectrum over a feed change (an override's ramp) holds its sidebands: no confirmation
                    # until the window has left the change
                    ok = ok and here - self.spectrum_samples(fs) >= state.get("last_unsteady", -1)
                    delay = _TWO_PI / cand[2] * fs
                    # a step of the force (a breakage) or a transient (an exit) makes the comb jump from the
                    # noise within a revolution; a step passes the double comb for two revolutions and the RMS
                    # window, a transient's comb dies away over a few (the decay check); chatter grows from the
                    # noise over revolutions and is confirmed at the recheck
                    step = (_AFTER_JUMP_REVS + self.window - self.hold_revs) * delay
                    # after a jump the comb must hold its level (a transient's dies away)
                    waited = here - pending[1] >= step - 1 if pending else False
                    if ok and again and pending[2] and waited and _below_peak(sc, state["peaks"], _AFTER_JUMP_KEEP):
                        ok = False
                    if ok and again and (not pending[2] or waited):
                        # the same line a moment later (past a step's passage if the comb jumped): chatter (a
                        # transient's line moves or goes)
                        sc[_LATCH] = 1.0
                        state["pending"] = None
                        events.append((here, "chatter", min(1.0, 0.5 * cand[0] / self.threshold),
                                       {"statistic": float(cand[0]), "threshold": self.threshold,
                                        "chatter_frequency_hz": freq, "prominence": prom,
                                        "forced_rms_n": float(cand[1]), "guards": guard_source(state)}))
                    elif ok and again:
                        # the same line after a jump: looked for again once a step would have passed
                        sc[_HOLD] = self.hold_revs * delay - (step - (here - pending[1]))
                    elif ok:
                        state["pending"] = (freq, here, _jumped(sc, state["peaks"], cand[1], self.threshold))
                        sc[_HOLD] = self.hold_revs * delay - recheck      # (below zero: counts up to it)
                    else:
                        state["pending"] = None
                        _unconfirmed(sc, held, start, done)
                        sc[_HOLD] = 0.0
                    cand[:] = 0.0
            pos = done
        if drive is not None:
            tail = state.setdefault("drive", RecentSamples(self.spectrum_samples(fs) + 1))
            tail.push(n, {"drive": drive[1]})
        return events, stat, thr, held

    def _drive(self, arrays: Mapping[str, np.ndarray]) -> tuple[str, np.ndarray] | None:
        """What gives the axis speed: (``position`` [m] or ``speed`` [m/s], the chunk's values), or None."""
        if not self.pitches_m:
            return None
        for kind, name in (("position", f"{self._axis}_table_position"), ("speed", "feed_speed")):
            if name in arrays:
                return kind, np.asarray(arrays[name], dtype=float)
        return None

    def _drive_bands(self, state: dict, drive, upto: int, omega: float) -> list[tuple[float, float]]:
        """:func:`drive_lines` for the spectrum window that ends at the chunk's sample ``upto - 1``."""
        if drive is None:
            return []
        fs = state["fs"]
        length = self.spectrum_samples(fs)
        kind, values = drive
        past = state["drive"].last("drive", length + 1) if "drive" in state else np.zeros(0)
        x = np.concatenate([past, values[:upto]])[-(length + 1):]
        parts = np.array_split(np.arange(x.size), 4)
        if kind == "position":       # the mean speed over each quarter of the window
            speeds = np.array([(x[p[-1]] - x[p[0]]) * fs / max(p[-1] - p[0], 1) for p in parts if p.size > 1])
        else:
            speeds = np.array([x[p].mean() for p in parts if p.size])
        tooth_hz = None if self.teeth is None else self.teeth * omega / _TWO_PI
        return drive_lines(speeds, self.pitches_m, tooth_hz, 3.0 * fs / length)
