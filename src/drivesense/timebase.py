"""Time bases: checking that time stamps are uniform, and formatting sample times.

A Recording is uniformly sampled; real controller traces and CSV exports carry
time stamps that must be checked (monotonic, no jitter, no drift) before they
are trusted.  Messages name the offending row so a user can find it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .errors import ConfigError, TimebaseError
from .nc_context import CONTEXT_CHANNELS

__all__ = ["validate_timebase", "check_timebase", "check_fs", "format_time", "resample_uniform"]


def format_time(t: float, fs: float) -> str:
    """Time [s] with enough decimals to resolve one sample at `fs` [Hz].

    Parameters
    ----------
    t : float
        Time [s].
    fs : float
        Sampling rate [Hz] that sets the resolution.

    Returns
    -------
    str
    """
    decimals = min(12, max(0, math.ceil(math.log10(fs)))) if fs > 1 else 3
    return f"{t:.{decimals}f}"


def check_fs(fs: Any) -> float:
    """Return `fs` [Hz] as a float; TimebaseError unless it is a positive finite number.

    Parameters
    ----------
    fs : float
        Sampling rate [Hz].

    Returns
    -------
    float
    """
    real = (int, float, np.integer, np.floating)
    if isinstance(fs, (bool, np.bool_)) or not isinstance(fs, real):
        raise TimebaseError(f"fs must be a number in Hz, got {fs!r}")
    fs = float(fs)
    if not (math.isfinite(fs) and fs > 0):
        raise TimebaseError(f"fs must be a positive finite number of Hz, got {fs!r}")
    return fs


def _check_increasing(t: np.ndarray, name: str, at) -> None:
    """TimebaseError unless the 1-D stamps `t` [s] are at least 2, finite and strictly increasing.

    ``at(i)`` names stamp `i` in messages.
    """
    if t.size < 2:
        raise TimebaseError(f"{name}: {t.size} time value(s); a time base needs at least 2")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise TimebaseError(f"{name}: {bad.size} non-finite time value(s) "
                            f"(first {float(t[bad[0]])!r} at {at(int(bad[0]))})")
    nonpos = np.flatnonzero(np.diff(t) <= 0)
    if nonpos.size:
        i = int(nonpos[0]) + 1
        raise TimebaseError(f"{name}: time does not increase at {at(i)}: t={t[i]:.10g} s "
                            f"follows t={t[i - 1]:.10g} s at {at(i - 1)}")


def resample_uniform(time: ArrayLike, channels: dict, fs: float, *, name: str = "time",
                     rows: ArrayLike | None = None, row_label: str = "sample") -> tuple[float, dict, str]:
    """Resample irregularly stamped channels onto a uniform grid, explicitly (linear interpolation).

    The NC's context channels (:data:`~drivesense.nc_context.CONTEXT_CHANNELS`:
    a block number, a tool, an override) are held from the stamp at or before
    each grid time instead: block 10.5 means nothing.

    The grid starts at the first stamp and holds every ``t0 + k / fs`` up to
    the last stamp.  No anti-alias filter is applied: choose `fs` at or
    above the rate the data were logged at.

    Parameters
    ----------
    time : array_like
        Time stamps [s], 1-D, finite and strictly increasing (jitter allowed).
    channels : dict of str to array_like
        Channel name -> samples at the stamps [any unit: kept].
    fs : float
        Rate of the uniform grid [Hz].
    name : str, optional
        What the time stamps are, to start error messages.
    rows : array_like of int, optional
        Label of each stamp in messages (e.g. file line numbers); default the
        0-based sample index.
    row_label : str, optional
        Word for `rows` in messages (``"sample"``, ``"line"``...).

    Returns
    -------
    t0 : float
        Time of the first grid sample [s].
    resampled : dict of str to ndarray
        The channels on the grid.
    note : str
        What was done, for the provenance.

    Raises
    ------
    TimebaseError
        Fewer than 2 stamps, non-finite or non-increasing stamps (naming the
        row), a bad `fs`, or a span shorter than two samples at `fs`.
    """
    fs = check_fs(fs)
    t = np.asarray(time, dtype=np.float64)
    label = np.arange(t.size) if rows is None else np.asarray(rows)
    _check_increasing(t, name, lambda i: f"{row_label} {label[i]}")
    n = int(math.floor((t[-1] - t[0]) * fs * (1 + 1e-12))) + 1
    if n < 2:
        raise TimebaseError(f"{name}: the stamps span {t[-1] - t[0]:.6g} s, less than two samples at "
                            f"--resample {fs:g} Hz")
    grid = t[0] + np.arange(n) / fs
    held = sorted(k for k in channels if k in CONTEXT_CHANNELS)
    if held:
        last = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.size - 1)     # the stamp at or before
    out = {k: np.asarray(v, dtype=np.float64)[last] if k in held
           else np.interp(grid, t, np.asarray(v, dtype=np.float64)) for k, v in channels.items()}
    d = np.diff(t)
    note = (f"resampled explicitly (--resample) from {t.size} stamps (median step {float(np.median(d)):.6g} s, "
            f"steps {float(d.min()):.6g}..{float(d.max()):.6g} s) to a uniform grid at fs={fs:.12g} Hz, "
            f"{n} samples, by linear interpolation" + (f"; the NC's context held from the stamp before "
                                                        f"({', '.join(held)})" if held else ""))
    return float(t[0]), out, note


def check_timebase(time: ArrayLike, rel_tol: float, name: str, rows: ArrayLike | None,
              row_label: str) -> tuple[float, float]:
    """Check a time axis [s]; return (fs [Hz], worst step jitter as a fraction).

    The work of :func:`validate_timebase`, which describes the checks.

    Parameters
    ----------
    time : array_like
        Time stamps [s], 1-D.
    rel_tol : float
        Largest allowed step jitter, as a fraction of the median step [-].
    name : str
        What the time stamps are, to start error messages.
    rows : array_like of int or None
        Label of each stamp in messages; None for the 0-based sample index.
    row_label : str
        Word for `rows` in messages (``"sample"``, ``"line"``...).

    Returns
    -------
    fs : float
        Sampling rate [Hz].
    jitter : float
        Worst step jitter [-].
    """
    try:
        t = np.asarray(time, dtype=np.float64)
    except (TypeError, ValueError):
        raise TimebaseError(f"{name}: time values are not numeric") from None
    if t.ndim != 1:
        raise TimebaseError(f"{name}: time must be 1-D, got shape {t.shape}")
    if not (isinstance(rel_tol, (int, float)) and rel_tol >= 0):
        raise ConfigError(f"rel_tol must be a number >= 0, got {rel_tol!r}")
    label = np.arange(t.size) if rows is None else np.asarray(rows)

    def at(i: int) -> str:
        return f"{row_label} {label[i]}"

    n = t.size
    _check_increasing(t, name, at)
    d = np.diff(t)
    med = float(np.median(d))
    jit = np.abs(d - med) / med
    worst = int(np.argmax(jit))
    if jit[worst] > rel_tol:
        raise TimebaseError(
            f"{name}: sampling is not uniform: the step to {at(worst + 1)} is {d[worst]:.6g} s, "
            f"the median step is {med:.6g} s ({100 * jit[worst]:.3g} % jitter, "
            f"{100 * rel_tol:.3g} % allowed); resample it explicitly onto a uniform grid (--resample HZ)")
    jmax = float(jit[worst])
    fs = float(f"{(n - 1) / (t[-1] - t[0]):.12g}")  # drop float noise, e.g. from ms -> s
    dev = (t - (t[0] + np.arange(n) / fs)) * fs
    worst = int(np.argmax(np.abs(dev)))
    if abs(dev[worst]) > 0.5:
        raise TimebaseError(
            f"{name}: timestamps drift from a uniform grid at fs={fs:.12g} Hz by "
            f"{dev[worst]:+.3g} samples at {at(worst)}; resample it explicitly onto a uniform grid "
            "(--resample HZ) or split the data")
    return fs, jmax


def validate_timebase(time: ArrayLike, *, rel_tol: float = 1e-3, name: str = "time",
                      rows: ArrayLike | None = None, row_label: str = "sample") -> float:
    """Check that time stamps form a uniform time base and return its rate.

    Parameters
    ----------
    time : array_like
        Time stamps [s], 1-D.
    rel_tol : float, optional
        Largest allowed step jitter, ``max|dt - median(dt)| / median(dt)`` [-]
        (default 1e-3, i.e. 0.1 %).
    name : str, optional
        What the time stamps are (e.g. ``"cut_03.csv, column 'time [ms]'"``),
        used to start error messages.
    rows : array_like of int, optional
        Label of each stamp in messages (e.g. line numbers of a file); default
        the 0-based sample index.
    row_label : str, optional
        Word for `rows` in messages (``"sample"``, ``"line"``...).

    Returns
    -------
    float
        fs [Hz] = (n - 1) / (t[-1] - t[0]), rounded to 12 significant digits.

    Raises
    ------
    TimebaseError
        Fewer than 2 stamps, non-finite stamps, time not strictly increasing,
        step jitter above `rel_tol`, or stamps drifting more than half a sample
        from the uniform grid; the message names the offending row.
    """
    return check_timebase(time, rel_tol, name, rows, row_label)[0]
