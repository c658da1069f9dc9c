"""A $1 electret condenser used as an accelerometer, beside a reference piezo accelerometer (second paper, Sec. 3).

The electret's diaphragm is a small mass on a spring: below its resonance the deflection, and so
the output voltage, follows the acceleration; at the resonance it peaks; above it rolls off. The
preamplifier's coupling capacitors and the diaphragm's vent make a high-pass. So the response is
not flat (the paper's Fig. 6), but it is linear in amplitude from 1.3 to 6.6 g (Sec. 3.3) — a small
quadratic term and a soft saturation well above that range are kept here so that a linearity check
has something to find when driven too hard.

Assumed values (not in the paper, typical of a sealed capsule read by a sound card): sensitivity
5 mV/(m/s^2), 2nd-order high-pass at 40 Hz, diaphragm resonance 2.6 kHz with damping ratio 0.12,
quadratic distortion 0.3 % of the signal per 10 g, soft saturation near 200 g (diaphragm
deflection), self-noise 0.1 mV rms.
The reference (PCB 320C33-like, 100 mV/g) is flat within 1-4000 Hz, with a 0.5 Hz high-pass, a
mounted resonance at 25 kHz and 0.5 mV noise. Both channels are sampled on one clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal as _signal

from drivesense.errors import ConfigError
from drivesense.recording import Recording

__all__ = ["ElectretSensor", "ReferenceAccelerometer", "simulate_shaker_pair", "simulate_machining_vibration"]

G = 9.80665  # m/s^2


def _resonator(fs: float, f_n: float, zeta: float):
    """Digital (bilinear, pre-warped) 2nd-order low-pass with unit DC gain, as SOS."""
    w = 2 * fs * math.tan(math.pi * f_n / fs)          # pre-warped so the peak sits at f_n
    z, p, k = _signal.bilinear_zpk([], np.roots([1.0, 2 * zeta * w, w * w]), w * w, fs)
    return _signal.zpk2sos(z, p, k)


def _highpass(fs: float, f_c: float, order: int):
    return _signal.butter(order, f_c, "highpass", fs=fs, output="sos")


@dataclass(frozen=True)
class ElectretSensor:
    """Electret accelerometer model (acceleration [m/s^2] in, volts out).

    Parameters
    ----------
    sensitivity : float
        Gain below resonance [V/(m/s^2)].
    highpass_hz : float
        High-pass corner (2nd order) [Hz].
    resonance_hz : float
        Diaphragm resonance [Hz].
    damping : float
        Damping ratio of the resonance [-].
    distortion : float
        Quadratic term: relative distortion per 10 g of signal [-].
    saturation_g : float
        Soft saturation level [g].
    noise_v : float
        Self-noise [V rms].
    """

    sensitivity: float = 5e-3
    highpass_hz: float = 40.0
    resonance_hz: float = 2600.0
    damping: float = 0.12
    distortion: float = 3e-3
    saturation_g: float = 200.0
    noise_v: float = 1e-4

    def __post_init__(self) -> None:
        for name in ("sensitivity", "highpass_hz", "resonance_hz", "damping", "saturation_g"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"electret '{name}' must be > 0, got {getattr(self, name)!r}")

    def frequency_response(self, freq, fs: float) -> np.ndarray:
        """Linear response [V/(m/s^2)] of the sampled sensor at frequencies `freq` [Hz].

        Parameters
        ----------
        freq : array_like
            Frequencies [Hz].
        fs : float
            Sampling rate [Hz].

        Returns
        -------
        ndarray of complex
        """
        sos = np.vstack([_highpass(fs, self.highpass_hz, 2), _resonator(fs, self.resonance_hz, self.damping)])
        _, h = _signal.sosfreqz(sos, worN=np.asarray(freq, dtype=float), fs=fs)
        return self.sensitivity * h

    def respond(self, acceleration, fs: float, rng: np.random.Generator) -> np.ndarray:
        """Output voltage for an acceleration record.

        Parameters
        ----------
        acceleration : array_like
            Acceleration [m/s^2] at the mounting point.
        fs : float
            Sampling rate [Hz].
        rng : numpy.random.Generator
            Noise source.

        Returns
        -------
        ndarray
            Volts.
        """
        a = np.asarray(acceleration, dtype=float)
        y = _signal.sosfilt(_highpass(fs, self.highpass_hz, 2), a)
        y = _signal.sosfilt(_resonator(fs, self.resonance_hz, self.damping), y)
        sat = self.saturation_g * G
        y = sat * np.tanh(y / sat)
        y = y + self.distortion * y * y / (10 * G)
        return self.sensitivity * y + rng.normal(0.0, self.noise_v, a.size)


@dataclass(frozen=True)
class ReferenceAccelerometer:
    """Piezo reference accelerometer (flat within its band), output in m/s^2.

    Parameters
    ----------
    highpass_hz : float
        High-pass corner [Hz].
    resonance_hz : float
        Mounted resonance [Hz].
    noise : float
        Noise [m/s^2 rms] (0.5 mV at 100 mV/g).
    """

    highpass_hz: float = 0.5
    resonance_hz: float = 25000.0
    noise: float = 0.005 * G

    def measure(self, acceleration, fs: float, rng: np.random.Generator) -> np.ndarray:
        """Reading [m/s^2] of an acceleration record.

        Parameters
        ----------
        acceleration : array_like
            True acceleration [m/s^2].
        fs : float
            Sampling rate [Hz].
        rng : numpy.random.Generator
            Noise source.

        Returns
        -------
        ndarray
        """
        a = np.asarray(acceleration, dtype=float)
        y = _signal.sosfilt(_highpass(fs, self.highpass_hz, 1), a)
        if self.resonance_hz < 0.45 * fs:
            y = _signal.sosfilt(_resonator(fs, self.resonance_hz, 0.03), y)
        return y + rng.normal(0.0, self.noise, a.size)


def _band_noise(n: int, fs: float, lo: float, hi: float, rng: np.random.Generator) -> np.ndarray:
    x = rng.normal(size=n + 4096)
    x = _signal.sosfilt(_signal.butter(6, [lo, hi], "bandpass", fs=fs, output="sos"), x)[4096:]
    return x / np.std(x)


def simulate_shaker_pair(amplitude_g: float, *, fs: float = 44100.0, duration: float = 4.0, seed: int = 0,
                         sensor: ElectretSensor | None = None,
                         reference: ReferenceAccelerometer | None = None) -> Recording:
    """Shaker test: broadband random vibration (20 Hz-8 kHz) read by the electret and the reference.

    Parameters
    ----------
    amplitude_g : float
        RMS acceleration of the shaker table [g] (the paper used 1.3 to 6.6 g).
    fs : float
        Sampling rate of both channels [Hz].
    duration : float
        Length [s].
    seed : int
        Random seed.
    sensor : ElectretSensor, optional
        The cheap sensor (default values above).
    reference : ReferenceAccelerometer, optional
        The reference.

    Returns
    -------
    Recording
        Channels ``electret`` [V] and ``accel_ref`` [m/s^2]; meta holds the amplitude.
    """
    if not amplitude_g > 0:
        raise ConfigError(f"'amplitude_g' must be > 0, got {amplitude_g!r}")
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))
    accel = amplitude_g * G * _band_noise(n, fs, 20.0, 8000.0, rng)
    sensor, reference = sensor or ElectretSensor(), reference or ReferenceAccelerometer()
    return Recording.from_arrays({"electret": sensor.respond(accel, fs, rng),
                                  "accel_ref": reference.measure(accel, fs, rng)},
                                 fs=fs, units={"electret": "V", "accel_ref": "m/s^2"},
                                 meta={"name": f"shaker_{amplitude_g:g}g", "amplitude_g": amplitude_g,
                                       "source": "drivesense.sim.electret.simulate_shaker_pair"})


def simulate_machining_vibration(*, fs: float = 44100.0, duration: float = 3.0, seed: int = 0,
                                 spindle_rpm: float = 3000.0, flutes: int = 4, level_g: float = 3.0,
                                 sensor: ElectretSensor | None = None,
                                 reference: ReferenceAccelerometer | None = None) -> Recording:
    """Vibration of a milling cut (tooth-passing harmonics, runout line, two structural modes, noise).

    Parameters
    ----------
    fs : float
        Sampling rate [Hz].
    duration : float
        Length [s].
    seed : int
        Random seed.
    spindle_rpm : float
        Spindle speed [rev/min].
    flutes : int
        Number of flutes.
    level_g : float
        RMS acceleration [g].
    sensor : ElectretSensor, optional
        The cheap sensor.
    reference : ReferenceAccelerometer, optional
        The reference.

    Returns
    -------
    Recording
        Channels ``electret`` [V], ``accel_ref`` [m/s^2] and ``spindle_speed`` [rad/s].
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))
    t = np.arange(n) / fs
    f_s = spindle_rpm / 60.0
    x = 0.3 * np.cos(2 * np.pi * f_s * t + 0.7)
    for k in range(1, 12):
        x += np.cos(2 * np.pi * k * flutes * f_s * t + rng.uniform(0, 2 * np.pi)) / k ** 0.7
    kick = rng.normal(size=n)
    for f_m, z in ((850.0, 0.03), (2300.0, 0.02)):
        x += 0.4 * _signal.sosfilt(_resonator(fs, f_m, z), kick) / 10
    x += 0.2 * _band_noise(n, fs, 30.0, 6000.0, rng)
    accel = level_g * G * x / np.std(x)
    sensor, reference = sensor or ElectretSensor(), reference or ReferenceAccelerometer()
    return Recording.from_arrays({"electret": sensor.respond(accel, fs, rng),
                                  "accel_ref": reference.measure(accel, fs, rng),
                                  "spindle_speed": np.full(n, 2 * np.pi * f_s)},
                                 fs=fs, units={"electret": "V", "accel_ref": "m/s^2", "spindle_speed": "rad/s"},
                                 meta={"name": "milling_vibration", "spindle_rpm": spindle_rpm, "flutes": flutes,
                                       "source": "drivesense.sim.electret.simulate_machining_vibration"})
