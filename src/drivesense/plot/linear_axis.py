"""Figure of the linear-motor axis identification: cogging table and Stribeck friction curve per axis."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.identify.linear_axis import IdentificationReport

__all__ = ["plot_identification"]

_AXES = ("x", "y", "z")


def plot_identification(report: "IdentificationReport") -> Figure:
    """The identification: cogging table (top) and Stribeck curve with the segment means (bottom) per axis.

    Parameters
    ----------
    report : IdentificationReport
        Result of :func:`drivesense.identify.linear_axis.run_identification`:
        ``report.model.axis(ax)`` gives each axis (``cogging`` [N] over one
        ``pole_pitch`` [m], ``F_C``, ``F_br`` [N], ``v_s`` [m/s],
        ``friction_force(velocity [m/s])`` [N]); ``report.steps[ax]["friction"]["data"]``
        the segment means (``velocity_m_s``, ``force_n``).

    Returns
    -------
    matplotlib.figure.Figure
        A 2 x 3 grid: cogging force [N] against position modulo the pole pitch [mm],
        friction force [N] against velocity [mm/s], for x, y, z.
    """
    fig = new_figure((12, 6.5))
    panels = fig.subplots(2, 3)
    for j, ax in enumerate(_AXES):
        axis = report.model.axis(ax)
        u = np.arange(axis.cogging.size + 1) / axis.cogging.size * axis.pole_pitch
        panels[0, j].plot(u * 1e3, np.append(axis.cogging, axis.cogging[0]), color="tab:blue")
        panels[0, j].set_title(f"{ax}: cogging, 1st harmonic {axis.cogging_amplitudes(1)[0]:.1f} N", fontsize=9)
        panels[0, j].set_xlabel("position mod pole pitch [mm]")
        panels[0, j].set_ylabel("F_co [N]")
        data = report.steps[ax]["friction"].get("data", {})
        v = np.asarray(data.get("velocity_m_s", []))
        v_max = max(np.abs(v).max() if v.size else 0.1, 1e-3)
        vv = np.linspace(-v_max, v_max, 801)
        panels[1, j].plot(vv * 1e3, axis.friction_force(vv), color="tab:red", label="Eq. 4 fit")
        if v.size:
            panels[1, j].plot(v * 1e3, data["force_n"], "k.", label="segment means (Eq. 5)")
        panels[1, j].set_xscale("symlog", linthresh=1.0)
        panels[1, j].set_title(f"{ax}: F_C {axis.F_C:.1f} N, F_br {axis.F_br:.1f} N, v_s {axis.v_s * 1e3:.2g} mm/s",
                               fontsize=9)
        panels[1, j].set_xlabel("velocity [mm/s]")
        panels[1, j].set_ylabel("F_fr [N]")
        panels[1, j].legend(fontsize=7)
    fig.tight_layout()
    return fig
