"""Signal processing helpers: amplitude spectra in time and in the wavelength domain.

Position-dependent disturbances (friction ripple, encoder interpolation error,
screw lead error) are periodic in position, not in time: their frequency
scales with the feed speed.  Dividing the frequency axis by the feed speed
(first paper, Figs. 8 and 11) — or, more robustly, resampling the signal on a
uniform position grid before the FFT — puts them at fixed wavelengths.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy import signal as sps

from drivesense.errors import InvalidSignalError

__all__ = ["amplitude_spectrum", "wavelength_spectrum", "dominant_wavelengths", "median_of", "sosfilt_with_state"]


def amplitude_spectrum(x, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum (flat-top window, amplitude-corrected, mean removed).

    The flat-top window reads the amplitude of a sinusoid to within 0.1 %
    wherever it falls between frequency bins, at the cost of wider peaks.

    Parameters
    ----------
    x : array_like
        Uniformly sampled signal [any unit].
    fs : float
        Sample rate [Hz] (or samples per metre for a position grid).

    Returns
    -------
    freq : ndarray
        Frequencies [Hz] (or spatial frequencies [1/m]).
    amplitude : ndarray
        Amplitude in the signal's unit: a sinusoid of amplitude A reads A.
    """
    x = np.asarray(x, float)
    if x.size < 4:
        raise InvalidSignalError(f"amplitude_spectrum needs at least 4 samples, got {x.size}")
    x = x - np.mean(x)
    w = sps.windows.flattop(x.size, sym=False)
    amp = 2.0 * np.abs(np.fft.rfft(x * w)) / w.sum()
    return np.fft.rfftfreq(x.size, 1.0 / fs), amp


def wavelength_spectrum(values, position, *, step: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude spectrum of a position-dependent signal against wavelength.

    Parameters
    ----------
    values : array_like
        Signal samples (e.g. friction force [N] or relative displacement [m]).
    position : array_like
        Position of each sample [m]; must move in one direction overall
        (samples are sorted by position; repeated positions are averaged).
    step : float, optional
        Spacing of the uniform position grid [m]; default: the median
        spacing of the samples.

    Returns
    -------
    wavelength : ndarray
        Wavelengths [m], longest first (the zero frequency is dropped).
    amplitude : ndarray
        Amplitude in the unit of ``values``.
    """
    v = np.asarray(values, float)
    x = np.asarray(position, float)
    if v.shape != x.shape:
        raise InvalidSignalError(f"values and position differ in shape: {v.shape} vs {x.shape}")
    order = np.argsort(x, kind="stable")
    x, v = x[order], v[order]
    span = x[-1] - x[0]
    if span <= 0:
        raise InvalidSignalError("position does not move: a wavelength spectrum needs travel")
    if step is None:
        d = np.diff(x)
        d = d[d > 0]
        step = float(np.median(d)) if d.size else span / max(x.size - 1, 1)
    grid = x[0] + step * np.arange(int(np.floor(span / step)) + 1)
    uniq, inv = np.unique(x, return_inverse=True)
    mean_v = np.bincount(inv, weights=v) / np.bincount(inv)
    resampled = np.interp(grid, uniq, mean_v)
    k, amp = amplitude_spectrum(resampled, 1.0 / step)
    return 1.0 / k[1:], amp[1:]


def dominant_wavelengths(wavelength, amplitude, n: int = 5, *, min_separation: float = 0.1) -> list[dict]:
    """The ``n`` largest spectral peaks as ``[{"wavelength_m", "amplitude"}]``.

    Parameters
    ----------
    wavelength, amplitude : ndarray
        From :func:`wavelength_spectrum`: wavelengths [m] and amplitudes [unit
        of the signal].
    n : int
        Number of peaks.
    min_separation : float
        Peaks closer than this relative wavelength difference are merged [-].

    Returns
    -------
    list of dict
        Largest first; ``wavelength_m`` [m] and ``amplitude`` [unit of the signal].
    """
    wl = np.asarray(wavelength, float)
    amp = np.asarray(amplitude, float)
    is_peak = np.r_[False, (amp[1:-1] > amp[:-2]) & (amp[1:-1] >= amp[2:]), False]
    idx = np.flatnonzero(is_peak)
    idx = idx[np.argsort(amp[idx])[::-1]]
    peaks: list[dict] = []
    for i in idx:
        if all(abs(wl[i] - p["wavelength_m"]) > min_separation * p["wavelength_m"] for p in peaks):
            peaks.append({"wavelength_m": float(wl[i]), "amplitude": float(amp[i])})
        if len(peaks) == n:
            break
    return peaks


def median_of(x: np.ndarray) -> float:
    """The median of a 1-D array [unit of x] (numpy's, without its per-call wrappers; NaN when empty).

    Parameters
    ----------
    x : ndarray
        The values [any unit].
    """
    n = x.size
    if n == 0:
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, (k - 1, k))
    return float(0.5 * (part[k - 1] + part[k]))


@njit(cache=True, nogil=True)
def sosfilt_with_state(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``scipy.signal.sosfilt(sos, x, zi=zi)`` (direct form II transposed, as scipy), ``zi`` updated in place.

    Compiled: no per-call overhead for the short chunks of a live stream.

    Parameters
    ----------
    sos : ndarray
        Second-order sections, (n, 6) [-].
    x : ndarray
        The signal [any unit].
    zi : ndarray
        The filter state, (n, 2) [unit of x]; updated in place.
    """
    y = x.copy()
    for s in range(sos.shape[0]):
        b0, b1, b2, a1, a2 = sos[s, 0], sos[s, 1], sos[s, 2], sos[s, 4], sos[s, 5]
        z0, z1 = zi[s, 0], zi[s, 1]
        for i in range(y.size):
            xi = y[i]
            yi = b0 * xi + z0
            z0 = b1 * xi - a1 * yi + z1
            z1 = b2 * xi - a2 * yi
            y[i] = yi
        zi[s, 0] = z0
        zi[s, 1] = z1
    return y
