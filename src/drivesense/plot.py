"""Figures: estimate versus truth as a time trace and an amplitude spectrum.

matplotlib is imported lazily with the non-interactive Agg backend, so
importing drivesense never opens a window or touches a display.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from drivesense.recording import Recording
from drivesense.score import aligned_reference

__all__ = ["plot_estimates", "amplitude_spectrum"]

_COLOURS = {"truth": "black", "current": "tab:gray", "rigid": "tab:orange", "medob": "tab:green",
            "vibration": "tab:blue"}


def amplitude_spectrum(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum (Hann window, amplitude-corrected).

    Parameters
    ----------
    x : ndarray
        Signal (mean removed inside).
    fs : float
        Sample rate [Hz].

    Returns
    -------
    freq : ndarray
        Frequencies [Hz].
    amplitude : ndarray
        Amplitude in the signal's unit.
    """
    x = np.asarray(x, float) - np.mean(x)
    w = np.hanning(x.size)
    spec = np.fft.rfft(x * w)
    amp = 2.0 * np.abs(spec) / w.sum()
    return np.fft.rfftfreq(x.size, 1.0 / fs), amp


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def plot_estimates(truth: Recording, estimates: Mapping[str, Recording], path, *, channel: str = "force_x",
                   sos=None, window: tuple[float, float] | None = None, zoom_s: float = 0.1,
                   max_freq: float | None = None, title: str | None = None) -> Path:
    """Write a PNG: time trace (zoomed at the end of the window) and spectrum of each estimate vs truth.

    Parameters
    ----------
    truth : Recording
        Trace with the reference force ``channel``.
    estimates : mapping of str to Recording
        Estimates by method name.
    path : str or Path
        Output PNG.
    channel : str
        Force channel.
    sos : ndarray, optional
        Low-pass applied to the truth (as to the estimates).
    window : tuple of float, optional
        Spectrum window [s] (default: ``truth.meta["score_window"]``).
    zoom_s : float
        Length of the zoomed time trace [s].
    max_freq : float, optional
        Upper limit of the spectrum axis [Hz].
    title : str, optional
        Figure title.

    Returns
    -------
    Path
    """
    plt = _pyplot()
    window = window or tuple(truth.meta.get("score_window", (truth.t0, truth.t0 + truth.duration)))
    t = truth.time
    fig, (ax_t, ax_f) = plt.subplots(2, 1, figsize=(10, 7))
    sel = (t >= window[0]) & (t < window[1])
    zoom = (t >= window[1] - zoom_s) & (t < window[1])
    first_latency = None
    for name, est in estimates.items():
        latency = float(est.meta.get("latency_s", 0.0))
        first_latency = latency if first_latency is None else first_latency
        col = _COLOURS.get(name)
        ax_t.plot(t[zoom] - latency, est[channel][zoom], label=name, color=col, lw=1)
        f, a = amplitude_spectrum(est[channel][sel], truth.fs)
        ax_f.semilogy(f, a, label=name, color=col, lw=0.8)
    ref = aligned_reference(truth[channel], truth.fs, sos, 0.0)
    ax_t.plot(t[zoom], ref[zoom], label="truth (filtered)", color="black", lw=1.5, ls="--")
    f, a = amplitude_spectrum(ref[sel], truth.fs)
    ax_f.semilogy(f, a, label="truth (filtered)", color="black", lw=1.2, ls="--")
    ax_t.set_xlabel("time, shifted by each estimate's latency [s]")
    ax_t.set_ylabel(f"{channel} [N]")
    ax_t.legend(loc="upper right", fontsize=8, ncol=3)
    ax_t.grid(alpha=0.3)
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("amplitude [N]")
    ax_f.set_xlim(0, max_freq or 0.5 * truth.fs)
    ax_f.set_ylim(1e-3, None)
    ax_f.grid(alpha=0.3, which="both")
    ax_f.legend(loc="upper right", fontsize=8, ncol=3)
    fig.suptitle(title or str(truth.meta.get("name", "")))
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
