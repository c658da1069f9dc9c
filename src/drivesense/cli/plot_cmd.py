"""``drivesense plot``: time trace and amplitude spectrum of one channel in one PNG (second paper, Fig. 16).

With ``--wavelength`` the spectrum's frequency axis is divided by the feed
speed (first paper, Figs. 8 and 11): a disturbance fixed in position (friction
ripple, screw lead error) shows at its wavelength whatever the feed.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from drivesense.cli.common import console, friendly

__all__ = ["register", "plot_trace_spectrum", "feed_speed_of"]

_MAX_POINTS = 100_000


def feed_speed_of(rec, channel: str) -> tuple[float, str]:
    """Mean feed speed [m/s] of a recording, and where it came from.

    Parameters
    ----------
    rec : Recording
    channel : str
        The plotted channel; its axis letter (``x_...``, ``force_x``) picks the axis.

    Returns
    -------
    tuple of (float, str)

    Raises
    ------
    ConfigError
        No velocity or position channel and no ``condition.feed_speed`` in the metadata.
    """
    from drivesense.errors import ConfigError

    m = re.match(r"^([xyz])_|^force_([xyz])$", channel)
    axes = [m.group(1) or m.group(2)] if m else ["x", "y", "z"]
    best = None
    for ax in axes:
        for name in (f"{ax}_velocity", f"{ax}_table_position", f"{ax}_position"):
            if name in rec:
                speed, how = _moving_speed(np.asarray(rec[name]), rec.fs, name)
                if speed > 0 and (best is None or speed > best[0]):
                    best = (speed, how)
                break
    if best is None:
        cond = rec.meta.get("condition")
        if isinstance(cond, dict) and isinstance(cond.get("feed_speed"), (int, float)) and cond["feed_speed"] > 0:
            best = (float(cond["feed_speed"]), "meta condition.feed_speed")
    if best is None:
        raise ConfigError(f"--wavelength needs the feed speed: recording {rec.name!r} has no velocity or position "
                          "channel for the axis; give --feed SPEED [m/s]")
    return best


def _moving_speed(v: np.ndarray, fs: float, name: str) -> tuple[float, str]:
    """Median speed [m/s] while the axis moves (>20 % of its top speed), from ~200 block means."""
    k = max(1, v.size // 200)
    blocks = v[: v.size // k * k].reshape(-1, k).mean(axis=1)
    speed = np.abs(blocks) if name.endswith("velocity") else np.abs(np.diff(blocks)) * fs / k
    if speed.size == 0 or not np.max(speed) > 0:
        return 0.0, ""
    moving = speed[speed > 0.2 * np.max(speed)]
    return float(np.median(moving)), f"median speed of {name} while moving"


def _envelope(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Min/max per bucket so a long trace plots fast without hiding peaks."""
    if y.size <= _MAX_POINTS:
        return t, y
    k = int(np.ceil(y.size / (_MAX_POINTS // 2)))
    n = y.size // k * k
    tt = np.repeat(t[:n:k], 2)
    yy = np.column_stack([y[:n].reshape(-1, k).min(axis=1), y[:n].reshape(-1, k).max(axis=1)]).ravel()
    return tt, yy


def plot_trace_spectrum(rec, channel: str, path, *, wavelength: bool = False, feed_speed: float | None = None,
                        max_freq: float | None = None, title: str | None = None) -> Path:
    """Write a PNG: the channel's time trace (top) and amplitude spectrum (bottom).

    Parameters
    ----------
    rec : Recording
    channel : str
        Channel to plot.
    path : str or Path
        Output PNG.
    wavelength : bool, optional
        Spectrum against wavelength = feed speed / frequency [mm] instead of frequency [Hz].
    feed_speed : float, optional
        Feed speed [m/s] for `wavelength`; default :func:`feed_speed_of`.
    max_freq : float, optional
        Upper end of the frequency axis [Hz] (default fs/2).
    title : str, optional
        Figure title.

    Returns
    -------
    Path
    """
    from drivesense.dsp import amplitude_spectrum, dominant_wavelengths
    from drivesense.errors import ConfigError
    from drivesense.plot import _pyplot, _save

    rec.require(channel)
    y, unit = np.asarray(rec[channel]), rec.units(channel)
    f, amp = amplitude_spectrum(y, rec.fs)
    plt = _pyplot()
    fig, (ax_t, ax_f) = plt.subplots(2, 1, figsize=(10, 7))
    ax_t.plot(*_envelope(rec.time, y), lw=0.7, color="tab:blue")
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel(f"{channel} [{unit}]")
    ax_t.grid(alpha=0.3)
    keep = f > 0
    if wavelength:
        how = "given"
        if feed_speed is None:
            feed_speed, how = feed_speed_of(rec, channel)
        if not feed_speed > 0:
            raise ConfigError(f"--feed must be a positive speed in m/s, got {feed_speed!r}")
        lam = feed_speed / f[keep] * 1e3
        ax_f.loglog(lam, amp[keep], lw=0.8, color="tab:red")
        ax_f.set_xlabel(f"wavelength = feed speed / frequency [mm]   (feed {feed_speed * 6e4:.4g} mm/min, {how})")
        x_peak = lam
    else:
        sel = keep & (f <= (max_freq or 0.5 * rec.fs))
        ax_f.semilogy(f[sel], amp[sel], lw=0.8, color="tab:red")
        ax_f.set_xlabel("frequency [Hz]")
        x_peak, keep = f[sel], sel
    for rank, peak in enumerate(dominant_wavelengths(x_peak, amp[keep], n=3, min_separation=0.05)):
        ax_f.annotate(f"{peak['wavelength_m']:.4g} {'mm' if wavelength else 'Hz'}",
                      (peak["wavelength_m"], peak["amplitude"]), textcoords="offset points",
                      xytext=(6, 2 - 11 * rank), fontsize=8, arrowprops={"arrowstyle": "-", "lw": 0.5})
    ax_f.set_ylabel(f"amplitude [{unit}]")
    ax_f.grid(alpha=0.3, which="both")
    fig.suptitle(title or f"{rec.name or ''} {channel}: {rec.n_samples} samples @ {rec.fs:g} Hz "
                          f"(flat-top amplitude spectrum)".strip())
    return _save(plt, fig, path)


def _read(file: Path, measurement: Optional[str]):
    from drivesense.cli.common import read_trace
    from drivesense.errors import ConfigError

    if file.suffix.lower() == ".xml":
        from drivesense.io.xml_format import read_xml

        which = int(measurement) if measurement is not None and measurement.lstrip("-").isdigit() else measurement
        return read_xml(file, measurement=which)
    if measurement is not None:
        raise ConfigError("--measurement applies to .xml experiment files only")
    return read_trace(file)


def plot(
    file: Annotated[Path, typer.Argument(help="Recording (.nc, .csv) or experiment file (.xml).")],
    channel: Annotated[str, typer.Option("--channel", "-c", help="Channel to plot.")],
    out: Annotated[Optional[Path], typer.Option("--out", help="PNG (default FILE_CHANNEL.png).")] = None,
    wavelength: Annotated[bool, typer.Option("--wavelength", help="Spectrum over wavelength (divide by feed).")]
    = False,
    feed: Annotated[Optional[float], typer.Option(help="Feed speed [m/s] for --wavelength (default: from the "
                                                       "recording's velocity/position).")] = None,
    max_freq: Annotated[Optional[float], typer.Option(help="Upper frequency [Hz] of the spectrum.")] = None,
    measurement: Annotated[Optional[str], typer.Option(help="Measurement of an .xml file (name or index).")]
    = None,
) -> None:
    """Time trace and amplitude spectrum of one channel in one PNG."""
    rec = _read(file, measurement)
    out = out or file.with_name(f"{file.stem}_{channel}{'_wavelength' if wavelength else ''}.png")
    path = plot_trace_spectrum(rec, channel, out, wavelength=wavelength, feed_speed=feed, max_freq=max_freq)
    console.print(f"wrote {path}", markup=False, highlight=False)


def register(root: typer.Typer) -> None:
    """Add the ``plot`` command to the root application."""
    root.command("plot")(friendly(plot))
