"""Figures of force estimates against the reference: time trace and amplitude spectrum, and per-axis traces."""

from __future__ import annotations

from typing import TYPE_CHECKING, Mapping, Sequence

from matplotlib.figure import Figure

from drivesense.dsp import amplitude_spectrum
from drivesense.plot.figure import METHOD_COLOURS, new_figure
from drivesense.recording import Recording
from drivesense.score import aligned_reference, score_estimate

if TYPE_CHECKING:
    import numpy as np

__all__ = ["plot_estimates", "plot_force_estimate", "plot_pocket_estimate"]


def plot_estimates(truth: Recording, estimates: Mapping[str, Recording], *, channel: str = "force_x",
                   sos: "np.ndarray | None" = None, window: tuple[float, float] | None = None, zoom_s: float = 0.1,
                   max_freq: float | None = None, title: str | None = None) -> Figure:
    """Time trace (zoomed at the end of the window) and amplitude spectrum of each estimate against the truth.

    Parameters
    ----------
    truth : Recording
        Trace with the reference force ``channel`` [N].
    estimates : mapping of str to Recording
        Estimates by method name (each with ``channel`` [N] and ``meta["latency_s"]`` [s]).
    channel : str, optional
        Force channel.
    sos : ndarray, optional
        Low-pass (second-order sections, shape (n, 6)) [-] applied to the truth, as to the estimates.
    window : tuple of float, optional
        Spectrum window (start, end) [s] (default: ``truth.meta["score_window"]``, else the whole trace).
    zoom_s : float, optional
        Length of the zoomed time trace [s].
    max_freq : float, optional
        Upper limit of the spectrum axis [Hz] (default: half the sampling rate).
    title : str, optional
        Figure title (default: the truth's name).

    Returns
    -------
    matplotlib.figure.Figure
        Two panels: time trace, amplitude spectrum.
    """
    window = window or tuple(truth.meta.get("score_window", (truth.t0, truth.t0 + truth.duration)))
    t = truth.time
    fig = new_figure((10, 7))
    ax_t, ax_f = fig.subplots(2, 1)
    sel = (t >= window[0]) & (t < window[1])
    zoom = (t >= window[1] - zoom_s) & (t < window[1])
    for name, est in estimates.items():
        latency = float(est.meta.get("latency_s", 0.0))
        col = METHOD_COLOURS.get(name)
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
