"""The chatter detector's spectra: a line of its own between the spindle harmonics, and the drive's own lines.

:class:`~drivesense.events.chatter.ChatterDetector` confirms a candidate with
:func:`spectral_line` on the last fraction of a second of force, and leaves out
of both its statistic and that check the lines a position-periodic measuring
error of the drive puts into a force estimate (:func:`drive_lines`,
:func:`drive_share`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["drive_lines", "drive_share", "spectral_line"]

_TWO_PI = 2.0 * math.pi


def drive_lines(speeds: np.ndarray, pitches, tooth_hz: float | None, pad_hz: float) -> list[tuple[float, float]]:
    """Frequency bands [Hz] where the drive's position-periodic error puts lines: ``k |v| / p``.

    A measuring error that repeats every ``p`` of travel (the motor encoder's
    signal period) is a line at ``|v| / p`` and its second harmonic in the force
    estimate; the cut's tooth passes modulate it, so the lines one tooth-pass
    frequency to either side count too.  An override moves them through the
    chatter band.

    Parameters
    ----------
    speeds : ndarray
        The axis speeds over the spectrum's window (its parts) [m/s]; their range sets the bands' width.
    pitches : sequence of float
        The error's periods of travel [m].
    tooth_hz : float, optional
        Tooth-pass frequency [Hz] (None: the sidebands are not known).
    pad_hz : float
        Added to either side of every band [Hz] (the spectrum's resolution).
    """
    if not len(pitches) or speeds.size == 0:
        return []
    lo, hi = float(np.min(np.abs(speeds))), float(np.max(np.abs(speeds)))
    shifts = (0.0,) if not tooth_hz else (-tooth_hz, 0.0, tooth_hz)
    bands = []
    for p in pitches:
        for k in (1, 2):
            for m in shifts:
                a, b = k * lo / p + m, k * hi / p + m
                if b < 0.0:
                    a, b = -b, -a
                elif a < 0.0:
                    a, b = 0.0, max(-a, b)
                bands.append((a - pad_hz, b + pad_hz))
    return bands


def drive_share(fring: np.ndarray, head: int, fs: float, bands, length: int) -> float:
    """The share [-] of the comb output's power (its last ``length`` samples) that lies within ``bands`` [Hz].

    The drive's position-periodic lines (:func:`drive_lines`) pass the comb like chatter does; the
    statistic is judged without them.

    Parameters
    ----------
    fring : ndarray
        Ring of the band-passed comb output [N].
    head : int
        Index of the ring's next write (its last sample is ``head - 1``).
    fs : float
        Sample rate [Hz].
    bands : sequence of (float, float)
        Frequency bands [Hz].
    length : int
        Samples of the spectrum (<= the ring's size).
    """
    if not bands:
        return 0.0
    cap = fring.size
    x = fring[(head - length + np.arange(length)) % cap]
    power = np.abs(np.fft.rfft(x * np.hanning(length))) ** 2
    freq = np.fft.rfftfreq(length, 1.0 / fs)
    inside = np.zeros(freq.size, dtype=bool)
    for a, b in bands:
        inside |= (freq >= a) & (freq <= b)
    total = float(power.sum())
    return float(power[inside].sum() / total) if total > 0 else 0.0


def spectral_line(ring: np.ndarray, head: int, fs: float, omega: float, lowest_hz: float, highest_hz: float,
                    length: int, prominence: float, exclude=(), bands=(), near_hz: float | None = None,
                  tol_hz: float = 0.0) -> tuple[bool, float, float]:
    """Is there a narrow peak between the spindle harmonics?  (ok, its frequency [Hz], its prominence [-]).

    The last ``length`` force samples, Hann-windowed: the largest spectral line
    above ``lowest_hz`` that lies more than three bins (and 10 % of the rotation
    frequency) from every spindle harmonic, against the median of those lines.
    A drifting pattern (an exit, a feed ramp) leaves sidebands next to the
    harmonics; chatter is a line of its own.  Lines within 10 % of ``exclude``
    (the feed drive's own modes, which ring in the estimate after a force
    step) do not count, nor lines within ``bands`` (:func:`drive_lines`).

    Parameters
    ----------
    ring : ndarray
        Ring of the force [N].
    head : int
        Index of the ring's next write (its last sample is ``head - 1``).
    fs : float
        Sample rate [Hz].
    omega : float
        Spindle speed [rad/s].
    lowest_hz : float
        Lowest line that counts [Hz].
    highest_hz : float
        Highest line that counts [Hz].
    length : int
        Samples of the spectrum (<= the ring's size).
    prominence : float
        How many times the line must stand above the median of the lines [-].
    exclude : sequence of float
        The feed drive's mode frequencies [Hz].
    bands : sequence of (float, float)
        Frequency bands left out [Hz].
    near_hz : float, optional
        Look for the line only within ``tol_hz`` of this frequency [Hz] (a line found before, looked for
        again), against the median of all the lines.
    tol_hz : float
        See ``near_hz`` [Hz].
    """
    cap = ring.size
    x = ring[(head - length + np.arange(length)) % cap]
    x = x - x.mean()
    spec = np.abs(np.fft.rfft(x * np.hanning(length)))
    freq = np.fft.rfftfreq(length, 1.0 / fs)
    f_rev = omega / _TWO_PI
    df = freq[1]
    dist = np.abs(freq - f_rev * np.round(freq / f_rev))
    keep = (freq >= lowest_hz) & (freq <= highest_hz) & (dist > max(3.0 * df, 0.1 * f_rev))
    for f_mode in exclude:                     # the drive's own modes ring after any force step
        keep &= np.abs(freq - f_mode) > 0.1 * f_mode
    for a, b in bands:                         # the drive's position-periodic error, moved by the feed
        keep &= (freq < a) | (freq > b)
    if np.count_nonzero(keep) < 8:
        return False, 0.0, 0.0
    lines = spec[keep]
    floor = float(np.median(lines))
    candidates = lines if near_hz is None else np.where(np.abs(freq[keep] - near_hz) <= tol_hz, lines, -np.inf)
    k = int(np.argmax(candidates))
    if not np.isfinite(candidates[k]):
        return False, 0.0, 0.0
    ratio = float(lines[k] / floor) if floor > 0 else np.inf
    return ratio >= prominence, float(freq[keep][k]), ratio
