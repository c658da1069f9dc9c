"""The breakage detector's compiled loop: a revolution's harmonics and angle bins, the baseline, the statistic.

:class:`~drivesense.events.breakage.BreakageDetector` holds the parameters and
names the events; :func:`breakage_loop` runs the samples of a chunk through the
state (a vector of scalar slots, rings of one revolution, the harmonics, the
angle bins and the baseline snapshots), as the detector's docstring describes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["breakage_loop", "BINS_PER_TOOTH", "N_SLOTS", "CUTTING"]

_TWO_PI = 2.0 * math.pi


#: Bins of a revolution per tooth for the per-tooth force shares.
BINS_PER_TOOTH = 8
# scalar state slots
(_THETA, _NEXT_REV, _REVS, _MEAN, _M2, _NSTAT, _THR, _PERSIST, _LATCH, CUTTING, _HEAD, _COUNT,
 _DROP, _GATEOFF, _LHEAD, _DRIFT, _DEARLY, _THOFF, _PEND, _PEND_TH, _PEND_I) = range(21)
N_SLOTS = 21


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
def breakage_loop(force, raw, omega, feed_ok, moving, fs, teeth, nk, gate, w_min, baseline_revs, d_floor, sigmas,
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
        elif sc[CUTTING] != 0.0 and sc[_GATEOFF] * dth < _TWO_PI:
            # the force has just fallen: keep the cut's state one revolution (a broken tool, not yet air)
            sc[_GATEOFF] += 1.0
            continue
        if feed_ok[i] < 0.5 and sc[CUTTING] != 0.0 and sc[_REVS] >= 0.0 and cutting:
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
            if sc[CUTTING] != 0.0:
                sc[CUTTING] = 0.0
                sc[_REVS] = 0.0
                sc[_NSTAT] = 0.0
                sc[_LATCH] = 0.0
                sc[_PERSIST] = 0.0
                sc[_DROP] = 0.0
            sc[_NEXT_REV] = th + _TWO_PI
            continue
        if sc[CUTTING] == 0.0:
            sc[CUTTING] = 1.0
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
