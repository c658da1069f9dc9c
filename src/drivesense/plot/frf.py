"""Figure of a frequency-response fit: measured and model FRFs (magnitude, phase) and the coherence."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.identify.frf import FRFFit

__all__ = ["plot_frf_fit"]


def plot_frf_fit(fit: "FRFFit", *, title: str | None = None) -> Figure:
    """Measured and fitted FRFs (magnitude, phase) and the coherence (the first paper's Fig. 5 style).

    Parameters
    ----------
    fit : FRFFit
        A fit and the data it was fitted to: ``fit.measured`` (``freq`` [Hz],
        complex ``motor`` and ``table`` FRFs [(m/s^2)/N], ``coherence_motor``,
        ``coherence_table``, ``reference``), ``fit.model()`` (the model FRFs
        at ``freq``) and ``fit.normalised_rms``.
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Three panels sharing the frequency axis [Hz]: magnitude, phase [deg], coherence.
    """
    meas = fit.measured
    f = meas.freq
    model_m, model_t = fit.model()
    fig = new_figure((9, 9))
    ax_mag, ax_ph, ax_coh = fig.subplots(3, 1, sharex=True, gridspec_kw={"height_ratios": [3, 2, 1]})
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
    fig.tight_layout()
    return fig
