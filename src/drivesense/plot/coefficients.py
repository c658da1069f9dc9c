"""Figure of the K_tc / K_te calibration: F_t/a against h_avg with the regression line (second paper, Fig. 4)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.identify.coefficients import TangentialFit

__all__ = ["plot_calibration"]


def plot_calibration(fit: "TangentialFit", *, title: str | None = None) -> Figure:
    """The calibration regression, F_t/a [N/mm] against h_avg [mm] (the second paper's Fig. 4 style).

    Parameters
    ----------
    fit : TangentialFit
        The fit and its data: ``h_avg`` [m], ``force_per_depth`` [N/m],
        ``Ktc`` [N/m^2], ``Kte`` [N/m], their standard errors, ``r2``,
        ``correlation``, ``see_saw``, ``n`` and ``predict(h_avg [m])`` [N/m].
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One panel: the calibration cuts, the fitted line and the coefficients.
    """
    fig = new_figure((7, 5))
    ax = fig.subplots()
    h = fit.h_avg * 1e3
    ax.plot(h, fit.force_per_depth * 1e-3, "o", color="tab:blue", label="calibration cuts")
    hx = np.linspace(0.0, h.max() * 1.1, 100)
    ax.plot(hx, fit.predict(hx * 1e-3) * 1e-3, color="black", lw=1.2,
            label=f"F_t/a = {fit.Ktc * 1e-6:.0f} h_avg + {fit.Kte * 1e-3:.1f}")
    text = (f"K_tc = {fit.Ktc * 1e-6:.1f} ± {fit.Ktc_se * 1e-6:.2g} N/mm²\n"
            f"K_te = {fit.Kte * 1e-3:.2f} ± {fit.Kte_se * 1e-3:.2g} N/mm\n"
            f"R² = {fit.r2:.4f}, corr(K_tc, K_te) = {fit.correlation:+.3f}")
    if fit.see_saw:
        text += "\nsee-saw: h_avg span too small"
    ax.text(0.03, 0.97, text, transform=ax.transAxes, va="top", fontsize=9,
            color="tab:red" if fit.see_saw else "black",
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"})
    ax.set_xlabel("average chip thickness h_avg [mm]")
    ax.set_ylabel("average tangential force per depth F_t/a [N/mm]")
    ax.set_xlim(0, None)
    ax.set_ylim(0, None)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title or f"Tangential force model calibration ({fit.n} cuts, Eq. 5)")
    fig.tight_layout()
    return fig
