"""Excitation signals for frequency-response measurement, added to the current reference.

Swept sine (chirp), multisine with Schroeder phases (low crest factor,
periodic, so no leakage when the analysis window holds whole periods) and a
pseudo-random binary sequence.  Every generator takes an amplitude limit: a
request above it is refused rather than silently clipped.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal as sps

from drivesense.errors import ConfigError

__all__ = ["chirp", "multisine", "prbs", "make_excitation", "EXCITATIONS"]


def _check(amplitude: float, limit: float | None, n: int) -> None:
    if not (math.isfinite(amplitude) and amplitude > 0):
        raise ConfigError(f"excitation amplitude must be > 0, got {amplitude!r}")
    if limit is not None and amplitude > limit:
        raise ConfigError(f"excitation amplitude {amplitude:g} A exceeds the limit {limit:g} A")
    if n < 16:
        raise ConfigError(f"excitation too short: {n} samples")


def chirp(duration: float, fs: float, f0: float, f1: float, amplitude: float, *,
          limit: float | None = None) -> np.ndarray:
    """Logarithmic swept sine from ``f0`` to ``f1`` [Hz] over ``duration`` [s].

    Parameters
    ----------
    duration : float
        Length [s].
    fs : float
        Sample rate [Hz].
    f0, f1 : float
        Start and end frequency [Hz], ``0 < f0 < f1 < fs/2``.
    amplitude : float
        Peak amplitude [A].
    limit : float, optional
        Largest allowed amplitude [A].
    """
    n = int(round(duration * fs))
    _check(amplitude, limit, n)
    if not 0 < f0 < f1 < fs / 2:
        raise ConfigError(f"chirp needs 0 < f0 < f1 < fs/2, got f0={f0}, f1={f1}, fs={fs}")
    t = np.arange(n) / fs
    return amplitude * sps.chirp(t, f0=f0, t1=t[-1], f1=f1, method="logarithmic", phi=-90)


def multisine(duration: float, fs: float, f0: float, f1: float, amplitude: float, *, period: float = 1.0,
              limit: float | None = None, seed: int = 0) -> np.ndarray:
    """Periodic multisine, flat spectrum on the harmonics of ``1/period`` in ``[f0, f1]``.

    Schroeder phases keep the crest factor low; the result is scaled so its
    peak equals ``amplitude`` [A].  ``duration`` should be a whole number of
    periods.

    Parameters
    ----------
    duration : float
        Length [s].
    fs : float
        Sample rate [Hz].
    f0, f1 : float
        Band [Hz].
    amplitude : float
        Peak amplitude [A].
    period : float
        Period [s]; frequency resolution ``1/period`` [Hz].
    limit : float, optional
        Largest allowed amplitude [A].
    seed : int
        Seed of a small random phase perturbation (independent realisations).
    """
    n = int(round(duration * fs))
    _check(amplitude, limit, n)
    m = int(round(period * fs))
    df = 1.0 / period
    k = np.arange(max(1, int(math.ceil(f0 / df))), int(math.floor(f1 / df)) + 1)
    if k.size == 0:
        raise ConfigError(f"multisine band {f0}-{f1} Hz holds no harmonic of {df:g} Hz")
    rng = np.random.default_rng(seed)
    phases = -np.pi * k * (k - 1) / k.size + 0.1 * rng.standard_normal(k.size)
    spec = np.zeros(m // 2 + 1, complex)
    spec[k] = np.exp(1j * phases)
    one = np.fft.irfft(spec, n=m)
    one *= amplitude / np.max(np.abs(one))
    return np.resize(one, n)


def prbs(duration: float, fs: float, amplitude: float, *, order: int = 12, clock_divider: int = 1,
         limit: float | None = None) -> np.ndarray:
    """Maximum-length pseudo-random binary sequence of +-``amplitude`` [A].

    Parameters
    ----------
    duration : float
        Length [s].
    fs : float
        Sample rate [Hz].
    amplitude : float
        Level [A].
    order : int
        Register length (period ``2^order - 1`` bits).
    clock_divider : int
        Samples per bit (lowers the bandwidth to about ``fs / (2 clock_divider)``).
    limit : float, optional
        Largest allowed amplitude [A].
    """
    n = int(round(duration * fs))
    _check(amplitude, limit, n)
    bits = sps.max_len_seq(order)[0].astype(float) * 2.0 - 1.0
    seq = np.repeat(bits, int(clock_divider))
    return amplitude * np.resize(seq, n)


#: Names accepted by :func:`make_excitation`.
EXCITATIONS = ("multisine", "chirp", "prbs")


def make_excitation(kind: str, duration: float, fs: float, amplitude: float, *, f0: float = 5.0,
                    f1: float = 2000.0, limit: float | None = None, seed: int = 0) -> np.ndarray:
    """Build an excitation by name (``multisine``, ``chirp`` or ``prbs``) [A].

    Parameters
    ----------
    kind : str
        Signal type.
    duration, fs, amplitude
        Length [s], rate [Hz], peak amplitude [A].
    f0, f1 : float
        Band [Hz] (multisine, chirp).
    limit : float, optional
        Largest allowed amplitude [A].
    seed : int
        Seed (multisine phases).
    """
    if kind == "multisine":
        return multisine(duration, fs, f0, f1, amplitude, limit=limit, seed=seed)
    if kind == "chirp":
        return chirp(duration, fs, f0, f1, amplitude, limit=limit)
    if kind == "prbs":
        return prbs(duration, fs, amplitude, limit=limit)
    raise ConfigError(f"unknown excitation {kind!r}; choose one of {', '.join(EXCITATIONS)}")
