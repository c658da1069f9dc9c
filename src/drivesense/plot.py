"""Figures: estimate versus truth as a time trace and an amplitude spectrum.

matplotlib is imported lazily with the non-interactive Agg backend, so
importing drivesense never opens a window or touches a display.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from drivesense.dsp import amplitude_spectrum, dominant_wavelengths, wavelength_spectrum
from drivesense.recording import Recording
from drivesense.score import aligned_reference

__all__ = ["plot_estimates", "plot_friction_maps", "plot_frf_fit"]

_COLOURS = {"truth": "black", "current": "tab:gray", "rigid": "tab:orange", "medob": "tab:green",
            "vibration": "tab:blue"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path) -> Path:
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


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
    return _save(plt, fig, path)


def plot_friction_maps(maps, path, *, title: str | None = None) -> Path:
    """Write a PNG: each friction map's runs against table position, and its wavelength spectrum.

    The first paper's Figs. 7-11 in one figure: position dependence and
    repeatability (left), periodic components by wavelength (right).

    Parameters
    ----------
    maps : mapping of str to FrictionMap
        Maps by method name.
    path : str or Path
        Output PNG.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
    """
    plt = _pyplot()
    fig, axes = plt.subplots(len(maps), 2, figsize=(11, 3.2 * len(maps)), squeeze=False)
    for row, (name, fmap) in enumerate(maps.items()):
        ax_x, ax_w = axes[row]
        for k, run in enumerate(fmap.runs):
            ok = np.isfinite(run)
            ax_x.plot(fmap.position[ok] * 1e3, run[ok], lw=0.7, label=f"idle run {k + 1}")
        ax_x.plot(fmap.position * 1e3, fmap.force, color="black", lw=1.0, label="map (mean)")
        ax_x.set_xlabel("table position [mm]")
        ax_x.set_ylabel(f"{name}: friction [N]")
        ax_x.set_title(f"{name}: repeatability {fmap.repeatability_rms:.2f} N rms", fontsize=9)
        ax_x.legend(fontsize=7, loc="upper right")
        ax_x.grid(alpha=0.3)
        wl, amp = wavelength_spectrum(fmap.force, fmap.position)
        ax_w.loglog(wl * 1e3, amp, lw=0.8)
        for peak in dominant_wavelengths(wl, amp, 4):
            ax_w.annotate(f"{peak['wavelength_m'] * 1e3:.3g} mm", (peak["wavelength_m"] * 1e3, peak["amplitude"]),
                          fontsize=7, textcoords="offset points", xytext=(3, 3))
        ax_w.set_xlabel("wavelength [mm]")
        ax_w.set_ylabel("amplitude [N]")
        ax_w.grid(alpha=0.3, which="both")
    fig.suptitle(title or "Friction maps from idling runs")
    return _save(plt, fig, path)


def plot_frf_fit(fit, path, *, title: str | None = None) -> Path:
    """Write a PNG: measured and fitted FRFs (magnitude, phase) and the coherence (Fig. 5 style).

    Parameters
    ----------
    fit : drivesense.identify.frf.FRFFit
        A fit and the data it was fitted to.
    path : str or Path
        Output PNG.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
    """
    plt = _pyplot()
    meas = fit.measured
    f = meas.freq
    model_m, model_t = fit.model()
    fig, (ax_mag, ax_ph, ax_coh) = plt.subplots(3, 1, figsize=(9, 9), sharex=True,
                                                gridspec_kw={"height_ratios": [3, 2, 1]})
    for label, data, model, col in (("motor", meas.motor, model_m, "tab:blue"),
                                    ("table", meas.table, model_t, "tab:red")):
        ax_mag.loglog(f, np.abs(data), color=col, lw=0.8, ls="--", label=f"{label}: measured")
        ax_mag.loglog(f, np.abs(model), color=col, lw=1.4, label=f"{label}: model")
        model_phase = np.unwrap(np.angle(model))
        # measured phase drawn relative to the model's branch, so noise cannot make it wrap away
        ax_ph.semilogx(f, np.degrees(model_phase + np.angle(data / model)), color=col, lw=0.8, ls="--")
        ax_ph.semilogx(f, np.degrees(model_phase), color=col, lw=1.4)
    ax_coh.semilogx(f, meas.coherence_motor, color="tab:blue", lw=0.8)
    ax_coh.semilogx(f, meas.coherence_table, color="tab:red", lw=0.8)
    ax_mag.set_ylabel("acceleration / motor thrust [(m/s^2)/N]")
    ax_mag.legend(fontsize=8)
    ax_ph.set_ylabel("phase [deg]")
    ax_coh.set_ylabel("coherence")
    ax_coh.set_ylim(0, 1.05)
    ax_coh.set_xlabel("frequency [Hz]")
    for ax in (ax_mag, ax_ph, ax_coh):
        ax.grid(alpha=0.3, which="both")
    fig.suptitle(title or f"FRF fit ({meas.reference} reference, normalised residual {fit.normalised_rms:.2f})")
    return _save(plt, fig, path)
