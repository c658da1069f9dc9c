"""Figures of force estimates against the reference: time trace and amplitude spectrum, and per-axis traces."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from drivesense.dsp import amplitude_spectrum
from drivesense.plot.figure import METHOD_COLOURS, new_figure
from drivesense.recording import Recording
from drivesense.score import aligned_reference, score_estimate

__all__ = ["plot_estimates", "cut_zoom_window", "plot_force_estimate", "plot_pocket_estimate"]


def _spindle_rad_s(rec: Recording, window: tuple[float, float]) -> float | None:
    """Spindle speed [rad/s] from the ``spindle_speed`` channel (median in `window`) or the metadata."""
    if "spindle_speed" in rec.channels:
        t = rec.time
        sel = (t >= window[0]) & (t < window[1])
        w = float(np.median(np.abs(rec["spindle_speed"][sel]))) if sel.any() else 0.0
        if np.isfinite(w) and w > 0:
            return w
    meta = rec.meta
    condition = meta.get("condition") if isinstance(meta.get("condition"), dict) else {}
    for rpm in (meta.get("spindle_rpm"), meta.get("n_rpm"), condition.get("spindle_rpm")):
        if isinstance(rpm, (int, float)) and not isinstance(rpm, bool) and rpm > 0:
            return float(rpm) * 2 * np.pi / 60
    return None


def cut_zoom_window(rec: Recording, window: tuple[float, float] | None = None, *, periods: float = 5.0,
                    fallback_s: float = 0.1) -> tuple[float, float]:
    """A few tooth periods in the middle of the cut: the default close-up of the estimate figures.

    The tooth period comes from the spindle speed (the ``spindle_speed``
    channel, else ``meta["spindle_rpm"]``, ``meta["n_rpm"]`` or
    ``meta["condition"]["spindle_rpm"]``) and the flutes
    (``meta["tool"]["flutes"]``; unknown: `periods` / 2 spindle revolutions
    are shown instead).  Without a spindle speed: `fallback_s` in the middle.
    The cut starts at ``meta["t_contact"]`` [s] where the trace gives it.

    Parameters
    ----------
    rec : Recording
        The trace (or an estimate that carries its metadata).
    window : tuple of float, optional
        The cut (start, end) [s] (default: ``meta["score_window"]``, else the whole trace).
    periods : float, optional
        Tooth periods shown [-].
    fallback_s : float, optional
        Length shown when the spindle speed is unknown [s].

    Returns
    -------
    tuple of float
        (start, end) [s], inside `window`.
    """
    window = window or tuple(rec.meta.get("score_window", (rec.t0, rec.t0 + rec.duration)))
    contact = rec.meta.get("t_contact")
    if isinstance(contact, (int, float)) and not isinstance(contact, bool) and window[0] < contact < window[1]:
        window = (float(contact), window[1])
    omega = _spindle_rad_s(rec, window)
    tool = rec.meta.get("tool") if isinstance(rec.meta.get("tool"), dict) else {}
    flutes = tool.get("flutes")
    if omega is None:
        length = fallback_s
    elif isinstance(flutes, int) and not isinstance(flutes, bool) and flutes > 0:
        length = periods * 2 * np.pi / (omega * flutes)
    else:
        length = 0.5 * periods * 2 * np.pi / omega
    length = min(length, window[1] - window[0])
    mid = 0.5 * (window[0] + window[1])
    return mid - 0.5 * length, mid + 0.5 * length


def plot_estimates(truth: Recording | None, estimates: Mapping[str, Recording], *, channel: str = "force_x",
                   sos: np.ndarray | None = None, window: tuple[float, float] | None = None,
                   zoom: tuple[float, float] | None = None, zoom_s: float | None = None,
                   max_freq: float | None = None, title: str | None = None) -> Figure:
    """Overview of the whole trace, a close-up and the amplitude spectrum of each estimate (and the truth, if any).

    Parameters
    ----------
    truth : Recording or None
        Trace with the reference force ``channel`` [N]; None when there is no
        reference: the estimates are drawn alone (never as a "truth").
    estimates : mapping of str to Recording
        Estimates by method name (each with ``channel`` [N] and ``meta["latency_s"]`` [s]).
    channel : str, optional
        Force channel.
    sos : ndarray, optional
        Low-pass (second-order sections, shape (n, 6)) [-] applied to the truth, as to the estimates.
    window : tuple of float, optional
        Spectrum window (start, end) [s] (default: ``meta["score_window"]`` of the
        truth, else of the first estimate, else the whole trace).
    zoom : tuple of float, optional
        Close-up (start, end) [s] (default: :func:`cut_zoom_window`, a few tooth
        periods in the middle of `window`).
    zoom_s : float, optional
        Length of a close-up centred in `window` [s], when `zoom` is not given.
    max_freq : float, optional
        Upper limit of the spectrum axis [Hz] (default: half the sampling rate).
    title : str, optional
        Figure title (default: the truth's name, else the estimated trace's).

    Returns
    -------
    matplotlib.figure.Figure
        Three panels: the whole trace (close-up shaded), the close-up, the amplitude spectrum.
    """
    base = truth if truth is not None else next(iter(estimates.values()))
    window = window or tuple(base.meta.get("score_window", (base.t0, base.t0 + base.duration)))
    if zoom is None:
        if zoom_s is not None:
            mid, half = 0.5 * (window[0] + window[1]), 0.5 * min(zoom_s, window[1] - window[0])
            zoom = (mid - half, mid + half)
        else:
            zoom = cut_zoom_window(base, window)
    t = base.time
    fig = new_figure((10, 9))
    ax_all, ax_t, ax_f = fig.subplots(3, 1, gridspec_kw={"height_ratios": (1, 1.2, 1.2)})
    sel = (t >= window[0]) & (t < window[1])
    close = (t >= zoom[0]) & (t < zoom[1])
    for name, est in estimates.items():
        latency = float(est.meta.get("latency_s", 0.0))
        col = METHOD_COLOURS.get(name)
        ax_all.plot(t - latency, est[channel], label=name, color=col, lw=0.6)
        ax_t.plot(t[close] - latency, est[channel][close], label=name, color=col, lw=1)
        f, a = amplitude_spectrum(est[channel][sel], base.fs)
        ax_f.semilogy(f, a, label=name, color=col, lw=0.8)
    if truth is not None:
        ref = aligned_reference(truth[channel], truth.fs, sos, 0.0)
        ax_all.plot(t, ref, label="truth (filtered)", color="black", lw=0.8, ls="--")
        ax_t.plot(t[close], ref[close], label="truth (filtered)", color="black", lw=1.5, ls="--")
        f, a = amplitude_spectrum(ref[sel], truth.fs)
        ax_f.semilogy(f, a, label="truth (filtered)", color="black", lw=1.2, ls="--")
    ax_all.axvspan(*zoom, color="tab:blue", alpha=0.15, lw=0)
    ax_all.set_title(f"whole trace (shaded: the close-up, {zoom[0]:.4g}-{zoom[1]:.4g} s)", fontsize=9)
    ax_t.set_title("close-up" + ("" if truth is not None else " (no reference force in the trace)"), fontsize=9)
    for ax in (ax_all, ax_t):
        ax.set_xlabel("time, shifted by each estimate's latency [s]")
        ax.set_ylabel(f"{channel} [N]")
        ax.grid(alpha=0.3)
    ax_t.legend(loc="upper right", fontsize=8, ncol=3)
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("amplitude [N]")
    ax_f.set_xlim(0, max_freq or 0.5 * base.fs)
    ax_f.set_ylim(1e-3, None)
    ax_f.grid(alpha=0.3, which="both")
    ax_f.legend(loc="upper right", fontsize=8, ncol=3)
    fig.suptitle(title or str(base.meta.get("source" if truth is None else "name", base.meta.get("name", ""))))
    fig.tight_layout()
    return fig


def plot_force_estimate(trace: Recording, estimate: Recording, *, axes: Sequence[str] | None = None,
                        title: str | None = None) -> Figure:
    """Estimated against reference force per axis (the estimate alone where the trace has no reference).

    Parameters
    ----------
    trace : Recording
        The NC trace (``force_{ax}`` [N] if a reference exists; ``meta["score_window"]`` [s] shaded).
    estimate : Recording
        Estimator output with ``force_{ax}`` [N] and ``meta["latency_s"]`` [s].
    axes : sequence of str, optional
        Axes to plot (default: every ``force_{ax}`` of the estimate).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per axis, with the RMSE [N] and NRMSE [%] in its title where a reference exists.
    """
    axes = tuple(axes or [c.split("_", 1)[1] for c in estimate.channels if c.startswith("force_")])
    lat = float(estimate.meta.get("latency_s", 0.0))
    window = tuple(trace.meta.get("score_window", (trace.t0, trace.t0 + trace.duration)))
    fig = new_figure((9, 2.6 * len(axes) + 0.6))
    panels = fig.subplots(len(axes), 1, sharex=True, squeeze=False)
    for ax_plot, ax in zip(panels[:, 0], axes):
        ch = f"force_{ax}"
        label = f"{ax}"
        ax_plot.plot(estimate.time, estimate[ch], color="tab:red", lw=0.9, label="ModelBased")
        if ch in trace.channels:
            s = score_estimate(estimate, trace, channel=ch, window=window)
            ax_plot.plot(trace.time + lat, trace[ch], color="black", lw=0.6, alpha=0.8,
                         label="reference (delayed by the latency)")
            label += f": RMSE {s.rmse_n:.1f} N, NRMSE {s.nrmse * 100:.1f} %"
        if "score_window" in trace.meta:
            ax_plot.axvspan(*window, color="0.92", zorder=0)
        ax_plot.set_ylabel(f"F_{ax} [N]")
        ax_plot.set_title(label, fontsize=9)
        ax_plot.legend(loc="upper right", fontsize=8)
    panels[-1, 0].set_xlabel("time [s]")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def plot_pocket_estimate(trace: Recording, estimate: Recording) -> Figure:
    """A circular pocket: estimated against true force, x and y (like the third paper's Fig. 6).

    Parameters
    ----------
    trace : Recording
        Simulated pocket trace (``force_x``, ``force_y`` [N], ``meta["score_window"]`` [s]).
    estimate : Recording
        ModelBased output for it (``force_x``, ``force_y`` [N]).

    Returns
    -------
    matplotlib.figure.Figure
        See :func:`plot_force_estimate`.
    """
    return plot_force_estimate(trace, estimate, axes=("x", "y"),
                               title=f"{trace.meta.get('name', 'pocket')}: force on the workpiece (full physics)")
