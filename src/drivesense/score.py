"""Scoring a force estimate against a reference (dynamometer or simulator truth).

As in the first paper, the reference passes through the same low-pass as the
estimate.  It is then delayed by the estimate's declared latency (the pure
measurement delay no method can undo), and the comparison is restricted to an
explicit window that excludes start-up transients.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import signal as sps

from drivesense.errors import CoverageError
from drivesense.recording import Recording

__all__ = ["Score", "score_estimate", "aligned_reference", "harmonic_amplitudes"]


@dataclass(frozen=True)
class Score:
    """Accuracy of one estimate.

    Attributes
    ----------
    rmse_n : float
        Root-mean-square error [N].
    nrmse : float
        RMSE divided by the peak-to-peak of the (filtered) reference [-].
    max_abs_error_n : float
        Largest absolute error [N].
    peak_to_peak_n : float
        Peak-to-peak of the filtered reference in the window [N].
    harmonic_error : float
        Amplitude error at the tooth-pass harmonics below the cut-off,
        ``sum |A_est - A_ref| / sum A_ref`` [-] (weighted by amplitude, so
        negligible harmonics do not dominate; NaN when no tooth-pass
        frequency is known).
    window : tuple of float
        Scored time window [s].
    """

    rmse_n: float
    nrmse: float
    max_abs_error_n: float
    peak_to_peak_n: float
    harmonic_error: float
    window: tuple[float, float]

    def to_dict(self) -> dict:
        """Plain dict for JSON."""
        d = asdict(self)
        d["window"] = list(self.window)
        return d


def aligned_reference(reference: np.ndarray, fs: float, sos: np.ndarray | None, latency_s: float) -> np.ndarray:
    """Low-pass the reference like the estimate and delay it by ``latency_s`` [s].

    Parameters
    ----------
    reference : ndarray
        Reference force [N].
    fs : float
        Sampling rate [Hz].
    sos : ndarray or None
        The estimator's low-pass as second-order sections, shape (n, 6) [-];
        None for no filter.  The filter starts in its steady state at the
        first value.
    latency_s : float
        Delay [s] (fractional samples are interpolated linearly).

    Returns
    -------
    ndarray
        The filtered, delayed reference [N].
    """
    ref = np.asarray(reference, dtype=float)
    if sos is not None:
        ref = sps.sosfilt(sos, ref, zi=sps.sosfilt_zi(sos) * ref[0])[0]
    idx = np.arange(ref.size) - latency_s * fs
    return np.interp(idx, np.arange(ref.size), ref)


def harmonic_amplitudes(x: np.ndarray, fs: float, freqs) -> np.ndarray:
    """Amplitudes of sinusoids at ``freqs`` [Hz] in ``x`` by joint least squares.

    Parameters
    ----------
    x : ndarray
        Signal [any unit], uniformly sampled.
    fs : float
        Sampling rate [Hz].
    freqs : sequence of float
        Frequencies [Hz] fitted jointly (with a constant).

    Returns
    -------
    ndarray
        Amplitude at each frequency [unit of `x`].
    """
    t = np.arange(x.size) / fs
    cols = [np.ones_like(t)]
    for f in freqs:
        cols += [np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)]
    A = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    return np.hypot(coef[1::2], coef[2::2])


def score_estimate(estimate: Recording, reference: Recording, *, channel: str = "force_x",
                   window: tuple[float, float] | None = None, sos: np.ndarray | None = None,
                   tooth_pass_hz: float | None = None, cutoff_hz: float | None = None) -> Score:
    """Compare an estimate with a reference force.

    Parameters
    ----------
    estimate : Recording
        Output of an estimator (``meta["latency_s"]`` is honoured).
    reference : Recording
        Trace holding the reference ``channel`` on the same time base.
    channel : str
        Force channel to compare.
    window : tuple of float, optional
        ``(start, end)`` [s]; default ``reference.meta["score_window"]``.
    sos : ndarray, optional
        The estimator's low-pass (second-order sections, shape (n, 6)) [-]
        applied to the reference.
    tooth_pass_hz : float, optional
        Tooth-passing frequency [Hz] for the harmonic amplitude error.
    cutoff_hz : float, optional
        Only harmonics below this frequency [Hz] are compared.

    Returns
    -------
    Score
    """
    if window is None:
        window = tuple(reference.meta.get("score_window", (reference.t0, reference.t0 + reference.duration)))
    latency = float(estimate.meta.get("latency_s", 0.0))
    ref = aligned_reference(reference[channel], reference.fs, sos, latency)
    est = estimate[channel]
    t = reference.time
    sel = (t >= window[0]) & (t < window[1])
    if sel.sum() < 10:
        raise CoverageError(f"score window {window[0]}-{window[1]} s holds fewer than 10 samples")
    err = est[sel] - ref[sel]
    rmse = float(np.sqrt(np.mean(err**2)))
    p2p = float(np.ptp(ref[sel]))
    harm = float("nan")
    if tooth_pass_hz:
        limit = cutoff_hz or 0.5 * reference.fs
        k_max = int(np.floor(limit / tooth_pass_hz - 1e-9))
        if k_max >= 1:
            freqs = tooth_pass_hz * np.arange(1, k_max + 1)
            a_ref = harmonic_amplitudes(ref[sel], reference.fs, freqs)
            a_est = harmonic_amplitudes(est[sel], reference.fs, freqs)
            if a_ref.sum() > 0:
                harm = float(np.sum(np.abs(a_est - a_ref)) / np.sum(a_ref))
    return Score(rmse, rmse / p2p if p2p > 0 else float("inf"), float(np.max(np.abs(err))), p2p, harm,
                 (float(window[0]), float(window[1])))
