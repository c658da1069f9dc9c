"""How many teeth the tool has: ``--teeth``, the trace's tool, or the force's spindle-order spectrum.

The breakage and chipping detector needs the tooth count ``z``.  When neither
the user nor the trace's metadata gives it, :func:`infer_teeth` reads it from the
signals: a tool with ``z`` teeth loads the spindle ``z`` times a revolution, so
the force (the estimated one, a measured one, the feed drive's current, the
spindle's current or power) carries lines at the spindle orders ``z, 2z, 3z...``
(the tooth-passing frequency ``z n / 60`` and its harmonics).  Runout adds lines
at the other orders (``1``, ``z +- 1``...), weaker than the tooth-passing line.

The signal is resampled to the spindle angle (the integral of ``spindle_speed``,
so a varying speed keeps the orders in place) over the revolutions in the cut
(where the force's content that repeats every revolution stands clearly above
its level outside the cut), and averaged over blocks of
:data:`BLOCK_REVS` revolutions into order amplitudes ``A_1..A_K`` (``K``: the
highest order below the signal's Nyquist frequency or bandwidth).  Then:

1. the strongest line ``k*`` among the orders ``2..max_teeth`` is the
   tooth-passing line or one of its harmonics (the drive's response may lift a
   harmonic above it); a strongest line at the spindle frequency itself
   (order 1) means one tooth, or a runout that hides the count: refused;
2. sub-harmonic check: the smallest divisor ``d >= 2`` of ``k*`` whose line
   stands :data:`SUBHARMONIC_RATIO` times above every line that is not a
   multiple of ``d`` (runout's), at least :data:`SUBHARMONIC_SHARE` of ``k*``'s
   and :data:`LINE_TO_FLOOR` times the floor, is the tooth-passing line instead;
3. the answer ``z`` must stand :data:`LINE_TO_FLOOR` times above the noise
   floor between the orders, and be clear either in the spectrum (``A_z`` at
   least :data:`DOMINANCE` times every line that is not a multiple of ``z``) or
   in the pitch test: the revolution's repeating pattern (rebuilt from the
   orders' phasors), cut into ``z`` equal pitches, is one tooth shape at each
   tooth's own scale (:data:`PITCH_SHARE` of its energy, every tooth at least
   :data:`PITCH_BALANCE` of the largest, all of one sign).  A strong runout
   (a chip per tooth of a few micrometres against a runout of two) lifts the
   order-1 and side lines close to the tooth-passing one but leaves the
   pitches alike; a wrong count cuts pulses apart or leaves empty pitches;
4. every order up to ``max_teeth`` must be visible so that a larger tooth count
   is not missed -- or, for a band-limited estimate (a fast spindle), two
   orders beyond ``z`` with the pitch test passed.

The signals read: the forces (estimated, else the trace's own: a dynamometer),
else the spindle's power or current; beside them the feed drives' currents
(``{axis}_current``, whose band reaches higher than an estimate's), which
pass the force through the drive's response and can lift a runout line
above the tooth-passing one: their verdict counts only where a force shows
the same line clearly among the orders it resolves.  Each signal that can
judge gives a verdict; the answer needs at least one confident verdict and
no disagreement.  Otherwise the inference refuses (``teeth`` None) and says
why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage

from drivesense.recording import Recording

__all__ = ["TeethChoice", "infer_teeth", "known_teeth", "resolve_teeth", "TEETH_SOURCES"]

#: Where a tooth count came from (``TeethChoice.source``).
TEETH_SOURCES = ("--teeth", "tool metadata", "inferred from the spectrum", "unknown")

#: Revolutions per spectral block (the order resolution is 1 / BLOCK_REVS; half orders fall on the window's
#: nulls, where the floor is read).
BLOCK_REVS = 4
#: Least revolutions in the cut for a verdict.
MIN_REVS = 16
#: Most blocks read (the first ones of the cut).
MAX_BLOCKS = 256
#: A sub-harmonic is the tooth-passing line when it stands this many times above the lines of runout [-].
SUBHARMONIC_RATIO = 2.0
#: ... and at least this share of the strongest line [-].
SUBHARMONIC_SHARE = 0.1
#: The answer's line against the strongest line that is not one of its multiples [-].
DOMINANCE = 2.0
#: The answer's line against the noise floor between the orders (amplitude ratio) [-].
LINE_TO_FLOOR = 10.0
#: Pitch test: the share of a revolution's pattern one tooth shape at its own scale per pitch explains [-],
#: and the smallest tooth's scale against the largest's [-].
PITCH_SHARE = 0.75
PITCH_BALANCE = 0.05
#: Highest order read: twice the largest tooth count judged (its second harmonic) [-].
ORDERS_PER_TOOTH = 2


@dataclass(frozen=True)
class TeethChoice:
    """A tooth count and where it came from.

    Attributes
    ----------
    teeth : int or None
        The tooth count (None: not known, breakage and chipping are not looked for).
    source : str
        One of :data:`TEETH_SOURCES`.
    evidence : dict
        For an inferred count (or a refusal): the channel, the spindle and tooth-passing frequencies [Hz],
        the order amplitudes, the line's dominance and its height above the floor.
    reason : str or None
        Why the count is not known (None when it is).
    """

    teeth: int | None
    source: str
    evidence: dict = field(default_factory=dict)
    reason: str | None = None

    def to_json(self) -> dict:
        """``teeth``, ``teeth_source`` and ``teeth_evidence`` (with ``teeth_unknown``, the reason, when None).

        Returns
        -------
        dict
        """
        out = {"teeth": self.teeth, "teeth_source": self.source}
        if self.reason:
            out["teeth_unknown"] = self.reason
        if self.evidence:
            out["teeth_evidence"] = self.evidence
        return out

    @property
    def note(self) -> str | None:
        """One line for the user when breakage and chipping detection is off (None when it is on)."""
        if self.teeth is not None:
            return None
        return (f"breakage/chipping detection is off: the tool's number of teeth is unknown ({self.reason}); "
                f"--teeth N turns it on")


@dataclass(frozen=True)
class _Orders:
    """Order amplitudes of one channel over the cut."""

    channel: str
    amps: np.ndarray          # A_1..A_K
    phasors: np.ndarray       # H_1..H_K: the pattern of a revolution is Re(sum H_k exp(i k theta))
    floor: float              # RMS amplitude between the orders
    revs: float               # revolutions used
    spindle_hz: float         # mean spindle frequency over them [Hz]


def _angle(omega: np.ndarray, fs: float) -> np.ndarray:
    """Spindle angle [rad] per sample from the speed [rad/s] (trapezoidal integral, from 0)."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / fs)])


def cut_mask(x: np.ndarray, rev_samples: float) -> np.ndarray:
    """Samples where a signal's content at the spindle orders stands clearly above its quiet level.

    The signal less its mean over a revolution, its RMS over :data:`BLOCK_REVS` revolutions, against
    0.3 of its 95th percentile (and 3 times its 5th); gaps shorter than a block are closed.

    Parameters
    ----------
    x : ndarray
        The signal [any unit].
    rev_samples : float
        Samples per spindle revolution [-].

    Returns
    -------
    ndarray of bool
    """
    w = max(int(round(rev_samples)), 2)
    ac = x - scipy.ndimage.uniform_filter1d(x, w, mode="nearest")
    rms = np.sqrt(scipy.ndimage.uniform_filter1d(ac ** 2, BLOCK_REVS * w, mode="nearest"))
    hi, lo = np.percentile(rms, 95), np.percentile(rms, 5)
    if not hi > 0:
        return np.zeros(x.size, dtype=bool)
    mask = rms > max(0.3 * hi, 3.0 * lo)
    return scipy.ndimage.binary_closing(mask, np.ones(BLOCK_REVS * w, dtype=bool)) | mask


def _orders(name: str, x: np.ndarray, theta: np.ndarray, omega: np.ndarray, fs: float, top_hz: float,
            mask: np.ndarray | None = None) -> _Orders | str:
    """Order amplitudes of ``x`` over its cut (``mask``, default its own), or why they cannot be read.

    Each block of :data:`BLOCK_REVS` revolutions inside the cut is resampled to the spindle angle and
    Hann-windowed; the amplitudes are the median over the blocks (an event in a minority of them, a
    breakage late in the cut, does not change them)."""
    w_med = float(np.median(omega[omega > 0])) if np.any(omega > 0) else 0.0
    if not w_med > 0:
        return "the spindle does not turn"
    rev = 2 * math.pi / w_med * fs
    mask = (cut_mask(x, rev) if mask is None else mask) & (omega > 0.5 * w_med)
    per_rev = int(2 ** math.ceil(math.log2(max(64.0, rev))))       # angle samples per revolution
    block = BLOCK_REVS * per_rev
    window = np.hanning(block)
    k_all = np.arange(1, per_rev // 2)
    lines, gaps, phasors, w_max, speeds = [], [], [], 0.0, []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        th = theta[a:b]
        n_blocks = min(int((th[-1] - th[0]) / (2 * math.pi) // BLOCK_REVS) if b - a > 1 else 0,
                       MAX_BLOCKS - len(lines))
        if n_blocks < 1:
            continue
        grid = th[0] + (2 * math.pi / per_rev) * np.arange(n_blocks * block)
        y = np.interp(grid, th, x[a:b]).reshape(n_blocks, block)
        spec = np.fft.rfft((y - y.mean(axis=1, keepdims=True)) * window, axis=1)
        lines += list(np.abs(spec[:, BLOCK_REVS * k_all]) ** 2)
        gaps += list(np.abs(spec[:, BLOCK_REVS * k_all + BLOCK_REVS // 2]) ** 2)
        phasors += list(spec[:, BLOCK_REVS * k_all] * np.exp(-1j * k_all * th[0]))   # from the angle's zero
        end = min(b, a + int(np.searchsorted(th, grid[-1])) + 1)
        w_max = max(w_max, float(np.max(omega[a:end])))
        speeds.append(float(np.median(omega[a:end])))
    if len(lines) * BLOCK_REVS < MIN_REVS:
        return (f"{len(lines) * BLOCK_REVS} revolution(s) of cutting found in {name}, at least {MIN_REVS} are "
                f"needed")
    spindle_hz = w_max / (2 * math.pi)
    k_top = min(int(min(top_hz, 0.45 * fs) / spindle_hz), k_all.size)
    if k_top < 1:
        return f"the spindle frequency {spindle_hz:.4g} Hz is above what {name} resolves"
    scale = 2.0 / window.sum()
    amps = np.sqrt(np.median(np.array(lines)[:, :k_top], axis=0)) * scale
    ph = np.array(phasors)[:, :k_top]
    ph = (np.median(ph.real, axis=0) + 1j * np.median(ph.imag, axis=0)) * scale
    floor = math.sqrt(float(np.median(np.mean(np.array(gaps)[:, :k_top], axis=1)))) * scale
    return _Orders(name, amps, ph, floor, float(len(lines) * BLOCK_REVS), float(np.median(speeds)) / (2 * math.pi))


#: Samples of a revolution's pattern (divisible by every tooth count up to 8).
PATTERN_SAMPLES = 840


def _pattern(o: _Orders) -> np.ndarray:
    """A revolution of the signal's repeating part (its orders 1..K), :data:`PATTERN_SAMPLES` angles."""
    theta = 2 * math.pi * np.arange(PATTERN_SAMPLES) / PATTERN_SAMPLES
    k = np.arange(1, o.phasors.size + 1)
    return np.real(np.exp(1j * np.outer(theta, k)) @ o.phasors)


def _pitch_test(pattern: np.ndarray, z: int) -> tuple[float, float]:
    """Does the revolution split into ``z`` equal pitches of one shape, each tooth at its own scale?

    The pattern cut into ``z`` sectors (the cut placed where the split fits best): the share of their
    energy one common shape explains (rank one, every sector with the same sign), and the smallest
    sector's scale against the largest's.  Runout scales the teeth; a wrong count gives sectors of
    different shapes (a multiple of the true count: pulse and gap; another count: shifted pulses)."""
    n = pattern.size // z
    best = (0.0, 0.0)
    for off in range(0, n, max(1, n // 24)):
        m = np.roll(pattern, -off)[:z * n].reshape(z, n)
        m = m - m.mean(axis=1, keepdims=True)
        u, sv, _ = np.linalg.svd(m, full_matrices=False)
        scales = u[:, 0] * sv[0]
        if not (np.all(scales > 0) or np.all(scales < 0)):
            continue
        share = float(sv[0] ** 2 / max(np.sum(sv ** 2), 1e-300))
        if share > best[0]:
            best = (share, float(np.min(np.abs(scales)) / np.max(np.abs(scales))))
    return best


def _verdict(o: _Orders, max_teeth: int) -> tuple[int | None, dict, str | None]:
    """Tooth count from one channel's orders: (z or None, evidence, reason when None).  See the module."""
    a = o.amps
    k_top = a.size
    ev = {"channel": o.channel, "spindle_hz": round(o.spindle_hz, 3), "revolutions": round(o.revs, 1),
          "order_amplitudes": [float(f"{v:.4g}") for v in a[:ORDERS_PER_TOOTH * max_teeth]],
          "floor": float(f"{o.floor:.3g}")}
    short = (f"{o.channel} shows the spindle orders up to {k_top} only, {max_teeth} are needed (a faster "
             f"trace, or a slower spindle)")
    if k_top < 3:
        return None, ev, short

    def others(d: int) -> float:
        rest = [a[k - 1] for k in range(1, k_top + 1) if k % d]
        return max(rest) if rest else 0.0

    k_star = int(np.argmax(a[1:max_teeth])) + 2
    z = next((d for d in range(2, k_star) if k_star % d == 0 and a[d - 1] >= SUBHARMONIC_RATIO * others(d)
              and a[d - 1] >= SUBHARMONIC_SHARE * a[k_star - 1] and a[d - 1] >= LINE_TO_FLOOR * o.floor), k_star)
    dominance = a[z - 1] / max(others(z), 1e-300)
    above_floor = a[z - 1] / max(o.floor, 1e-300)
    share, balance = _pitch_test(_pattern(o), z)
    pitch = share >= PITCH_SHARE and balance >= PITCH_BALANCE
    ev.update({"teeth": z, "strongest_order": k_star, "tooth_passing_hz": round(z * o.spindle_hz, 2),
               "line": float(f"{a[z - 1]:.4g}"), "dominance": round(float(dominance), 2),
               "line_to_floor": round(float(above_floor), 1), "pitch_share": round(share, 3),
               "pitch_balance": round(balance, 3)})
    if a[0] >= a[k_star - 1]:
        return None, ev, (f"the strongest line of {o.channel} is the spindle frequency itself (one tooth, or "
                          f"runout hides the count)")
    if above_floor < LINE_TO_FLOOR:
        return None, ev, (f"no clear tooth-passing line in {o.channel}: the order-{z} line is {above_floor:.1f}x "
                          f"the noise between the orders, {LINE_TO_FLOOR:g}x is needed")
    if k_top < max_teeth and not (pitch and k_top >= z + 2):
        return None, ev, short
    if not (pitch or dominance >= DOMINANCE):
        return None, ev, (f"no clear tooth-passing line in {o.channel}: the order-{z} line is {dominance:.2f}x the "
                          f"strongest other one ({DOMINANCE:g}x is needed) and {z} equal pitches explain "
                          f"{100 * share:.0f} % of a revolution's pattern ({100 * PITCH_SHARE:.0f} % is needed)")
    return z, ev, None


def _channels(trace: Recording, forces: Recording | None,
              band_hz: float | None) -> list[tuple[str, np.ndarray, float, bool]]:
    """(name, samples, highest frequency to read [Hz], primary) of every signal that carries the line.

    Primary: the forces (estimated, else the trace's own), else the spindle's power or current.  The
    others (the feed drives' currents, and the spindle's beside a force) pass the force through a drive's
    response, which can lift a runout line above the tooth-passing one: they only count where a primary
    signal shows the same line."""
    out = []
    if forces is not None:
        top = math.inf if band_hz is None else float(band_hz)
        out += [(c, forces[c], top) for c in forces.channels if c.startswith("force_")]
    else:
        out += [(c, trace[c], math.inf) for c in trace.channels if c.startswith("force_")]
    spindle = [(c, trace[c], math.inf) for c in ("spindle_power", "spindle_current") if c in trace.channels]
    drives = [(c, trace[c], math.inf) for c in sorted(trace.channels) if c.endswith("_current") and
              not c.startswith("spindle")]
    primary = out or spindle
    return ([(c, np.asarray(x, dtype=float), top, True) for c, x, top in primary]
            + [(c, np.asarray(x, dtype=float), top, False) for c, x, top in (spindle if out else []) + drives])


def _confirms(o: _Orders, z: int) -> bool:
    """Does a primary signal show the order-``z`` line clearly among the orders it resolves?"""
    a = o.amps
    if a.size < z:
        return False
    rest = [a[k - 1] for k in range(1, a.size + 1) if k % z]
    return a[z - 1] >= DOMINANCE * max(rest, default=0.0) and a[z - 1] >= LINE_TO_FLOOR * o.floor


def infer_teeth(trace: Recording, forces: Recording | None = None, *, spindle_rpm: float | None = None,
                band_hz: float | None = None, max_teeth: int = 8) -> TeethChoice:
    """The tool's number of teeth from the tooth-passing line of the force's spindle-order spectrum.

    See the module docstring for the rule.  Refuses (``teeth`` None, with the reason) rather than guesses:
    without a spindle speed, a clear line, ``max_teeth`` visible orders or :data:`MIN_REVS` revolutions of
    cutting, when two signals name different counts, or when only a drive's current names one (a feed
    drive's response can lift a runout line above the tooth-passing one: a force, or the spindle's power
    or current, must show the same line).

    Parameters
    ----------
    trace : Recording
        The drive-signal trace: ``spindle_speed`` [rad/s], and whichever of ``force_*`` [N] (when `forces`
        is not given), ``spindle_power`` [W], ``spindle_current`` [A], ``{axis}_current`` [A] it has.
    forces : Recording, optional
        Estimated forces (``force_*`` [N]) on the trace's time base; they are read first and mark the cut.
    spindle_rpm : float, optional
        Fixed spindle speed [min^-1] when the trace has no ``spindle_speed``.
    band_hz : float, optional
        Bandwidth of the estimated forces [Hz]: their lines are read below it.
    max_teeth : int
        Largest tooth count considered (every order up to it must be visible) [-].

    Returns
    -------
    TeethChoice
        ``source`` "inferred from the spectrum"; the evidence names the channel, the spindle and
        tooth-passing frequencies [Hz], the order amplitudes [channel unit], the line's dominance over the
        strongest other order and its height above the noise between the orders, and each channel's verdict.
    """
    source = TEETH_SOURCES[2]
    if "spindle_speed" in trace.channels:
        omega = np.asarray(trace["spindle_speed"], dtype=float)
    elif forces is not None and "spindle_speed" in forces.channels:
        omega = np.asarray(forces["spindle_speed"], dtype=float)
    elif spindle_rpm is not None and spindle_rpm > 0:
        omega = np.full(trace.n_samples, float(spindle_rpm) * 2 * math.pi / 60.0)
    else:
        return TeethChoice(None, source, reason="no spindle speed (no spindle_speed channel, no --spindle-rpm)")
    chans = _channels(trace, forces, band_hz)
    if not any(primary for *_, primary in chans):
        return TeethChoice(None, source, reason="the trace has no force, spindle power or spindle current (a "
                                                "feed drive's current alone does not tell the tooth count)")
    if trace.n_samples < 2 or not np.all(np.isfinite(omega)):
        return TeethChoice(None, source, reason="the spindle speed is not usable")
    theta = _angle(omega, trace.fs)
    w_med = float(np.median(omega[omega > 0])) if np.any(omega > 0) else 0.0
    cut = cut_mask(chans[0][1], 2 * math.pi / w_med * trace.fs) if w_med > 0 else None
    verdicts: dict[str, int | str] = {}
    primaries, found, reasons = [], [], []
    for name, x, top, primary in chans:
        o = _orders(name, x, theta, omega, trace.fs, top, cut) if np.all(np.isfinite(x)) else "non-finite samples"
        z, ev, why = (None, {}, o) if isinstance(o, str) else _verdict(o, max_teeth)
        if primary and not isinstance(o, str):
            primaries.append(o)
        if z is not None and not primary and not any(_confirms(p, z) for p in primaries):
            z, why = None, f"{name}'s order-{z} line is not seen in the force"
        verdicts[name] = z if z is not None else why
        if z is None:
            reasons.append(why)
        else:
            found.append((z, ev))
    counts = sorted({z for z, _ in found})
    if not counts:
        return TeethChoice(None, source, {"channels": verdicts}, reasons[0] if reasons else "no usable signal")
    if len(counts) > 1:
        said = ", ".join(f"{name} {v}" for name, v in verdicts.items() if isinstance(v, int))
        return TeethChoice(None, source, {"channels": verdicts},
                           f"the signals name different tooth counts ({said})")
    best = max((ev for _, ev in found), key=lambda ev: ev["dominance"])
    return TeethChoice(counts[0], source, {**best, "channels": verdicts})


def known_teeth(trace: Recording, teeth: int | None = None) -> TeethChoice | None:
    """The tooth count someone stated: ``teeth`` (``--teeth``), else the trace's tool; None when neither says.

    Parameters
    ----------
    trace : Recording
        The trace (``meta["tool"]["flutes"]`` when its metadata names the tool).
    teeth : int, optional
        Given by the user (``--teeth``).

    Returns
    -------
    TeethChoice or None
    """
    if teeth is not None:
        return TeethChoice(int(teeth), TEETH_SOURCES[0])
    tool = trace.meta.get("tool") if isinstance(trace.meta.get("tool"), dict) else None
    if tool and isinstance(tool.get("flutes"), int) and not isinstance(tool["flutes"], bool) and tool["flutes"] >= 1:
        return TeethChoice(int(tool["flutes"]), TEETH_SOURCES[1])
    return None


def resolve_teeth(trace: Recording, teeth: int | None = None, *, forces: Recording | None = None,
                  spindle_rpm: float | None = None, band_hz: float | None = None) -> TeethChoice:
    """The tooth count the detectors use: ``teeth`` (``--teeth``), else the trace's tool, else inferred.

    Parameters
    ----------
    trace : Recording
        The trace (``meta["tool"]["flutes"]`` when its metadata names the tool).
    teeth : int, optional
        Given by the user (``--teeth``).
    forces, spindle_rpm, band_hz
        As in :func:`infer_teeth`.

    Returns
    -------
    TeethChoice
    """
    known = known_teeth(trace, teeth)
    return known if known is not None else infer_teeth(trace, forces, spindle_rpm=spindle_rpm, band_hz=band_hz)
