"""Figure of the feed-drive power model: average x-force against cutting power per slide speed (Fig. 14)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import colour_cycle, new_figure

if TYPE_CHECKING:
    from drivesense.identify.feed_power import FeedCuts, FeedPowerModel, SpeedFit

__all__ = ["plot_feed_power"]


def plot_feed_power(cuts: "FeedCuts", model: "FeedPowerModel", speed_fits: "Sequence[SpeedFit]" = (), *,
                    title: str | None = None) -> Figure:
    """Force against cutting power per slide speed with the model (the second paper's Fig. 14), and eta(v).

    Parameters
    ----------
    cuts : FeedCuts
        Cuts with ``force_x`` [N], ``slide_speed`` [m/s], ``power()`` [W] and ``speed_groups()``.
    model : FeedPowerModel
        The fitted model (``a0``, ``a1`` [s/m], ``f0`` [N], ``speed_range`` [m/s], ``efficiency(v [m/s])``,
        ``rms_error`` [N]).
    speed_fits : sequence of SpeedFit, optional
        Each speed's own straight line (``speed`` [m/s], ``r2``), as from
        :func:`drivesense.identify.feed_power.per_speed_fits`; their R² goes into the legend.
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Left: average x-force [N] against cutting power [W] per speed, with the model's lines;
        right: efficiency against slide speed [mm/min].
    """
    fig = new_figure((12, 5))
    ax, ax_e = fig.subplots(1, 2)
    p = cuts.power()
    colours = colour_cycle()
    fits = {round(s.speed, 9): s for s in speed_fits}
    groups = cuts.speed_groups()
    for k, g in enumerate(groups):
        v = float(np.mean(cuts.slide_speed[g]))
        col = colours[k % len(colours)]
        ax.plot(p[g], cuts.force_x[g], "o", color=col)
        px = np.linspace(0.0, p[g].max() * 1.1, 50)
        fit = fits.get(round(v, 9))
        label = f"{v * 6e4:.0f} mm/min ({v * 60 / 0.0254:.0f} in/min)"
        if fit is not None and math.isfinite(fit.r2):
            label += f", R² = {fit.r2:.3f}"
        ax.plot(px, (model.a0 + model.a1 * v) * px / v + model.f0, color=col, lw=1, label=label)
    ax.set_xlabel("cutting power P_total - P_tare [W]")
    ax.set_title("lines: the fitted model; R²: each speed's own straight line", fontsize=9)
    ax.set_ylabel("average x-force [N]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    vx = np.linspace(*model.speed_range, 50)
    ax_e.plot(vx * 6e4, model.efficiency(vx), color="black")
    for g in groups:
        v = float(np.mean(cuts.slide_speed[g]))
        ax_e.plot(v * 6e4, model.efficiency(v), "o", color="black")
    ax_e.set_xlabel("slide speed [mm/min]")
    ax_e.set_ylabel("efficiency eta(v) (incl. sensor scale)")
    ax_e.grid(alpha=0.3)
    fig.suptitle(title or f"Feed-drive power to x-force: F0 = {model.f0:.1f} N, rms error {model.rms_error:.1f} N")
    fig.tight_layout()
    return fig
