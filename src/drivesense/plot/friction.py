"""Figure of friction maps from idling runs: runs against table position, and the wavelength spectrum."""

from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import numpy as np
from matplotlib.figure import Figure

from drivesense.dsp import dominant_wavelengths, wavelength_spectrum
from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.estimate.friction_map import FrictionMap

__all__ = ["plot_friction_maps"]


def plot_friction_maps(maps: "Mapping[str, FrictionMap]", *, title: str | None = None) -> Figure:
    """Each friction map's runs against table position, and its wavelength spectrum.

    The first paper's Figs. 7-11 in one figure: position dependence and
    repeatability (left), periodic components by wavelength (right).

    Parameters
    ----------
    maps : mapping of str to FrictionMap
        Maps by method name; each has ``position`` [m], ``force`` [N] (the
        mean map), ``runs`` (one force array [N] per idle run, NaN where a
        run did not reach a bin) and ``repeatability_rms`` [N].
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One row per map: friction [N] against position [mm], amplitude [N] against wavelength [mm].
    """
    fig = new_figure((11, 3.2 * len(maps)))
    axes = fig.subplots(len(maps), 2, squeeze=False)
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
    fig.tight_layout()
    return fig
