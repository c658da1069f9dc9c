"""Spectra in time and in the wavelength domain recover known sinusoids."""

import numpy as np
import pytest

from drivesense.dsp import amplitude_spectrum, dominant_wavelengths, wavelength_spectrum
from drivesense.errors import InvalidSignalError


def test_amplitude_spectrum_reads_sinusoid_amplitude():
    fs = 10_000.0
    t = np.arange(20_000) / fs
    f, a = amplitude_spectrum(3.0 + 2.0 * np.sin(2 * np.pi * 250.0 * t), fs)
    k = np.argmax(a)
    assert f[k] == pytest.approx(250.0, abs=0.5)
    assert a[k] == pytest.approx(2.0, rel=0.01)


def test_wavelength_spectrum_is_independent_of_feed_speed():
    """The same position ripple sampled at two feed speeds peaks at the same wavelengths."""
    def ripple(x):
        return 4.0 * np.sin(2 * np.pi * x / 1.25e-3) + 1.0 * np.sin(2 * np.pi * x / 83e-6)

    peaks = []
    for speed in (1e-3, 5e-3):
        x = np.arange(0.0, 10e-3, speed / 10_000.0)
        wl, amp = wavelength_spectrum(ripple(x), x)
        peaks.append(dominant_wavelengths(wl, amp, 2))
    for p in peaks:
        assert p[0]["wavelength_m"] == pytest.approx(1.25e-3, rel=0.02)
        assert p[0]["amplitude"] == pytest.approx(4.0, rel=0.05)
        assert p[1]["wavelength_m"] == pytest.approx(83e-6, rel=0.02)
        assert p[1]["amplitude"] == pytest.approx(1.0, rel=0.05)


def test_wavelength_spectrum_needs_travel():
    with pytest.raises(InvalidSignalError, match="travel"):
        wavelength_spectrum(np.ones(10), np.zeros(10))
    with pytest.raises(InvalidSignalError, match="shape"):
        wavelength_spectrum(np.ones(10), np.arange(9.0))
