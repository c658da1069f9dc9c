"""Figure of a tool-wear session: K_tc, K_te and the power increase against cut distance (second paper, Fig. 11)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.condition.wear import WearReport

__all__ = ["plot_wear_track"]

_STATE_COLOURS = {"new": "#e8f5e9", "progressing": "#fff8e1", "near end of life": "#ffebee"}


def plot_wear_track(report: "WearReport", *, truth: dict | None = None, failure_distance: float | None = None,
                    title: str | None = None) -> Figure:
    """The coefficients against cut distance (the second paper's Fig. 11 style) with the state and the percent power.

    Parameters
    ----------
    report : WearReport
        The tracked session: ``states`` (each with ``distance`` [m], ``Ktc``,
        ``Ktc_se`` [N/m^2], ``Kte``, ``Kte_se`` [N/m], ``force_ref`` [N],
        ``percent_power`` [%] or None, ``state``), ``h_ref`` [m],
        ``alarm_distance`` [m] or None, ``name``, ``state``, ``mode``.
    truth : dict, optional
        Simulated truth per calibration (``distance`` [m], ``Ktc`` [N/m^2], ``Kte`` [N/m]) to overlay.
    failure_distance : float, optional
        Where the tool failed [m] (a vertical line).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Three panels sharing the cut distance [m]: K_tc [N/mm²], K_te [N/mm], power increase [%];
        the background shaded by the wear state.
    """
    st = report.states
    d = np.array([s.distance for s in st])
    fig = new_figure((9, 9))
    ax_tc, ax_te, ax_p = fig.subplots(3, 1, sharex=True)
    ax_tc.errorbar(d, [s.Ktc * 1e-6 for s in st], [s.Ktc_se * 1e-6 for s in st], fmt="o-", color="tab:red",
                   ms=4, lw=1, capsize=2, label="K_tc (calibrated)")
    ax_te.errorbar(d, [s.Kte * 1e-3 for s in st], [s.Kte_se * 1e-3 for s in st], fmt="s-", color="tab:blue",
                   ms=4, lw=1, capsize=2, label="K_te (calibrated)")
    if truth is not None:
        ax_tc.plot(truth["distance"], np.asarray(truth["Ktc"]) * 1e-6, color="0.4", ls="--", lw=1, label="truth")
        ax_te.plot(truth["distance"], np.asarray(truth["Kte"]) * 1e-3, color="0.4", ls="--", lw=1, label="truth")
    pct = [(s.distance, s.percent_power) for s in st if s.percent_power is not None]
    if pct:
        ax_p.plot(*zip(*pct), "d-", color="tab:purple", ms=4, lw=1, label="reference cut")
    ax_p.plot(d, [100 * (s.force_ref / st[0].force_ref - 1) for s in st], color="tab:green", lw=1,
              label=f"F_ref at h = {report.h_ref * 1e3:.3g} mm")
    edges = np.concatenate([[d[0]], 0.5 * (d[1:] + d[:-1]), [d[-1]]]) if len(d) > 1 else np.array([d[0], d[0] + 1])
    for ax in (ax_tc, ax_te, ax_p):
        for s, a, b in zip(st, edges[:-1], edges[1:]):
            ax.axvspan(a, b, color=_STATE_COLOURS[s.state], lw=0)
        if report.alarm_distance is not None:
            ax.axvline(report.alarm_distance, color="tab:red", lw=1.5, ls=":")
        if failure_distance is not None:
            ax.axvline(failure_distance, color="black", lw=1.5)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    ax_tc.set_ylabel("K_tc [N/mm²]")
    ax_te.set_ylabel("K_te [N/mm]")
    ax_p.set_ylabel("power increase [%]")
    ax_p.set_xlabel("cut distance [m]   (green: new, yellow: progressing, red: near end of life; "
                    "dotted: alarm" + (", black: failure)" if failure_distance is not None else ")"))
    fig.suptitle(title or f"{report.name}: {report.state}, mode {report.mode}"
                 + (f", alarm at {report.alarm_distance:.3g} m" if report.alarm_distance is not None else ""))
    fig.tight_layout()
    return fig
