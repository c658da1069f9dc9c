"""Figure of the cheap-sensor calibration: ratio spectrum per shaker level, phase, coherence, inverse filter."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.plot.figure import new_figure
from drivesense.units import unit_info

if TYPE_CHECKING:
    from drivesense.identify.sensor import SensorCalibration

__all__ = ["plot_sensor_calibration"]

_G = unit_info("g").factor  # standard gravity [m/s^2]


def plot_sensor_calibration(calibration: "SensorCalibration", *, title: str | None = None) -> Figure:
    """Amplitude ratio per pair (the second paper's Fig. 6 style), phase, coherence and the inverse filter's gain.

    Parameters
    ----------
    calibration : SensorCalibration
        The calibration: ``freq`` [Hz], ``per_pair`` ratio magnitudes and the
        pooled complex ``response`` [V/(m/s^2)], ``coherence``, ``taps`` (the
        inverse FIR filter [(m/s^2)/V]), ``band`` [Hz], ``fs`` [Hz] and ``linearity``.
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Three panels sharing the frequency axis [Hz]: sensor / reference [mV/g] with the
        inverse filter [g/V], phase [deg], coherence; the calibrated band shaded.
    """
    cal = calibration
    f = cal.freq
    sel = f <= min(1.25 * cal.band[1], 0.5 * cal.fs)
    fig = new_figure((9, 9))
    ax_a, ax_p, ax_c = fig.subplots(3, 1, sharex=True, gridspec_kw={"height_ratios": [3, 2, 1]})
    amps = cal.linearity.get("amplitudes_g", [None] * len(cal.per_pair))
    for mag, amp in zip(cal.per_pair, amps):
        ax_a.plot(f[sel], mag[sel] * _G * 1e3, lw=0.7, label=f"{amp:.1f} g" if amp else None)
    ax_a.plot(f[sel], np.abs(cal.response[sel]) * _G * 1e3, color="black", lw=1.3, label="pooled")
    inv = np.abs(np.fft.rfft(cal.taps, n=2 * (f.size - 1)))
    ax_i = ax_a.twinx()
    ax_i.plot(f[sel], inv[sel] / _G, color="tab:gray", ls="--", lw=1, label="inverse filter")
    ax_i.set_ylabel("inverse filter [g/V]", color="tab:gray")
    ax_a.set_ylabel("sensor / reference [mV/g]")
    ax_a.legend(fontsize=8, loc="upper left", title="shaker level", title_fontsize=8)
    ax_p.plot(f[sel], np.degrees(np.angle(cal.response[sel])), color="black", lw=1)
    ax_p.set_ylabel("phase [deg]")
    ax_c.plot(f[sel], cal.coherence[sel], color="tab:green", lw=1)
    ax_c.set_ylabel("coherence")
    ax_c.set_ylim(0, 1.05)
    ax_c.set_xlabel("frequency [Hz]")
    for ax in (ax_a, ax_p, ax_c):
        ax.axvspan(*cal.band, color="tab:blue", alpha=0.06)
        ax.grid(alpha=0.3)
    lin = cal.linearity
    note = "" if lin.get("linear") is None else (f"; gain spread {100 * lin['spread']:.1f} % over "
                                                 f"{min(amps):.1f}-{max(amps):.1f} g: "
                                                 + ("linear" if lin["linear"] else "NOT linear"))
    fig.suptitle(title or f"Cheap-sensor calibration (ratio spectrum, Fig. 6){note}")
    fig.tight_layout()
    return fig
