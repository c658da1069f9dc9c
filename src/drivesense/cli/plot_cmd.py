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

from drivesense.cli.common import AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly, trace_reader

__all__ = ["register", "feed_speed_of"]


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


def _read(file: Path, measurement: Optional[str], read_trace):
    from drivesense.errors import ConfigError

    if file.suffix.lower() == ".xml":
        from drivesense.io.xml_format import read_xml

        which = int(measurement) if measurement is not None and measurement.lstrip("-").isdigit() else measurement
        return read_xml(file, measurement=which)
    if measurement is not None:
        raise ConfigError("--measurement applies to .xml experiment files only")
    return read_trace(file)


def _channel_name(rec, channel: str, axis_name: str) -> str:
    """The recording's channel for ``--channel``: a bare axis name (``current_ref``) gets the ``--axis-name``
    prefix, as ``estimate`` reads it."""
    from drivesense.io.csv import BARE_AXIS_CHANNELS

    if channel not in rec.channels and channel in BARE_AXIS_CHANNELS:
        return f"{axis_name}_{channel}"
    return channel


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
    axis_name: Annotated[str, typer.Option("--axis-name", help="Axis letter of bare channel names "
                                                               "(-c current_ref plots x_current_ref).")] = "x",
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Time trace and amplitude spectrum of one channel in one PNG."""
    from functools import partial

    from drivesense.errors import ConfigError
    from drivesense.plot import plot_trace_spectrum, save_figure

    rec = _read(file, measurement, partial(trace_reader(fs, resample, assume_si, bad_samples), axis_name=axis_name))
    channel = _channel_name(rec, channel, axis_name)
    out = out or file.with_name(f"{file.stem}_{channel}{'_wavelength' if wavelength else ''}.png")
    rec.require(channel)
    how = "given"
    if wavelength:
        if feed is None:
            feed, how = feed_speed_of(rec, channel)
        if not feed > 0:
            raise ConfigError(f"--feed must be a positive speed in m/s, got {feed!r}")
    fig = plot_trace_spectrum(rec, channel, wavelength=wavelength, feed_speed=feed, feed_source=how,
                              max_freq=max_freq)
    path = save_figure(fig, out)
    console.print(f"wrote {path}", markup=False, highlight=False)


def register(root: typer.Typer) -> None:
    """Add the ``plot`` command to the root application."""
    root.command("plot")(friendly(plot))
