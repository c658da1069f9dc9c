"""Calibrating a cheap vibration sensor against a reference accelerometer (second paper, Sec. 3, Figs. 5-6).

From paired recordings (cheap sensor and reference on the same shaker, one clock) at several
amplitudes:

1. **Linearity**: the sensor's band gain ``|H|`` at each amplitude; the sensor is linear when the
   gains agree within a tolerance (the paper: "the gain at any particular frequency is constant
   with respect to input amplitude", 1.3-6.6 g).
2. **Ratio spectrum** (Fig. 6): ``H(f) = S_ref,sensor / S_ref,ref`` (H1, Welch), with coherence,
   pooled over all pairs. It is complex: the phase of the sensor's resonance matters for the
   waveform.
3. **Regularised deconvolution**: ``G = conj(H) / (|H|^2 + lambda)`` with a Wiener term
   ``lambda = |H|^2 (1 - coh) / coh`` (noise where the coherence drops) plus a small floor, tapered
   to zero outside the band, turned into a linear-phase FIR filter (frequency sampling, Tukey
   window) that maps the sensor's volts to the reference's m/s^2; applied by FFT convolution with
   the filter's delay removed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal as _signal

from drivesense.errors import ConfigError, IdentificationError, InvalidSignalError, SignalTooShortError
from drivesense.io import JsonFileMixin

__all__ = ["SensorCalibration", "ratio_spectrum", "check_linearity", "calibrate_sensor", "deconvolution_residual"]

G = 9.80665
_VERSION = 1


def _pairs(pairs, fs, sensor_channel, reference_channel):
    """Normalise the input to (list of (sensor, reference) arrays, fs)."""
    from drivesense.recording import Recording

    out, rates = [], []
    for k, p in enumerate(pairs):
        if isinstance(p, Recording):
            p.require(sensor_channel, reference_channel)
            out.append((np.asarray(p[sensor_channel]), np.asarray(p[reference_channel])))
            rates.append(p.fs)
        else:
            try:
                s, r = p
            except (TypeError, ValueError):
                raise ConfigError(f"pair {k}: give a Recording or a (sensor, reference) tuple") from None
            s, r = np.asarray(s, dtype=float), np.asarray(r, dtype=float)
            if s.shape != r.shape or s.ndim != 1:
                raise InvalidSignalError(f"pair {k}: sensor and reference must be 1-D of equal length, "
                                         f"got {s.shape} and {r.shape}")
            out.append((s, r))
            rates.append(fs)
        if not (np.all(np.isfinite(out[-1][0])) and np.all(np.isfinite(out[-1][1]))):
            raise InvalidSignalError(f"pair {k}: non-finite samples")
    if not out:
        raise IdentificationError("no paired recordings: the calibration needs at least one sensor/reference pair")
    if any(r is None for r in rates):
        raise ConfigError("'fs' [Hz] is needed for array pairs")
    if max(rates) - min(rates) > 1e-9 * max(rates):
        raise ConfigError(f"the pairs have different sampling rates ({sorted(set(rates))} Hz); resample first")
    return out, float(rates[0])


def _check_band(band, fs) -> tuple[float, float]:
    lo, hi = (float(b) for b in band)
    if not (0 < lo < hi < 0.5 * fs):
        raise ConfigError(f"--band LOW:HIGH must satisfy 0 < LOW < HIGH < fs/2 = {0.5 * fs:g} Hz (half the "
                          f"recordings' rate), got {lo:g}:{hi:g}")
    return lo, hi


def ratio_spectrum(sensor, reference, fs: float, *, nperseg: int = 4096):
    """Complex ratio spectrum H = sensor / reference (H1 estimator) and coherence.

    Parameters
    ----------
    sensor : array_like
        Cheap-sensor samples [V].
    reference : array_like
        Reference acceleration [m/s^2], same clock.
    fs : float
        Sampling rate [Hz].
    nperseg : int
        Welch segment length [samples].

    Returns
    -------
    freq : ndarray
        [Hz].
    response : ndarray of complex
        H [V/(m/s^2)].
    coherence : ndarray
        In [0, 1].
    """
    s, r = np.asarray(sensor, dtype=float), np.asarray(reference, dtype=float)
    if s.size < 2 * nperseg:
        raise SignalTooShortError(f"{s.size} samples; the ratio spectrum needs at least {2 * nperseg} (2 segments)")
    f, prr = _signal.welch(r, fs, nperseg=nperseg)
    _, pss = _signal.welch(s, fs, nperseg=nperseg)
    _, prs = _signal.csd(r, s, fs, nperseg=nperseg)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(prr > 0, prs / prr, 0.0)
        coh = np.where(prr * pss > 0, np.abs(prs) ** 2 / (prr * pss), 0.0)
    return f, h, coh


def check_linearity(pairs, *, fs: float | None = None, band=(100.0, 4000.0), tolerance: float = 0.05,
                    nperseg: int = 4096, sensor_channel: str = "electret",
                    reference_channel: str = "accel_ref") -> dict:
    """Is the sensor's gain the same at every amplitude?

    Parameters
    ----------
    pairs : sequence of Recording or (sensor, reference)
        Paired recordings at different amplitudes.
    fs : float, optional
        Sampling rate [Hz] for array pairs.
    band : (float, float)
        Frequency band [Hz] of the comparison.
    tolerance : float
        Largest allowed relative spread of the band gains [-].
    nperseg : int
        Welch segment length.
    sensor_channel, reference_channel : str
        Channel names in Recordings.

    Returns
    -------
    dict
        ``amplitudes_g`` (reference rms), ``band_gain`` (mean |H| per pair [V/(m/s^2)]),
        ``spread`` ((max - min) / mean), ``rms_fit_r2`` (sensor rms against reference rms through
        zero), ``linear`` (spread <= tolerance).
    """
    items, fs = _pairs(pairs, fs, sensor_channel, reference_channel)
    lo, hi = _check_band(band, fs)
    amps, gains, out_rms = [], [], []
    for s, r in items:
        f, h, _ = ratio_spectrum(s, r, fs, nperseg=nperseg)
        sel = (f >= lo) & (f <= hi)
        gains.append(float(np.mean(np.abs(h[sel]))))
        amps.append(float(np.std(r) / G))
        out_rms.append(float(np.std(s)))
    gains_a, amps_a, out_a = np.array(gains), np.array(amps), np.array(out_rms)
    spread = float(np.ptp(gains_a) / np.mean(gains_a))
    k = float(amps_a @ out_a / (amps_a @ amps_a))
    ss = float(np.sum((out_a - out_a.mean()) ** 2))
    r2 = 1 - float(np.sum((out_a - k * amps_a) ** 2)) / ss if len(items) > 1 and ss > 0 else float("nan")
    return {"amplitudes_g": amps, "band_gain": gains, "spread": spread, "rms_fit_r2": r2,
            "linear": bool(spread <= tolerance), "tolerance": tolerance, "band_hz": [lo, hi]}


@dataclass(eq=False)
class SensorCalibration(JsonFileMixin):
    """A cheap sensor's response and its inverse (deconvolution) filter.

    Attributes
    ----------
    fs : float
        Sampling rate the filter is for [Hz].
    band : (float, float)
        Calibrated band [Hz].
    freq : ndarray
        Frequencies of the ratio spectrum [Hz].
    response : ndarray of complex
        Ratio spectrum H [V/(m/s^2)] pooled over the pairs.
    coherence : ndarray
        Pooled coherence [-].
    taps : ndarray
        FIR deconvolution filter (V -> m/s^2) [(m/s^2)/V], linear phase; its delay of
        ``(len(taps) - 1) / 2`` samples is removed by :meth:`apply`.
    linearity : dict
        Result of :func:`check_linearity`.
    per_pair : list of ndarray
        |H| of each pair [V/(m/s^2)] (for the Fig. 6 plot).
    """

    fs: float
    band: tuple
    freq: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    taps: np.ndarray
    linearity: dict = field(default_factory=dict)
    per_pair: list = field(default_factory=list, repr=False)

    #: Named in the errors of :meth:`load`; the file is written compact (:class:`~drivesense.io.JsonFileMixin`).
    json_what = "calibration file"
    json_indent = None

    def apply(self, sensor, fs: float | None = None, *, channel: str = "electret", out: str = "acceleration"):
        """Deconvolve sensor samples into acceleration [m/s^2].

        Parameters
        ----------
        sensor : array_like or Recording
            Sensor samples [V], or a Recording holding them.
        fs : float, optional
            Sampling rate [Hz] of an array (checked against the calibration's).
        channel : str
            Sensor channel of a Recording.
        out : str
            Name of the output channel added to a Recording.

        Returns
        -------
        ndarray or Recording
            Acceleration [m/s^2] (a Recording gets a new channel `out`).
        """
        from drivesense.recording import Recording

        if isinstance(sensor, Recording):
            rec = sensor
            rec.require(channel)
            self._check_fs(rec.fs)
            acc = self._convolve(np.asarray(rec[channel]))
            return rec.with_channels({out: acc}, units={out: "m/s^2"}).with_provenance(
                f"deconvolved {channel} with a {self.taps.size}-tap sensor calibration "
                f"({self.band[0]:g}-{self.band[1]:g} Hz)")
        self._check_fs(fs if fs is not None else self.fs)
        x = np.asarray(sensor, dtype=float)
        if x.ndim != 1 or not np.all(np.isfinite(x)):
            raise InvalidSignalError("'sensor' must be 1-D and finite")
        return self._convolve(x)

    def _check_fs(self, fs: float) -> None:
        if abs(fs - self.fs) > 1e-6 * self.fs:
            raise ConfigError(f"the recording is sampled at {fs:g} Hz, the calibration at {self.fs:g} Hz")

    def _convolve(self, x: np.ndarray) -> np.ndarray:
        d = (self.taps.size - 1) // 2
        return _signal.oaconvolve(x, self.taps, mode="full")[d:d + x.size]

    def to_dict(self) -> dict:
        """JSON-ready calibration (filter taps and response included).

        Returns
        -------
        dict
        """
        return {"version": _VERSION, "kind": "drivesense sensor calibration", "fs_hz": self.fs,
                "band_hz": list(self.band), "taps": self.taps.tolist(), "freq_hz": self.freq.tolist(),
                "response_re": self.response.real.tolist(), "response_im": self.response.imag.tolist(),
                "coherence": self.coherence.tolist(), "linearity": self.linearity}

    @classmethod
    def from_dict(cls, data: dict) -> "SensorCalibration":
        """Rebuild from :meth:`to_dict` output.

        Parameters
        ----------
        data : dict
            As written by :meth:`to_dict`.

        Returns
        -------
        SensorCalibration
        """
        if not isinstance(data, dict) or data.get("version") != _VERSION or "taps" not in data:
            raise ConfigError(f"not a sensor calibration (version {_VERSION}) file")
        try:
            return cls(float(data["fs_hz"]), tuple(data["band_hz"]), np.array(data["freq_hz"], dtype=float),
                       np.array(data["response_re"], dtype=float) + 1j * np.array(data["response_im"], dtype=float),
                       np.array(data["coherence"], dtype=float), np.array(data["taps"], dtype=float),
                       dict(data.get("linearity", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"sensor calibration: missing or bad field ({exc})") from None


def calibrate_sensor(pairs, *, fs: float | None = None, band=(100.0, 4000.0), nperseg: int = 4096,
                     regularisation: float = 1e-3, tolerance: float = 0.05, sensor_channel: str = "electret",
                     reference_channel: str = "accel_ref") -> SensorCalibration:
    """Ratio spectrum, linearity and deconvolution filter from paired recordings.

    Parameters
    ----------
    pairs : sequence of Recording or (sensor, reference)
        Paired shaker recordings (ideally at several amplitudes).
    fs : float, optional
        Sampling rate [Hz] for array pairs.
    band : (float, float)
        Band [Hz] the filter restores (outside it the output is tapered to zero).
    nperseg : int
        Welch segment length = FIR length - 1 (even, >= 256).
    regularisation : float
        Floor of the Tikhonov term relative to the median |H|^2 in the band [-].
    tolerance : float
        Linearity tolerance (relative spread of the band gains) [-].
    sensor_channel, reference_channel : str
        Channel names in Recordings.

    Returns
    -------
    SensorCalibration

    Raises
    ------
    IdentificationError
        No pairs, or a band where the sensor does not respond (coherence below 0.5).
    """
    if isinstance(nperseg, bool) or not isinstance(nperseg, int) or nperseg < 256 or nperseg % 2:
        raise ConfigError(f"'nperseg' must be an even integer >= 256, got {nperseg!r}")
    if not (isinstance(regularisation, (int, float)) and regularisation > 0):
        raise ConfigError(f"'regularisation' must be > 0, got {regularisation!r}")
    items, fs = _pairs(pairs, fs, sensor_channel, reference_channel)
    lo, hi = _check_band(band, fs)
    prr = pss = prs = 0.0
    per_pair = []
    for s, r in items:
        if s.size < 2 * nperseg:
            raise SignalTooShortError(f"a pair has {s.size} samples; at least {2 * nperseg} are needed")
        f, a = _signal.welch(r, fs, nperseg=nperseg)
        _, b = _signal.welch(s, fs, nperseg=nperseg)
        _, c = _signal.csd(r, s, fs, nperseg=nperseg)
        prr, pss, prs = prr + a, pss + b, prs + c
        with np.errstate(divide="ignore", invalid="ignore"):
            per_pair.append(np.where(a > 0, np.abs(c / a), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(prr > 0, prs / prr, 0.0)
        coh = np.clip(np.where(prr * pss > 0, np.abs(prs) ** 2 / (prr * pss), 0.0), 0.0, 1.0)
    inband = (f >= lo) & (f <= hi)
    if np.median(coh[inband]) < 0.5:
        raise IdentificationError(f"the sensor and the reference are not coherent in {lo:g}-{hi:g} Hz (median "
                                  f"coherence {np.median(coh[inband]):.2f}): not the same vibration, or no signal")
    h2 = np.abs(h) ** 2
    floor = regularisation * float(np.median(h2[inband]))
    wiener = h2 * (1 - coh) / np.maximum(coh, 1e-6)
    g = np.conj(h) / (h2 + wiener + floor)
    taper = np.zeros_like(f)
    taper[inband] = 1.0
    low = (f >= 0.5 * lo) & (f < lo)
    taper[low] = 0.5 - 0.5 * np.cos(np.pi * (f[low] - 0.5 * lo) / (0.5 * lo))
    top = min(1.5 * hi, 0.5 * fs)
    high = (f > hi) & (f <= top)
    taper[high] = 0.5 + 0.5 * np.cos(np.pi * (f[high] - hi) / (top - hi))
    impulse = np.fft.irfft(g * taper, n=nperseg)
    impulse = np.roll(impulse, nperseg // 2)
    taps = np.append(impulse, impulse[0]) * _signal.windows.tukey(nperseg + 1, 0.25)
    lin = check_linearity(items, fs=fs, band=(lo, hi), tolerance=tolerance, nperseg=nperseg) \
        if len(items) > 1 else {"linear": None, "note": "one pair: linearity not checked"}
    return SensorCalibration(fs, (lo, hi), f, h, coh, taps, lin, per_pair)


def deconvolution_residual(calibration: SensorCalibration, sensor, reference, *, fs: float | None = None,
                           band=None) -> float:
    """RMS of (deconvolved sensor - reference) over the reference RMS, both band-passed.

    Parameters
    ----------
    calibration : SensorCalibration
        The filter.
    sensor : array_like
        Sensor samples [V].
    reference : array_like
        Reference acceleration [m/s^2] of the same vibration.
    fs : float, optional
        Sampling rate [Hz] (default the calibration's).
    band : (float, float), optional
        Evaluation band [Hz] (default the calibrated band).

    Returns
    -------
    float
        Relative residual (0.05 = 5 %), over the record less one filter length at each end.
    """
    fs = calibration.fs if fs is None else fs
    lo, hi = _check_band(band or calibration.band, fs)
    est = calibration.apply(sensor, fs)
    sos = _signal.butter(6, [lo, hi], "bandpass", fs=fs, output="sos")
    a, b = _signal.sosfiltfilt(sos, est), _signal.sosfiltfilt(sos, np.asarray(reference, dtype=float))
    m = calibration.taps.size
    if a.size <= 3 * m:
        raise SignalTooShortError(f"{a.size} samples; the residual needs more than {3 * m}")
    a, b = a[m:-m], b[m:-m]
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2)))
