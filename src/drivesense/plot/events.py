"""Figure of a detection run: force, each detector's statistic with its threshold, and the events, on one time axis."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.events.pipeline import DetectionReport
    from drivesense.recording import Recording

__all__ = ["plot_events"]

_COLOURS = {"breakage": "#c62828", "chipping": "#ef6c00", "chatter": "#6a1b9a", "collision": "#000000",
            "overload": "#37474f", "missing_tool": "#1565c0", "limit": "#00838f", "wear": "#558b2f"}


def plot_events(inputs: "Recording", report: "DetectionReport", *, channel: str = "force_x",
                truth: list | None = None, title: str | None = None) -> Figure:
    """Force on top, one panel per detector below (statistic and threshold), events as vertical lines.

    Where a detector's guards held its statistic (``report.held``: a cut's start, a feed change, a
    transient shorter than the detector's hold...) the statistic is drawn grey and dashed: crossing the
    threshold there raises no event, by design.

    Parameters
    ----------
    inputs : Recording
        The force stream the detectors read (``channel`` [N]).
    report : DetectionReport
        The detectors' events and statistics.
    channel : str
        Force channel to draw.
    truth : list of dict, optional
        Known events (``kind``, ``time_s``) of a simulated trace, drawn dashed.
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    names = list(report.statistics)
    fig = new_figure((10.0, 2.0 + 1.6 * (len(names) + 1)))
    axes = fig.subplots(len(names) + 1, 1, sharex=True, squeeze=False)[:, 0]
    t = inputs.time
    axes[0].plot(t, inputs[channel], lw=0.4, color="#455a64")
    axes[0].set_ylabel(f"{channel} [N]")
    held_by = getattr(report, "held", {}) or {}
    for ax, name in zip(axes[1:], names):
        stat, thr = report.statistics[name]
        held = held_by.get(name)
        if held is None or not np.any(held > 0):
            ax.plot(t, stat, lw=0.6, label="statistic")
        else:
            _plot_held(ax, t, np.asarray(stat, dtype=float), np.asarray(held) > 0)
        if np.any(np.isfinite(thr)):
            ax.plot(t, thr, lw=0.8, ls="--", color="#c62828", label="threshold")
        ax.set_ylabel(name)
        ax.legend(loc="upper left", fontsize=7, frameon=False)
    for ax in axes:
        for e in report.events:
            ax.axvline(e.time_s, color=_COLOURS.get(e.kind, "#c62828"), lw=1.0)
        for e in truth or []:
            ax.axvline(e["time_s"], color="#9e9e9e", lw=1.0, ls=":")
    for e in report.events:          # beside its line, not on it
        axes[0].annotate(e.kind, (e.time_s, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -3),
                         textcoords="offset points", rotation=90, va="top", ha="left", fontsize=7,
                         color=_COLOURS.get(e.kind, "#c62828"),
                         bbox=dict(boxstyle="square,pad=0.1", facecolor="white", edgecolor="none", alpha=0.8))
    axes[-1].set_xlabel("time [s]")
    if truth:
        axes[0].plot([], [], color="#9e9e9e", ls=":", label="simulated event (truth)")
        axes[0].legend(loc="lower left", fontsize=7, frameon=False)
    fig.suptitle(title or f"{len(report.events)} event(s); latency {report.latency_s * 1e3:.1f} ms")
    fig.tight_layout()
    return fig


def _plot_held(ax, t: np.ndarray, stat: np.ndarray, held: np.ndarray) -> None:
    """The statistic solid where the detector judged it, grey and dashed (on a shaded band) where its guards
    held it."""
    edge = held | np.concatenate([held[1:], [False]]) | np.concatenate([[False], held[:-1]])  # joined lines
    ax.plot(t, np.where(~held, stat, np.nan), lw=0.6, label="statistic")
    ax.plot(t, np.where(edge, stat, np.nan), lw=0.6, ls="--", color="#757575",
            label="held by the detector's guards (shaded): no event there")
    ax.fill_between(t, 0, 1, where=held, transform=ax.get_xaxis_transform(), color="#9e9e9e", alpha=0.15, lw=0)
