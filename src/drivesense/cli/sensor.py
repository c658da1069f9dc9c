"""``drivesense sensor simulate|calibrate|apply``: cheap-sensor calibration against a reference accelerometer."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, err_console, friendly,
                                   key_column, progress_bar, save_recording, trace_reader, write_json)

__all__ = ["register", "sensor_app"]

sensor_app = typer.Typer(no_args_is_help=True,
                         help="Calibrate a cheap vibration sensor (e.g. a $1 electret) against a reference "
                              "accelerometer and use it in its place.")


def _band(text: str) -> tuple[float, float]:
    from drivesense.errors import ConfigError

    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise ConfigError(f"--band {text!r}: expected LOW:HIGH in Hz, e.g. 100:4000") from None
    return lo, hi


@sensor_app.command("simulate")
@friendly
def simulate(
    out_dir: Annotated[Path, typer.Option("--out-dir", help="Folder for the simulated recordings.")],
    levels: Annotated[str, typer.Option(help="Shaker levels [g rms], comma separated.")] = \
        "1.3,2.6,4.0,5.3,6.6",
    fmt: Annotated[str, typer.Option("--format", help="nc (lossless, compact) or csv.")] = "nc",
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Simulate shaker pairs (electret + reference) at several levels and one milling-vibration record."""
    from drivesense.errors import ConfigError
    from drivesense.sim.electret import simulate_machining_vibration, simulate_shaker_pair

    try:
        amps = [float(v) for v in levels.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--levels {levels!r}: expected numbers in g, e.g. 1.3,4,6.6") from None
    if fmt not in ("nc", "csv"):
        raise ConfigError(f"--format must be nc or csv, got {fmt!r}")
    with progress_bar() as progress:
        task = progress.add_task("simulate", total=len(amps) + 1)
        for k, a in enumerate(amps):
            path = out_dir / f"shaker_{a:g}g.{fmt}"
            save_recording(simulate_shaker_pair(a, seed=seed + k), path, parents=True)
            progress.advance(task)
        save_recording(simulate_machining_vibration(seed=seed + 100), out_dir / f"milling.{fmt}", parents=True)
        progress.advance(task)
    console.print(f"wrote {len(amps)} shaker pairs and milling.{fmt} to {out_dir} "
                  + "(channels electret [V], accel_ref [m/s^2])", markup=False)


@sensor_app.command("calibrate")
@friendly
def calibrate(
    pairs: Annotated[list[Path], typer.Argument(help="Paired recordings (.nc or .csv), ideally at several levels.")],
    out: Annotated[Path, typer.Option("--out", help="Calibration (deconvolution filter) JSON to write.")],
    sensor_channel: Annotated[str, typer.Option(help="Channel of the cheap sensor [V].")] = "electret",
    reference_channel: Annotated[str, typer.Option(help="Channel of the reference [m/s^2].")] = "accel_ref",
    band: Annotated[str, typer.Option(help="Band to restore, LOW:HIGH [Hz].")] = "100:4000",
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write a JSON summary here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write the ratio spectrum (Fig. 6 style) here.")] = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Linearity check, ratio spectrum and a regularised deconvolution filter from paired recordings."""
    from drivesense.identify.sensor import calibrate_sensor

    read_trace = trace_reader(fs, resample, assume_si, bad_samples)
    recs = [read_trace(p) for p in pairs]
    cal = calibrate_sensor(recs, band=_band(band), sensor_channel=sensor_channel,
                           reference_channel=reference_channel)
    cal.save(out)
    lin = cal.linearity
    table = Table(title=f"Sensor calibration from {len(recs)} pair(s)")
    key_column(table, "recording", [p.name for p in pairs])
    table.add_column(escape("level [g rms]"), justify="right")
    table.add_column(escape("band gain [mV/g]"), justify="right")
    for p, a, g in zip(pairs, lin.get("amplitudes_g", []), lin.get("band_gain", [])):
        table.add_row(escape(p.name), f"{a:.2f}", f"{g * 9.80665e3:.2f}")
    console.print(table)
    if lin.get("linear") is None:
        err_console.print("[bold yellow]warning:[/] one pair only: linearity not checked", highlight=False)
    elif lin["linear"]:
        console.print(f"linear: band gains agree within {100 * lin['spread']:.2f} % "
                      f"(tolerance {100 * lin['tolerance']:.0f} %)", markup=False)
    else:
        err_console.print(f"[bold yellow]warning:[/] NOT linear: band gains spread {100 * lin['spread']:.1f} % "
                          f"(> {100 * lin['tolerance']:.0f} %); the filter holds only near the levels it saw",
                          highlight=False)
    console.print(f"{cal.taps.size}-tap filter for {cal.band[0]:g}-{cal.band[1]:g} Hz at {cal.fs:g} Hz; wrote {out}",
                  markup=False)
    info = {"pairs": [str(p) for p in pairs], "filter": str(out), "fs_hz": cal.fs, "band_hz": list(cal.band),
            "taps": int(cal.taps.size), "linearity": lin}
    if plot:
        from drivesense.plot import plot_sensor_calibration, save_figure

        save_figure(plot_sensor_calibration(cal), plot)
        info["plot"] = str(plot)
        console.print(f"wrote {plot}", markup=False)
    write_json(json_path, info)


@sensor_app.command("apply")
@friendly
def apply(
    recording: Annotated[Path, typer.Argument(help="Recording (.nc or .csv) holding the cheap sensor's channel.")],
    filter_path: Annotated[Path, typer.Option("--filter", help="Calibration JSON from 'sensor calibrate'.")],
    out: Annotated[Path, typer.Option("--out", help="Output recording (.nc or .csv) with the acceleration.")],
    sensor_channel: Annotated[str, typer.Option(help="Channel of the cheap sensor [V].")] = "electret",
    reference_channel: Annotated[str, typer.Option(help="Reference channel, if present, to score against.")] =
    "accel_ref",
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write a JSON summary here.")] = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Deconvolve the cheap sensor's signal into acceleration in m/s^2 (channel 'acceleration')."""
    import numpy as np

    from drivesense.identify.sensor import SensorCalibration, deconvolution_residual

    cal = SensorCalibration.load(filter_path)
    rec = trace_reader(fs, resample, assume_si, bad_samples)(recording)
    result = cal.apply(rec, channel=sensor_channel)
    save_recording(result, out)
    acc = result["acceleration"]
    info = {"recording": str(recording), "filter": str(filter_path), "output": str(out),
            "acceleration_rms_m_s2": float(np.std(acc))}
    console.print(f"acceleration rms {np.std(acc):.3g} m/s^2 ({np.std(acc) / 9.80665:.3g} g); wrote {out}",
                  markup=False)
    if reference_channel in rec.channels:
        res = deconvolution_residual(cal, rec[sensor_channel], rec[reference_channel], fs=rec.fs)
        info["residual_vs_reference"] = res
        console.print(f"against {reference_channel}: residual {100 * res:.2f} % of the reference rms in "
                      f"{cal.band[0]:g}-{cal.band[1]:g} Hz", markup=False)
    write_json(json_path, info)


def register(root: typer.Typer) -> None:
    """Add the ``sensor`` command group to the root application."""
    root.add_typer(sensor_app, name="sensor")
