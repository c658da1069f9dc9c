"""``drivesense wear simulate|calibrate|track``: cutting coefficients from spindle power, tool-wear tracking."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import console, friendly, key_column, progress_bar, warn, write_json

__all__ = ["register", "wear_app"]

wear_app = typer.Typer(no_args_is_help=True,
                       help="Tool wear from spindle power: calibrate K_tc/K_te, track a tool's life, simulate one.")

_TABLE_HELP = ("CSV, one cut per row, 'name [unit]' headers: spindle_speed [rpm], axial_depth [mm], "
               "feed_per_tooth [mm] (or feed_speed [mm/min]), radial_depth [mm] (or entry_angle/exit_angle [deg]), "
               "spindle_power and air_power [W] (or cutting_power), diameter [mm] and flutes (or the options).")


def _read(path: Path, diameter: Optional[float], flutes: Optional[int], mode: str):
    from drivesense.identify.coefficients import read_cut_table

    return read_cut_table(path, diameter=None if diameter is None else diameter * 1e-3, flutes=flutes, mode=mode)


def _write_session(life, path: Path) -> Path:
    """Write a simulated tool life as a session CSV in shop units (what a user's logger would give).

    The CSV starts with its header (other tools read it with their defaults); what it is goes into the
    metadata sidecar ``SESSION.csv.json``.
    """
    from drivesense.io import write_json_file, write_text_file
    from drivesense.io.csv import sidecar_path

    exp, t = life.experiment, life.table
    head = ["calibration", "distance [m]", "diameter [mm]", "flutes", "axial_depth [mm]", "spindle_speed [rpm]",
            "feed_per_tooth [mm]", "entry_angle [deg]", "exit_angle [deg]", "spindle_power [W]", "air_power [W]"]
    from drivesense.sim.tool_life import PASS_LENGTH

    about = {"name": path.stem, "source": f"drivesense wear simulate: experiment {exp.name} of the paper's Table 1 "
             f"({exp.tool_material}, {exp.flutes} flute(s), calibrating on {exp.calibration_material})",
             "seed": life.seed, "rows": "one per calibration cut: mean spindle power in the cut and in the air cut "
                                        "before it"}
    if not exp.continuous:        # what 'wear track' counts the next calibration in
        about.update(cut_length_m=PASS_LENGTH, calibration_interval_m=exp.calibration_interval)
    lines = [",".join(head)]
    for c, k, d, sp, ap in zip(t.cuts, t.calibration, t.distance, life.spindle_power, life.air_power):
        lines.append(",".join([str(int(k)), f"{d:.6g}", f"{c.diameter * 1e3:.6g}", str(c.flutes),
                               f"{c.axial_depth * 1e3:.6g}", f"{c.spindle_speed * 30 / math.pi:.6g}",
                               f"{c.feed_per_tooth * 1e3:.6g}", f"{math.degrees(c.entry_angle):.6g}",
                               f"{math.degrees(c.exit_angle):.6g}", f"{sp:.6g}", f"{ap:.6g}"]))
    write_text_file(path, "\n".join(lines) + "\n")
    write_json_file(sidecar_path(path), about)
    return path


@wear_app.command("simulate")
@friendly
def simulate(
    experiment: Annotated[Optional[str], typer.Argument(help="Table 1 experiment: A..H.")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", help="Session CSV to write.")] = None,
    seed: Annotated[int, typer.Option(help="Random seed (the tool and the noise).")] = 0,
    list_: Annotated[bool, typer.Option("--list", help="List the experiments.")] = False,
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the simulated truth as JSON here.")] = None,
) -> None:
    """Simulate one tool life of the paper's Table 1 and write its calibration session (spindle power per cut)."""
    from drivesense.errors import ConfigError
    from drivesense.sim.tool_life import simulate_tool_life, table1_experiments

    if list_:
        table = Table(title="Table 1 tool-wear experiments")
        experiments = table1_experiments()
        key_column(table, "exp", list(experiments))
        for col in ("tool", "D [mm]", "flutes", "rpm", "feeds [mm]", "entry/exit [deg]", "calib. every [m]",
                    "paper mode"):
            table.add_column(escape(col), overflow="fold")
        for e in experiments.values():
            table.add_row(e.name, e.tool_material, f"{e.diameter * 1e3:.4g}", str(e.flutes),
                          f"{e.spindle_speed * 30 / math.pi:.0f}", " ".join(f"{f * 1e3:.3g}" for f in e.feeds),
                          " ".join(f"{math.degrees(a):.0f}/{math.degrees(b):.0f}" for a, b in e.angles),
                          "continuous" if e.continuous else f"{e.calibration_interval:g}", e.paper_mode)
        console.print(table)
        return
    if experiment is None or out is None:
        raise ConfigError("give an EXPERIMENT (A..H) and --out SESSION.csv (or --list)")
    life = simulate_tool_life(experiment, seed)
    _write_session(life, out)
    console.print(f"wrote {out}: experiment {life.experiment.name}, {len(life.truth['distance'])} calibrations, "
                  f"{len(life.table)} cuts; the tool failed at {life.failure_distance:.3g} m ({life.failure_mode})",
                  markup=False)
    write_json(json_path, {"experiment": life.experiment.name, "seed": seed, "session": str(out),
                           "failure_distance_m": life.failure_distance, "failure_mode": life.failure_mode,
                           "chips": [{"distance_m": d, "depth_m": s} for d, s in life.chips],
                           "truth": {k: v.tolist() for k, v in life.truth.items()}})


def _runout(offset_um, phase_deg, helix_deg):
    """The measured runout of the options (None without --runout-um)."""
    if offset_um is None:
        return None
    import math

    from drivesense.machine.tool_runout import ToolRunout

    return ToolRunout(offset_um * 1e-6, math.radians(phase_deg), helix_deg)


@wear_app.command("calibrate")
@friendly
def calibrate(
    cuts: Annotated[Path, typer.Argument(help=_TABLE_HELP)],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the fit as JSON here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write the regression figure (Fig. 4 style) here.")] = None,
    diameter: Annotated[Optional[float], typer.Option(help="Tool diameter [mm] if the table has none.")] = None,
    flutes: Annotated[Optional[int], typer.Option(help="Number of flutes if the table has none.")] = None,
    mode: Annotated[str, typer.Option(help="up | down: milling mode of radial_depth rows.")] = "down",
    calibration: Annotated[Optional[int], typer.Option(help="Use only this calibration number of a session.")] = None,
    runout_um: Annotated[Optional[float], typer.Option("--runout-um", help="Measured tool runout (axis offset) "
                                                       "[um]: flutes that lose contact stop rubbing.")] = None,
    runout_phase_deg: Annotated[float, typer.Option(help="Direction of the runout from flute 1 [deg].")] = 0.0,
    helix_deg: Annotated[float, typer.Option(help="Helix angle of the tool [deg] (with --runout-um).")] = 30.0,
) -> None:
    """Calibrate K_tc and K_te: regression of F_t/a (from spindle minus air-cut power, Eq. 5) on h_avg (Eq. 4)."""
    import numpy as np

    from drivesense.errors import ConfigError
    from drivesense.identify.coefficients import SeeSawWarning, fit_cut_table

    table = _read(cuts, diameter, flutes, mode)
    idx = np.arange(len(table))
    if table.calibration is not None:
        numbers = sorted(set(int(k) for k in table.calibration))
        if calibration is None and len(numbers) > 1:
            raise ConfigError(f"{cuts.name} holds {len(numbers)} calibrations ({numbers[0]}..{numbers[-1]}): "
                              "choose one with --calibration N, or follow the tool with 'drivesense wear track'")
        if calibration is not None:
            if calibration not in numbers:
                raise ConfigError(f"--calibration {calibration}: {cuts.name} has calibrations {numbers}")
            idx = np.flatnonzero(table.calibration == calibration)
    elif calibration is not None:
        raise ConfigError(f"--calibration {calibration}: {cuts.name} has no 'calibration' column")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SeeSawWarning)
        fit = fit_cut_table(table, idx, runout=_runout(runout_um, runout_phase_deg, helix_deg))
    out = Table(title=escape(f"Tangential force model from {len(idx)} cuts of {cuts.name}"), show_header=False)
    out.add_row("K_tc (cutting)", f"{fit.Ktc * 1e-6:.1f} ± {fit.Ktc_se * 1e-6:.2g} N/mm²")
    out.add_row("K_te (edge)", f"{fit.Kte * 1e-3:.2f} ± {fit.Kte_se * 1e-3:.2g} N/mm")
    out.add_row("corr(K_tc, K_te)", f"{fit.correlation:+.3f}")
    out.add_row("R² / residual", f"{fit.r2:.4f} / {fit.rmse * 1e-3:.3g} N/mm")
    out.add_row("h_avg range", f"{fit.h_avg.min() * 1e3:.4g} - {fit.h_avg.max() * 1e3:.4g} mm")
    console.print(out)
    for note in fit.warnings:
        warn(note)
    info = {"table": str(cuts), "cuts": [int(i) for i in idx], **fit.to_dict()}
    if plot:
        from drivesense.plot import plot_calibration, save_figure

        save_figure(plot_calibration(fit, title=f"K_tc / K_te calibration: {cuts.name}"), plot)
        info["plot"] = str(plot)
        console.print(f"wrote {plot}", markup=False)
    write_json(json_path, info)


@wear_app.command("track")
@friendly
def track(
    session: Annotated[Path, typer.Argument(help=_TABLE_HELP + " Plus 'calibration' and/or 'distance [m]'.")],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the wear history as JSON here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write the coefficient history (Fig. 11 style) here.")] = None,
    diameter: Annotated[Optional[float], typer.Option(help="Tool diameter [mm] if the table has none.")] = None,
    flutes: Annotated[Optional[int], typer.Option(help="Number of flutes if the table has none.")] = None,
    mode: Annotated[str, typer.Option(help="up | down: milling mode of radial_depth rows.")] = "down",
    reference: Annotated[Optional[int], typer.Option(help="Cut (0-based, in the first calibration) for the "
                                                          "percent-power indicator; default its middle cut.")] = None,
    runout_um: Annotated[Optional[float], typer.Option("--runout-um", help="Measured tool runout (axis offset) "
                                                       "[um] for every calibration.")] = None,
    runout_phase_deg: Annotated[float, typer.Option(help="Direction of the runout from flute 1 [deg].")] = 0.0,
    helix_deg: Annotated[float, typer.Option(help="Helix angle of the tool [deg] (with --runout-um).")] = 30.0,
    interval: Annotated[Optional[float], typer.Option(help="Your fixed calibration interval [m of cutting]; "
                                                           "default: the session's median spacing.")] = None,
    cut_length: Annotated[Optional[float], typer.Option(help="Cutting distance per cut (part, pass) [mm], to "
                                                             "count the next calibration in cuts; default: the "
                                                             "session's metadata.")] = None,
) -> None:
    """Track tool wear through a session: state, dominant mode (flank / chipping), end-of-life alarm, and
    when to calibrate next (sooner when the wear speeds up or jumps)."""
    from drivesense.errors import ConfigError
    from drivesense.condition.wear import WearTracker, track_wear

    for name, value in (("--interval", interval), ("--cut-length", cut_length)):
        if value is not None and (not math.isfinite(value) or value <= 0):
            raise ConfigError(f"{name} must be > 0, got {value!r}")
    table = _read(session, diameter, flutes, mode)
    with progress_bar() as progress:
        task = progress.add_task("calibrations", total=len(table.groups()))
        report = track_wear(table, reference=reference, runout=_runout(runout_um, runout_phase_deg, helix_deg))
        progress.update(task, completed=len(report.states))
    colour = {"new": "green", "progressing": "yellow", "near end of life": "bold red"}
    out = Table(title=escape(f"Wear history of {session.name}"))
    for col in ("#", "distance [m]", "K_tc [N/mm²]", "K_te [N/mm]", "power +%"):
        out.add_column(escape(col), justify="right", overflow="fold")
    key_column(out, "state", [s.state for s in report.states])   # the keys: never cut
    key_column(out, "mode", [s.mode for s in report.states])
    for s in report.states:
        pct = "" if s.percent_power is None else f"{s.percent_power:+.0f}"
        out.add_row(str(s.index), f"{s.distance:.3g}", f"{s.Ktc * 1e-6:.0f} ± {s.Ktc_se * 1e-6:.0f}",
                    f"{s.Kte * 1e-3:.1f} ± {s.Kte_se * 1e-3:.1f}", pct, f"[{colour[s.state]}]{s.state}[/]", s.mode)
    console.print(out)
    if report.alarm_index is not None:
        console.print(f"[bold red]ALARM[/] end of tool life near: calibration {report.alarm_index} at "
                      f"{report.alarm_distance:.3g} m — {escape(report.states[report.alarm_index].evidence)}",
                      highlight=False)
    else:
        console.print(f"no end-of-life alarm; state {report.state}", highlight=False, markup=False)
    console.print(f"dominant mode: {report.mode} — {report.states[-1].evidence}", highlight=False, markup=False)
    info = report.to_dict()
    info["next_calibration"] = _next_calibration(session, report, interval, cut_length)
    info["table"] = str(session)
    info["settings"] = WearTracker().settings.__dict__
    if plot:
        from drivesense.plot import plot_wear_track, save_figure

        save_figure(plot_wear_track(report), plot)
        info["plot"] = str(plot)
        console.print(f"wrote {plot}", markup=False)
    write_json(json_path, info)


def _next_calibration(session: Path, report, interval: Optional[float], cut_length_mm: Optional[float]) -> dict:
    """Print and return the adaptive cadence's proposal for the next calibration."""
    import json

    import numpy as np

    from drivesense.io.csv import sidecar_path
    from drivesense.condition.cadence import propose_from_states

    about = {}
    side = sidecar_path(session)
    if side.is_file():
        try:
            about = json.loads(side.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            about = {}
    spacing = np.diff([s.distance for s in report.states])
    base = interval or about.get("calibration_interval_m") or (float(np.median(spacing)) if spacing.size else None)
    if not base or base <= 0:
        console.print("next calibration: give --interval (your calibration interval in m of cutting); the session "
                      "has one calibration or no distances", highlight=False, markup=False)
        return {"interval_m": None, "reason": "no fixed interval known (--interval)"}
    proposal = propose_from_states(report.states, float(base))
    length = cut_length_mm * 1e-3 if cut_length_mm is not None else about.get("cut_length_m")
    out = {"interval_m": proposal.interval, "factor_of_fixed_interval": proposal.factor, "fixed_interval_m": base,
           "reason": proposal.reason, "cut_length_m": length, "cuts": None}
    if length:
        out["cuts"] = proposal.cuts(float(length))
        when = f"after {out['cuts']} cut(s) ({out['cuts'] * length:.3g} m of cutting)"
    else:
        when = f"after {proposal.interval:.3g} m of cutting (give --cut-length to count it in cuts)"
    if report.alarm_index is not None:
        when += " if the tool stays in (the alarm is raised: plan the tool change)"
    console.print(f"next calibration {when}: {proposal.factor:.2g}x your interval of {base:.3g} m — "
                  f"{proposal.reason}", highlight=False, markup=False)
    return out


def register(root: typer.Typer) -> None:
    """Add the ``wear`` command group to the root application."""
    root.add_typer(wear_app, name="wear")
