"""``drivesense detect`` (process events in a trace) and ``drivesense teach`` (teach-in limits from good runs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, build_estimator, check_output,
                                   console, friendly, parse_window, trace_reader, warn, write_json)

__all__ = ["register"]

AxisOpt = Annotated[Optional[Path], typer.Option("--axis", help="AXIS.toml with [axis] and [signal] (ball screw).")]
MethodOpt = Annotated[str, typer.Option(help="current | rigid | medob | vibration (--axis); model (--axes); "
                                             "lstm | hybrid (--model)")]
IdleOpt = Annotated[Optional[list[Path]], typer.Option(help="Idle (air-cut) run(s) for the friction map.")]
TareOpt = Annotated[Optional[str], typer.Option(help="START:END [s] of a tare window (standing axis).")]
AxisNameOpt = Annotated[str, typer.Option("--axis-name", help="Axis letter of the channels.")]
AxesOpt = Annotated[Optional[Path], typer.Option("--axes", help="AXES.toml (linear-motor X/Y/Z) for --method model.")]
ModelOpt = Annotated[Optional[Path], typer.Option("--model", help="Trained model folder for --method lstm|hybrid.")]
SpindleRpmOpt = Annotated[Optional[float], typer.Option("--spindle-rpm", help="Spindle speed [min^-1] when the trace "
                                                        "has no spindle_speed column.")]
TeethOpt = Annotated[Optional[int], typer.Option("--teeth", help="Number of teeth (flutes) of the tool: the breakage "
                                                 "detector needs it (default: the trace's tool, when it names one, "
                                                 "else read from the force's tooth-passing line; breakage is off "
                                                 "when that is not clear).")]
LimitsOpt = Annotated[Optional[Path], typer.Option("--limits", help="LIMITS.json from 'drivesense teach'.")]
ForceLimitOpt = Annotated[Optional[float], typer.Option("--force-limit", help="Collision/overload limit [N] "
                                                        "(default: the taught one).")]


def check_detector_options(*, spindle_rpm: Optional[float] = None, teeth: Optional[int] = None,
                           baseline_revs: Optional[int] = None, force_limit: Optional[float] = None) -> None:
    """Refuse ``--spindle-rpm`` <= 0, ``--teeth`` < 1, ``--baseline-revs`` < 3 and ``--force-limit`` <= 0
    (``detect``, ``batch detect``, ``monitor --replay``) before any work, naming the option."""
    from drivesense.events.pipeline import check_detector_settings

    check_detector_settings(spindle_rpm=spindle_rpm, teeth=teeth, baseline_revs=baseline_revs,
                            force_limit_n=force_limit)


def _teeth_line(choice) -> str:
    """``2 (--teeth)``, ``2 (tool metadata)`` or ``2 (inferred from the spectrum: ... line at ... Hz ...)``."""
    ev = choice.evidence
    if "tooth_passing_hz" not in ev:
        return f"{choice.teeth} ({choice.source})"
    return (f"{choice.teeth} ({choice.source}: {ev['channel']}'s line at {ev['tooth_passing_hz']:.1f} Hz = "
            f"{choice.teeth} x the spindle's {ev['spindle_hz']:.2f} Hz, {ev['dominance']:g}x the strongest other "
            f"order; {choice.teeth} equal pitches explain {100 * ev['pitch_share']:.0f} % of a revolution's pattern; "
            f"--teeth N overrides)")


def _forces(trace: Path, read, est, method: str, idle, tare, axis_name: str):
    """The trace and the detector inputs (estimated forces + spindle speed, feed, positions)."""
    from drivesense.events.pipeline import detector_inputs
    from drivesense.monitor.config import fit_or_tare

    rec = read(trace, axis_name) if est.drive == "ballscrew" else read(trace)
    fit_or_tare(est, method, idle_runs=(lambda: [read(p, axis_name) for p in idle]) if idle else None,
                tare=parse_window(tare) if tare else None, trace=rec)
    forces = est.estimate(rec)
    return rec, detector_inputs(rec, forces)


def register(app: typer.Typer) -> None:
    """Add ``detect`` and ``teach`` to the root app."""

    @app.command()
    @friendly
    def detect(
        trace: Annotated[Path, typer.Argument(help="CSV (name [unit] header), .nc or .xml trace.")],
        json_path: Annotated[Path, typer.Option("--json", help="Write EVENTS.json here.")],
        axis_file: AxisOpt = None,
        method: MethodOpt = "vibration",
        idle: IdleOpt = None,
        tare: TareOpt = None,
        spindle_rpm: SpindleRpmOpt = None,
        teeth: TeethOpt = None,
        limits: LimitsOpt = None,
        force_limit: ForceLimitOpt = None,
        baseline_revs: Annotated[int, typer.Option("--baseline-revs", help="Revolutions of each cut the breakage "
                                                   "detector learns its baseline over.")] = 8,
        plot: Annotated[Optional[Path], typer.Option(help="Write a PNG: force, detector statistics, thresholds "
                                                          "and events on one time axis.")] = None,
        axis_name: AxisNameOpt = "x",
        axes_file: AxesOpt = None,
        model_dir: ModelOpt = None,
        assume_si: AssumeSiOpt = False,
        fs: FsOpt = None,
        resample: ResampleOpt = None,
        bad_samples: BadSamplesOpt = None,
    ) -> None:
        """Detect process events (breakage, chipping, chatter, collision, overload, missing tool, teach-in limits)."""
        from drivesense.io import read_json_file
        from drivesense.events import TeachLimits
        from drivesense.events.detector import events_to_json
        from drivesense.events.pipeline import detect_in_trace, estimate_limits
        from drivesense.nc_context import CONTEXT_CHANNELS

        check_output(json_path, "--json")
        if plot is not None:
            check_output(plot, "--plot")
        check_detector_options(spindle_rpm=spindle_rpm, teeth=teeth, baseline_revs=baseline_revs,
                               force_limit=force_limit)
        taught = None if limits is None else TeachLimits.from_json(read_json_file(limits, "--limits file"))
        est = build_estimator(method, axis_file=axis_file, axes_file=axes_file, model_dir=model_dir,
                              axis_name=axis_name)
        read = trace_reader(fs, resample, assume_si, bad_samples)
        rec, inputs = _forces(trace, read, est, method, idle, tare, axis_name)
        found = detect_in_trace(rec, inputs, **estimate_limits(est), teeth=teeth, spindle_rpm=spindle_rpm, limits=taught, force_limit_n=force_limit,
                                baseline_revs=baseline_revs)
        report, detectors = found.report, found.detectors
        for note in found.notes:
            warn(note)
        payload = events_to_json(report.events, report.latency_s)
        context = [c for c in CONTEXT_CHANNELS if c in inputs.channels]
        payload.update({"trace": str(trace), "method": method, **found.to_json(),
                        "estimator_latency_s": float(inputs.meta["latency_s"]),
                        "guards": {"nc_context": context, "feed_speed": "feed_speed" in inputs.channels}})
        write_json(json_path, payload)
        if plot is not None:
            from drivesense.plot import plot_events, save_figure

            truth = rec.meta.get("truth", {}).get("events") if isinstance(rec.meta.get("truth"), dict) else None
            first = next(c for c in inputs.channels if c.startswith("force_"))
            save_figure(plot_events(inputs, report, channel=first, truth=truth,
                                    title=f"{trace.name}: {len(report.events)} event(s)"), plot)
        table = Table(title=escape(f"events in {trace.name} ({method})"))
        for col in ("time [s]", "kind", "axis", "confidence", "evidence"):
            table.add_column(col)
        for e in report.events:
            ev = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in e.evidence.items())
            table.add_row(f"{e.time_s:.4f}", e.kind, e.axis, f"{e.confidence:.2f}", escape(ev))
        console.print(table)
        if found.teeth_choice is not None and found.teeth is not None:
            console.print(f"teeth: {_teeth_line(found.teeth_choice)}", markup=False)
        console.print("guards: the NC's context (" + ", ".join(context) + ") and the path speed" if context else
                      "guards: the path speed and the force alone (the trace has no NC context channels: tool, "
                      "block, overrides, execution state, in-cut flag)", markup=False)
        console.print(f"{len(report.events)} event(s); declared latency {report.latency_s * 1e3:.1f} ms "
                      f"(detectors: {', '.join(d.name for d in detectors)})", markup=False)

    @app.command()
    @friendly
    def teach(
        traces: Annotated[list[Path], typer.Argument(help="Good runs of one NC program (CSV, .nc or .xml).")],
        out: Annotated[Path, typer.Option("--out", help="Write LIMITS.json here.")],
        axis_file: AxisOpt = None,
        method: MethodOpt = "vibration",
        idle: IdleOpt = None,
        tare: TareOpt = None,
        align: Annotated[str, typer.Option(help="auto | time | path | block: bins of program time, of "
                                                "tool-path length (a feed override does not shift them), or per "
                                                "tool and block of the NC program (needs the block_number "
                                                "channel); auto: block, else path, else time.")] = "auto",
        bin_width: Annotated[Optional[float], typer.Option("--bin-width", help="Bin width [s] (time) or [mm] "
                                                           "(path, block); default 0.05 s or 0.5 mm.")] = None,
        tolerance: Annotated[float, typer.Option(help="Relative widening of the runs' range [-].")] = 0.3,
        axis_name: AxisNameOpt = "x",
        axes_file: AxesOpt = None,
        model_dir: ModelOpt = None,
        assume_si: AssumeSiOpt = False,
        fs: FsOpt = None,
        resample: ResampleOpt = None,
        bad_samples: BadSamplesOpt = None,
    ) -> None:
        """Learn teach-in bands (force and spindle power) from good runs of one NC program."""
        from drivesense.io import write_json_file
        from drivesense.events import teach as teach_limits

        check_output(out, "--out")
        est = build_estimator(method, axis_file=axis_file, axes_file=axes_file, model_dir=model_dir,
                              axis_name=axis_name)
        read = trace_reader(fs, resample, assume_si, bad_samples)
        runs = [_forces(t, read, est, method, idle, tare, axis_name)[1] for t in traces]
        # bins of time where asked for or where the runs have no table positions, else of path [mm -> m]
        per_time = align == "time" or not all(any(c.endswith("_table_position") for c in r.channels) for r in runs)
        width = None if bin_width is None else (bin_width if per_time else bin_width * 1e-3)
        limits = teach_limits(runs, align=align, bin_width=width, tolerance=tolerance)
        write_json_file(out, limits.to_json())
        unit = "s" if limits.unit == "s" else "mm"
        shown = limits.bin_width if limits.unit == "s" else limits.bin_width * 1e3
        per_block = f" in {len(limits.segments)} block visit(s)" if limits.align == "block" else ""
        console.print(f"taught {limits.runs} runs: {limits.bins} bins of {shown:g} {unit} ({limits.align}"
                      f"{per_block}), "
                      f"channels {', '.join(limits.channels)}; collision/overload limit "
                      f"{limits.force_limit_n:.1f} N; wrote {out}", markup=False)
