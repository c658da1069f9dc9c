"""Figure of one channel: time trace and amplitude spectrum, over frequency or wavelength (second paper, Fig. 16).

Over wavelength the spectrum's frequency axis is divided by the feed speed
(first paper, Figs. 8 and 11): a disturbance fixed in position (friction
ripple, screw lead error) shows at its wavelength whatever the feed.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from drivesense.dsp import amplitude_spectrum, dominant_wavelengths
from drivesense.errors import ConfigError
from drivesense.plot.figure import new_figure
from drivesense.recording import Recording

__all__ = ["plot_trace_spectrum"]

_MAX_POINTS = 100_000


def _envelope(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Min/max per bucket so a long trace plots fast without hiding peaks."""
    if y.size <= _MAX_POINTS:
        return t, y
    k = int(np.ceil(y.size / (_MAX_POINTS // 2)))
    n = y.size // k * k
    tt = np.repeat(t[:n:k], 2)
    yy = np.column_stack([y[:n].reshape(-1, k).min(axis=1), y[:n].reshape(-1, k).max(axis=1)]).ravel()
    return tt, yy


def plot_trace_spectrum(rec: Recording, channel: str, *, wavelength: bool = False, feed_speed: float | None = None,
                        feed_source: str = "given", max_freq: float | None = None,
                        title: str | None = None) -> Figure:
    """The channel's time trace (top) and amplitude spectrum (bottom), the three largest peaks marked.

    Parameters
    ----------
    rec : Recording
        The recording.
    channel : str
        Channel to plot (its unit labels the axes).
    wavelength : bool, optional
        Spectrum against wavelength = feed speed / frequency [mm] instead of frequency [Hz].
    feed_speed : float, optional
        Feed speed [m/s]; required with `wavelength` (e.g. from
        :func:`drivesense.cli.plot_cmd.feed_speed_of`).
    feed_source : str, optional
        Where `feed_speed` came from, shown in the wavelength axis label.
    max_freq : float, optional
        Upper end of the frequency axis [Hz] (default fs/2; not used over wavelength).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Two panels: the trace against time [s], the amplitude spectrum.

    Raises
    ------
    MissingChannelError
        The recording has no `channel`.
    ConfigError
        `wavelength` without a positive `feed_speed`.
    """
    rec.require(channel)
    if wavelength and not (feed_speed is not None and feed_speed > 0):
        raise ConfigError(f"a wavelength spectrum needs a positive feed speed in m/s, got {feed_speed!r}")
    y, unit = np.asarray(rec[channel]), rec.units(channel)
    f, amp = amplitude_spectrum(y, rec.fs)
    fig = new_figure((10, 7))
    ax_t, ax_f = fig.subplots(2, 1)
    ax_t.plot(*_envelope(rec.time, y), lw=0.7, color="tab:blue")
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel(f"{channel} [{unit}]")
    ax_t.grid(alpha=0.3)
    keep = f > 0
    flat = not np.any(amp[keep] > 0)        # a constant channel: nothing to draw on a log scale
    if flat:
        ax_f.text(0.5, 0.5, f"{channel} is constant ({y[0]:.6g} {unit}): its spectrum is zero above 0 Hz",
                  transform=ax_f.transAxes, ha="center", va="center", fontsize=9)
    if wavelength:
        lam = feed_speed / f[keep] * 1e3
        (ax_f.semilogx if flat else ax_f.loglog)(lam, amp[keep], lw=0.8, color="tab:red")
        ax_f.set_xlabel(f"wavelength = feed speed / frequency [mm]   (feed {feed_speed * 6e4:.4g} mm/min, "
                        f"{feed_source})")
        x_peak = lam
    else:
        sel = keep & (f <= (max_freq or 0.5 * rec.fs))
        (ax_f.plot if flat else ax_f.semilogy)(f[sel], amp[sel], lw=0.8, color="tab:red")
        ax_f.set_xlabel("frequency [Hz]")
        x_peak, keep = f[sel], sel
    if flat:
        ax_f.set_ylim(-0.05, 1.0)
    peaks = [] if flat else dominant_wavelengths(x_peak, amp[keep], n=3, min_separation=0.05)
    for rank, peak in enumerate(peaks):
        ax_f.annotate(f"{peak['wavelength_m']:.4g} {'mm' if wavelength else 'Hz'}",
                      (peak["wavelength_m"], peak["amplitude"]), textcoords="offset points",
                      xytext=(6, 2 - 11 * rank), fontsize=8, arrowprops={"arrowstyle": "-", "lw": 0.5})
    ax_f.set_ylabel(f"amplitude [{unit}]")
    ax_f.grid(alpha=0.3, which="both")
    fig.suptitle(title or f"{rec.name or ''} {channel}: {rec.n_samples} samples @ {rec.fs:g} Hz "
                          f"(flat-top amplitude spectrum)".strip())
    fig.tight_layout()
    return fig
