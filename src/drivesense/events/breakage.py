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
from numba import njit

from drivesense.dsp import median_of, sosfilt_with_state
from drivesense.errors import SignalTooShortError
from drivesense.machine.milling import check_int, check_number
from drivesense.events.detector import Detector, spindle_speed_of
from drivesense.events.edge_loss import fit_edge_loss, pattern_bins, warm_edge_loss
from drivesense.events.nc_guard import guard_source, process_steady

__all__ = ["BreakageDetector"]

_TWO_PI = 2.0 * math.pi


_BINS_PER_TOOTH = 8
# scalar state slots
(_THETA, _NEXT_REV, _REVS, _MEAN, _M2, _NSTAT, _THR, _PERSIST, _LATCH, _CUTTING, _HEAD, _COUNT,
 _DROP, _GATEOFF, _LHEAD, _DRIFT, _DEARLY, _THOFF, _PEND, _PEND_TH, _PEND_I) = range(21)
_N_SLOTS = 21


@njit(cache=True, nogil=True)
def _accumulate(harm, weight, theta):  # pragma: no cover - numba
    """``harm[k] += weight * exp(-i (k + 1) theta)`` for every k, by powers of one phasor."""
    z = complex(math.cos(theta), -math.sin(theta))
    p = z
    for k in range(harm.size):
        harm[k] += weight * p
        p *= z


@njit(cache=True, nogil=True)
def _sector(theta, nb):  # pragma: no cover - numba
    """Bin of the spindle angle ``theta`` [rad] among ``nb`` equal sectors of a revolution."""
    return int((theta % _TWO_PI) / _TWO_PI * nb) % nb


@njit(cache=True, nogil=True)
def _window_pattern(sc, ring_s, ring_t, out):  # pragma: no cover - numba
    """Sum of the raw force and count of samples per angle bin over the window (one revolution) into ``out``."""
    cap = ring_s.size
    nbm = out.shape[1]
    out[:, :] = 0.0
    for j in range(int(sc[_COUNT])):
        idx = int(sc[_HEAD] - sc[_COUNT] + j) % cap
        b = _sector(ring_t[idx] + sc[_THOFF], nbm)
        out[0, b] += ring_s[idx]
        out[1, b] += 1.0


@njit(cache=True, nogil=True)
def _emit_pending(sc, start, n_ev, pend_data, pend_base, ring_s, ring_t, ev_index, ev_data, ev_pat, named, i):  # pragma: no cover
    """The pending event out, with the baseline's pattern and (``named``) the revolution since the detection."""
    if n_ev >= ev_index.size:
        return n_ev
    ev_index[n_ev] = int(sc[_PEND_I] - start)
    for q in range(5):
        ev_data[n_ev, q] = pend_data[q]
    ev_data[n_ev, 5] = 1.0 if named else 0.0
    ev_data[n_ev, 6] = i - (sc[_PEND_I] - start)
    ev_pat[n_ev, 0:2, :] = pend_base
    if named:
        _window_pattern(sc, ring_s, ring_t, ev_pat[n_ev, 2:4, :])
    sc[_PEND] = 0.0
    return n_ev + 1


@njit(cache=True, nogil=True)
def _rebase(sc, ring_v, ring_r, ring_t, harm, bins):  # pragma: no cover - numba
    """A cut begins: count the angle from here (the window's angles moved with it, its sums taken afresh).

    Everything the cut learns then depends on the signal since about a revolution before the cut, not on
    how long the stream has run: a monitor that takes the machine over and replays the signal from
    before the cut reaches the same state, and the same events (the running sums' rounding and the
    revolution boundaries no longer carry the stream's whole history).  ``_THOFF`` keeps the angle at
    which the count restarted, so the per-tooth sectors stay on the spindle's own angle.
    """
    cap = ring_v.size
    theta0 = sc[_THETA]
    sc[_THOFF] += theta0
    sc[_THETA] = 0.0
    harm[:] = 0.0
    bins[:] = 0.0
    nb = bins.size
    for j in range(int(sc[_COUNT])):
        idx = int(sc[_HEAD] - sc[_COUNT] + j) % cap
        ring_t[idx] -= theta0
        _accumulate(harm, ring_v[idx] / math.pi, ring_t[idx])
        bins[_sector(ring_t[idx] + sc[_THOFF], nb)] += ring_r[idx]


@njit(cache=True, nogil=True)
def _breakage_loop(force, raw, omega, feed_ok, moving, fs, teeth, nk, gate, w_min, baseline_revs, d_floor, sigmas,
                   persist_n, level_drop, alpha, step_ratio, min_shift, sc, levels, ring_v, ring_r, ring_t, harm,
                   heff, bins, ema_h, ema_b, snap_h, snap_b, stat, thr_out, ev_index, ev_data, ring_s, pat, pat_ema,
                   pat_snap, pend_data, pend_base, ev_pat, start):  # pragma: no cover - numba
    n = force.size
    cap = ring_v.size
    nb = bins.size
    n_ev = 0
    for i in range(n):
        w = omega[i]
        dth = w / fs
        th = sc[_THETA] + dth
        sc[_THETA] = th
        v = force[i] * dth
        # add the sample to the window (harmonics of the high-passed force; bins of the force itself, for
        # the per-tooth shares)
        if sc[_COUNT] >= cap:          # slower than min_rpm: drop the oldest sample
            tail = int(sc[_HEAD] - sc[_COUNT]) % cap
            tv = ring_v[tail]
            tt = ring_t[tail]
            _accumulate(harm, -tv / math.pi, tt)
            bins[_sector(tt + sc[_THOFF], nb)] -= ring_r[tail]
            sc[_COUNT] -= 1
        head = int(sc[_HEAD]) % cap
        ring_v[head] = v
        ring_r[head] = abs(raw[i]) * dth
        ring_t[head] = th
        ring_s[head] = raw[i]
        sc[_HEAD] = (sc[_HEAD] + 1) % cap
        sc[_COUNT] += 1
        _accumulate(harm, v / math.pi, th)
        bins[_sector(th + sc[_THOFF], nb)] += abs(raw[i]) * dth
        # drop what is older than one revolution
        while sc[_COUNT] > 0:
            tail = int(sc[_HEAD] - sc[_COUNT]) % cap
            tt = ring_t[tail]
            if th - tt < _TWO_PI:
                break
            _accumulate(harm, -ring_v[tail] / math.pi, tt)
            bins[_sector(tt + sc[_THOFF], nb)] -= ring_r[tail]
            sc[_COUNT] -= 1
        if sc[_PEND] != 0.0 and th - sc[_PEND_TH] >= _TWO_PI:
            # a whole revolution since the detection: the event is named from it (edge_loss.py)
            n_ev = _emit_pending(sc, start, n_ev, pend_data, pend_base, ring_s, ring_t, ev_index, ev_data, ev_pat,
                                 True, i)
        # the window covers exactly one revolution: the oldest sample counts for the part of its angle
        # step inside it (else the window's edge leaks the pattern into every harmonic)
        for k in range(nk):
            heff[k] = harm[k]
        if sc[_COUNT] > 0:
            tail = int(sc[_HEAD] - sc[_COUNT]) % cap
            tt = ring_t[tail]
            tv = ring_v[tail]
            step = dth if dth > 0.0 else 1.0
            outside = 1.0 - (tt - (th - _TWO_PI)) / step
            if outside > 0.0:
                _accumulate(heff, -outside * tv / math.pi, tt)
        ht = 0.0
        for k in range(nk):
            if (k + 1) % teeth == 0:
                ht += heff[k].real ** 2 + heff[k].imag ** 2
        ht = math.sqrt(ht)
        stat[i] = np.nan
        thr_out[i] = np.nan
        armed = sc[_REVS] >= baseline_revs
        # a sudden loss of (nearly) all cutting while the feed goes on: a broken tool (one flute) --
        # checked before the cutting gate, which that loss closes
        if armed and sc[_LATCH] == 0.0 and moving[i] > 0.5 and sc[_DRIFT] <= 0.1:
            bt = 0.0
            for k in range(nk):
                if (k + 1) % teeth == 0:
                    bt += snap_h[2, k].real ** 2 + snap_h[2, k].imag ** 2
            bt = math.sqrt(bt)
            if bt > 0.0 and ht < level_drop * bt:
                sc[_DROP] += 1.0
                if sc[_DROP] >= persist_n and n_ev < ev_index.size:
                    ev_index[n_ev] = i
                    ev_data[n_ev, 0] = 1.0 - ht / bt
                    ev_data[n_ev, 1] = ht / bt
                    ev_data[n_ev, 2] = level_drop
                    ev_data[n_ev, 3] = -1.0
                    ev_data[n_ev, 4] = 1.0
                    n_ev += 1
                    sc[_LATCH] = 1.0
            else:
                sc[_DROP] = 0.0
        cutting = ht > gate and w > w_min
        if cutting:
            sc[_GATEOFF] = 0.0
        elif sc[_CUTTING] != 0.0 and sc[_GATEOFF] * dth < _TWO_PI:
            # the force has just fallen: keep the cut's state one revolution (a broken tool, not yet air)
            sc[_GATEOFF] += 1.0
            continue
        if feed_ok[i] < 0.5 and sc[_CUTTING] != 0.0 and sc[_REVS] >= 0.0 and cutting:
            # the feed changes: the pattern changes with it (a feed override); learn it afresh
            if sc[_PEND] != 0.0:
                n_ev = _emit_pending(sc, start, n_ev, pend_data, pend_base, ring_s, ring_t, ev_index, ev_data,
                                     ev_pat, False, i)
            sc[_REVS] = -1.0
            sc[_NSTAT] = 0.0
            sc[_PERSIST] = 0.0
            sc[_DROP] = 0.0
        if not cutting:
            if sc[_PEND] != 0.0:
                n_ev = _emit_pending(sc, start, n_ev, pend_data, pend_base, ring_s, ring_t, ev_index, ev_data,
                                     ev_pat, False, i)
            if sc[_CUTTING] != 0.0:
                sc[_CUTTING] = 0.0
                sc[_REVS] = 0.0
                sc[_NSTAT] = 0.0
                sc[_LATCH] = 0.0
                sc[_PERSIST] = 0.0
                sc[_DROP] = 0.0
            sc[_NEXT_REV] = th + _TWO_PI
            continue
        if sc[_CUTTING] == 0.0:
            sc[_CUTTING] = 1.0
            _rebase(sc, ring_v, ring_r, ring_t, harm, bins)
            sc[_NEXT_REV] = _TWO_PI
            sc[_REVS] = -1.0                     # the window still holds air: learn from the next revolution
            continue
        if th >= sc[_NEXT_REV]:
            sc[_NEXT_REV] += _TWO_PI
            sc[_REVS] += 1.0
            # the tooth-pass level once per revolution: a level that drifted by > 10 % between 8 and 3
            # revolutions back is an entry or an exit, where the pattern changes without an event
            lk = int(sc[_LHEAD]) % levels.size
            levels[lk] = ht
            sc[_LHEAD] = lk + 1
            if sc[_REVS] >= 8.0:
                recent = levels[(lk - 3) % levels.size]
                old = levels[(lk - 8) % levels.size]
                sc[_DRIFT] = abs(recent / old - 1.0) if old > 0.0 else 1.0
            else:
                sc[_DRIFT] = 0.0
            if sc[_REVS] == baseline_revs and sc[_LATCH] == 0.0:
                # armed: the statistic's mean and spread over the last baseline revolution (the most settled
                # one; the first revolutions of a cut still change), then followed as the cut goes on
                sc[_M2] = sc[_M2] / max(sc[_NSTAT] - 1.0, 1.0)      # from here on: the variance itself
                sc[_THR] = max(d_floor, sc[_MEAN] + sigmas * math.sqrt(sc[_M2]))
            elif sc[_REVS] < baseline_revs:
                sc[_NSTAT] = 0.0
            _window_pattern(sc, ring_s, ring_t, pat)
            if sc[_REVS] <= 0.0:
                for k in range(nk):
                    ema_h[k] = heff[k]
                for b in range(nb):
                    ema_b[b] = bins[b]
                pat_ema[:, :] = pat
            elif sc[_LATCH] == 0.0:
                for k in range(nk):
                    ema_h[k] += alpha * (heff[k] - ema_h[k])
                for b in range(nb):
                    ema_b[b] += alpha * (bins[b] - ema_b[b])
                pat_ema[:, :] += alpha * (pat - pat_ema)
            for q in range(pat_snap.shape[0] - 1, 0, -1):
                pat_snap[q] = pat_ema if sc[_REVS] <= 0.0 else pat_snap[q - 1]
            pat_snap[0] = pat_ema
            depth = snap_h.shape[0]
            for k in range(nk):
                for q in range(depth - 1, 0, -1):
                    snap_h[q, k] = ema_h[k] if sc[_REVS] <= 0.0 else snap_h[q - 1, k]
                snap_h[0, k] = ema_h[k]
            for b in range(nb):
                for q in range(depth - 1, 0, -1):
                    snap_b[q, b] = ema_b[b] if sc[_REVS] <= 0.0 else snap_b[q - 1, b]
                snap_b[0, b] = ema_b[b]
            # how much the pattern changed between 5 and 2 revolutions back: a breakage is a step (nothing
            # before it), an entry or an exit a drift (as much before as now)
            et = 0.0
            lt = 0.0
            for k in range(nk):
                if (k + 1) % teeth == 0:
                    et += snap_h[2, k].real ** 2 + snap_h[2, k].imag ** 2
                    lt += snap_h[5, k].real ** 2 + snap_h[5, k].imag ** 2
            sc[_DEARLY] = 0.0
            if et > 0.0 and lt > 0.0:
                sc5 = math.sqrt(et / lt)
                ch = 0.0
                for k in range(nk):
                    if (k + 1) % teeth != 0:
                        ch += (snap_h[2, k].real - sc5 * snap_h[5, k].real) ** 2 \
                            + (snap_h[2, k].imag - sc5 * snap_h[5, k].imag) ** 2
                sc[_DEARLY] = math.sqrt(ch / et)
            if sc[_LATCH] != 0.0 and sc[_REVS] > baseline_revs + 2:
                # after an alarm: the new pattern is learnt afresh
                sc[_REVS] = 0.0
                sc[_NSTAT] = 0.0
                sc[_LATCH] = 0.0
        if sc[_REVS] < 1.0 or teeth < 2:
            continue
        bt = 0.0
        for k in range(nk):
            if (k + 1) % teeth == 0:
                bt += snap_h[2, k].real ** 2 + snap_h[2, k].imag ** 2
        bt = math.sqrt(bt)
        s_scale = ht / bt if bt > 0.0 else 1.0
        diff = 0.0
        for k in range(nk):
            if (k + 1) % teeth != 0:
                dr = heff[k].real - s_scale * snap_h[2, k].real
                di = heff[k].imag - s_scale * snap_h[2, k].imag
                diff += dr * dr + di * di
        d = math.sqrt(diff) / ht
        stat[i] = d
        if not armed:
            if sc[_REVS] >= 1.0:                 # the statistic's spread in this baseline revolution
                sc[_NSTAT] += 1.0
                delta = d - sc[_MEAN] if sc[_NSTAT] > 1.0 else 0.0
                if sc[_NSTAT] == 1.0:
                    sc[_MEAN] = d
                    sc[_M2] = 0.0
                else:
                    sc[_MEAN] += delta / sc[_NSTAT]
                    sc[_M2] += delta * (d - sc[_MEAN])
            continue
        thr_out[i] = sc[_THR]
        if sc[_LATCH] != 0.0:
            continue
        if d > sc[_THR] and sc[_DRIFT] <= 0.1 and d > step_ratio * sc[_DEARLY]:
            sc[_PERSIST] += 1.0
        else:
            sc[_PERSIST] = 0.0
        if d <= sc[_THR]:
            # the statistic's level follows slow changes of the cut (entry, exit, wear): a running mean and
            # variance over about 10 revolutions, from samples below the threshold only
            a_s = dth / (10.0 * _TWO_PI)
            delta = d - sc[_MEAN]
            sc[_MEAN] += a_s * delta
            sc[_M2] = (1.0 - a_s) * (sc[_M2] + a_s * delta * delta)
            sc[_THR] = max(d_floor, sc[_MEAN] + sigmas * math.sqrt(sc[_M2]))
        if sc[_PERSIST] >= persist_n and n_ev < ev_index.size:
            # which tooth lost how much: the revolution cut into one sector per tooth, at every rotation of
            # the partition; a damaged tooth moves work from its sector to the next one at some rotation,
            # a change every tooth shares (the part's edge notching every pulse) moves none at any
            worst = 0.0
            worst_j = 0
            shift_o = 0
            shift = 0.0
            tot_now = 0.0
            tot_base = 0.0
            for b in range(nb):
                tot_now += bins[b]
                tot_base += snap_b[2, b]
            per = nb // teeth
            for o in range(per):
                o_shift = 0.0
                o_worst = 0.0
                o_j = 0
                for j in range(teeth):
                    now = 0.0
                    base = 0.0
                    for q in range(per):
                        b = (o + j * per + q) % nb
                        now += bins[b]
                        base += snap_b[2, b]
                    if base > 0.0 and tot_now > 0.0 and tot_base > 0.0:
                        moved = abs(now / tot_now - base / tot_base)
                        loss = 1.0 - (now / tot_now) / (base / tot_base)
                        if moved > o_shift:
                            o_shift = moved
                        if loss > o_worst:
                            o_worst = loss
                            o_j = j
                if o_shift > shift:
                    shift = o_shift
                    worst = o_worst
                    worst_j = o_j
                    shift_o = o
            if shift < min_shift:
                # every tooth kept its share of the work: the pattern changed for all teeth alike (the tool
                # leaving the part notches every pulse), which no damaged tooth does
                sc[_PERSIST] = 0.0
                continue
            # named one revolution later, from the whole revolution after the detection (the sector shares
            # above are the fallback when the cut ends before)
            pend_data[0] = min(worst, 1.0)
            pend_data[1] = d
            pend_data[2] = sc[_THR]
            pend_data[3] = ((shift_o + worst_j * per) % nb) * 360.0 / nb
            pend_data[4] = s_scale
            pend_base[:, :] = pat_snap[2]
            sc[_PEND] = 1.0
            sc[_PEND_TH] = th
            sc[_PEND_I] = start + i
            sc[_LATCH] = 1.0
            sc[_REVS] = baseline_revs        # count on from here; re-learn after baseline_revs + 2 more
    return n_ev


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
        """Three revolutions at the slowest expected spindle speed [s]: up to two to detect (typically one)
        and the whole revolution after the detection that names the event.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        rpm = self.spindle_rpm or self.min_rpm
        return 3 * 60.0 / rpm

    def new_state(self, fs: float) -> dict:
        """Ring of one revolution at ``min_rpm``, harmonics, bins, baselines (constant size).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        cap = int(math.ceil(fs * 60.0 / self.min_rpm)) + 2
        nk = 2 * self.teeth if self.teeth > 1 else 2
        nb = _BINS_PER_TOOTH * self.teeth
        nbm = pattern_bins(self.teeth)
        if self.teeth > 1:
            warm_edge_loss(nbm, self.teeth)      # the naming's grid, built now rather than at the first alarm
        return {"sc": np.zeros(_N_SLOTS), "levels": np.zeros(16), "ring_v": np.zeros(cap), "ring_r": np.zeros(cap),
                "ring_t": np.zeros(cap), "harm": np.zeros(nk, dtype=complex), "heff": np.zeros(nk, dtype=complex),
                "bins": np.zeros(nb), "ema_h": np.zeros(nk, dtype=complex), "ema_b": np.zeros(nb),
                "snap_h": np.zeros((6, nk), dtype=complex), "snap_b": np.zeros((6, nb)),
                "ring_s": np.zeros(cap), "pat": np.zeros((2, nbm)), "pat_ema": np.zeros((2, nbm)),
                "pat_snap": np.zeros((6, 2, nbm)), "pend_data": np.zeros(5), "pend_base": np.zeros((2, nbm)),
                "fs": float(fs), "armed_ever": False, "cut_seen": False}

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
        n_ev = _breakage_loop(force, raw, omega, feed_ok, moving, fs, self.teeth, state["harm"].size, self.gate_n,
                              self.min_rpm * _TWO_PI / 60.0, float(self.baseline_revs), self.threshold, self.sigmas,
                              persist, self.level_drop, self.alpha, self.step_ratio, self.min_shift, state["sc"],
                              state["levels"], state["ring_v"], state["ring_r"], state["ring_t"], state["harm"],
                              state["heff"], state["bins"], state["ema_h"], state["ema_b"], state["snap_h"],
                              state["snap_b"], stat, thr, ev_index, ev_data, state["ring_s"], state["pat"],
                              state["pat_ema"], state["pat_snap"], state["pend_data"], state["pend_base"], ev_pat,
                              float(start))
        state["armed_ever"] = state["armed_ever"] or bool(np.any(np.isfinite(thr)))
        state["cut_seen"] = state["cut_seen"] or bool(np.any(np.isfinite(stat))) or state["sc"][_CUTTING] > 0
        if state["sc"][_CUTTING] == 0.0:
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
            events.append((start + int(ev_index[e]), kind, confidence, evidence))
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
        if state["sc"][_CUTTING] == 0.0:
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
