"""Core commands: demo, simulate, estimate, friction, bench, axis."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich import box
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, ColumnsOpt, FsOpt, ResampleOpt, accuracy_table,
                                   build_estimator, check_recording_suffix, console, friendly, parse_window,
                                   progress_bar, save_recording, show_warnings, trace_reader, warn, write_json)

__all__ = ["register"]

app = typer.Typer()


# ---------------------------------------------------------------------- demo
@app.command()
@friendly
def demo(
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the results as JSON here.")] = None,
    out: Annotated[Path, typer.Option("--out", help="Folder for the PNG figures (and demo.json).")] = Path("demo_out"),
    seed: Annotated[int, typer.Option(help="Seed of the simulated cuts.")] = 1,
) -> None:
    """Simulate the Table 1 stage, run idling and the 10 end-milling conditions, score every estimator."""
    from drivesense.bench import machine_info, run_condition, summarise
    from drivesense.estimate.design import lowpass_sos
    from drivesense.machine.presets import table1_axis, table1_signal
    from drivesense.plot import plot_estimates, plot_friction_maps, save_figure
    from drivesense.sim.scenarios import paper_conditions

    axis, signal = table1_axis(), table1_signal()
    out.mkdir(parents=True, exist_ok=True)
    rows, figures = [], []
    conditions = paper_conditions()
    with progress_bar() as progress:
        task = progress.add_task("simulate + estimate", total=len(conditions))
        for cond in conditions:
            progress.update(task, description=f"{cond.name:<18}")
            res = run_condition(cond, axis, signal, seed=seed)
            rows.extend(res.rows)
            fig = plot_estimates(res.cut, res.estimates, sos=lowpass_sos(signal, res.cut.fs), max_freq=1500.0,
                                 title=f"{cond.name}: estimated vs true force_x (full physics)")
            figures.append(str(save_figure(fig, out / f"{cond.name}.png")))
            if res.friction_maps and not any("friction" in f for f in figures):
                maps = {m: res.friction_maps[m] for m in ("rigid", "vibration")}
                fig = plot_friction_maps(maps, title=f"Friction from 3 idling runs ({cond.name})")
                figures.append(str(save_figure(fig, out / f"friction_maps_{cond.name}.png")))
            progress.advance(task)
    console.print(accuracy_table(rows, "Force estimation on the 10 end-milling conditions (full physics)"))
    summary = summarise(rows)
    vib = max(summary["worst_nrmse"].get("vibration/feed", 0), summary["worst_nrmse"].get("vibration/cross", 0))
    console.print(f"worst VibrationMode NRMSE: {vib * 100:.2f} %   "
                  f"cross-feed RigidBody / VibrationMode (smallest ratio): "
                  f"{summary['cross_rigid_over_vibration_min']:.1f}x", markup=False)
    console.print(f"figures: {out}/<scenario>.png, {out}/friction_maps_*.png", markup=False)
    payload = {"machine": machine_info(), "axis": axis.to_dict(), "signal": signal.to_dict(),
               "accuracy": rows, "summary": summary, "figures": figures}
    write_json(json_path or out / "demo.json", payload)


# ------------------------------------------------------------------ simulate
@app.command()
@friendly
def simulate(
    scenario: Annotated[Optional[str], typer.Argument(help="Scenario name (see --list).")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", help="Output .nc (lossless) or .csv; for air_moves a "
                                                              "folder (one .nc per move).")] = None,
    list_: Annotated[bool, typer.Option("--list", help="List the scenarios (one line each).")] = False,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    ideal: Annotated[bool, typer.Option(help="Use exactly the estimators' model (no friction, noise...).")] = False,
    ap: Annotated[Optional[float], typer.Option("--ap", help="Linear-machine processes: axial depth of cut [mm] "
                                                             "(default 2).")] = None,
    ae: Annotated[Optional[float], typer.Option("--ae", help="Linear-machine processes: radial depth of cut [mm] "
                                                             "(default 5; grooves: the tool diameter).")] = None,
    vf: Annotated[Optional[float], typer.Option("--vf", help="Linear-machine processes: feed speed [mm/min] "
                                                             "(default 500).")] = None,
    rpm: Annotated[Optional[float], typer.Option("--rpm", help="Linear-machine processes: spindle speed [min^-1] "
                                                               "(default 4500).")] = None,
    event: Annotated[Optional[list[str]], typer.Option("--event", help="Ball-screw feed cuts: inject an event, "
                     "KIND@TIME[:VALUE] with TIME [s]: breakage@6 (flute 0), chipping@6:0.4 (edge loss), "
                     "collision@6.5:500 or overload@6.5:300 (force [N]), feed_override@5:0.6 (factor), "
                     "missing_tool@0.  Repeatable.")] = None,
    columns: Annotated[Optional[str], typer.Option(
        "--columns", metavar="MAP.toml|NAME", help="Write the .csv as this controller export (its column names, "
                                                   "units, scales and signs), e.g. kit-dmc60h.")] = None,
) -> None:
    """Simulate one scenario to a file: drive signals plus the true force (ball-screw stage or linear-motor machine)."""
    from dataclasses import replace

    from drivesense.cli.common import key_column
    from drivesense.errors import ConfigError
    from drivesense.sim.catalog import AIR_MOVES, ProcessParameters, describe_scenarios, is_process, simulate_scenario

    given = {"--ap": ap, "--ae": ae, "--vf": vf, "--rpm": rpm}
    params = None
    if any(v is not None for v in given.values()):
        params = replace(ProcessParameters(), **{k: v * f for (k, f), v in zip(
            (("a_p", 1e-3), ("a_e", 1e-3), ("v_f", 1 / 60e3), ("n", 1.0)), given.values()) if v is not None})
    if list_:
        described = describe_scenarios()
        table = Table(title="drivesense simulate SCENARIO --out FILE", box=box.SIMPLE,
                      caption="ball screw: 10 kHz; linear machine: 250 Hz NC trace; cuts carry the true force. "
                              f"Processes at {(params or ProcessParameters()).describe()} (--ap, --ae, --vf, --rpm)")
        key_column(table, "scenario", described)
        table.add_column("what it simulates", overflow="fold")
        for name, line in described.items():
            table.add_row(escape(name), escape(line))
        console.print(table)
        return
    if scenario is None or out is None:
        raise ConfigError("give a SCENARIO and --out FILE (or --list)")
    if params is not None and not is_process(scenario):
        raise ConfigError(f"{', '.join(k for k, v in given.items() if v is not None)}: cutting parameters of the "
                          "linear machine's processes (groove_*, side_*, pocket_ccw, pocket_cw, ramp_-y+z), "
                          f"not of {scenario!r}")
    column_map = None
    if columns is not None:
        from drivesense.io import resolve_column_map

        if out is not None and out.suffix.lower() != ".csv":
            raise ConfigError(f"--columns writes a CSV export: give --out FILE.csv, not '{out}'")
        column_map = resolve_column_map(columns)
    if scenario == AIR_MOVES and out.suffix.lower() in (".nc", ".csv"):
        raise ConfigError(f"{AIR_MOVES} writes 9 recordings: give --out a folder (one .nc file per move), "
                          f"not '{out}'")
    recs = simulate_scenario(scenario, seed=seed, ideal=ideal, params=params,
                             events=tuple(_parse_event(e) for e in event or ()))
    if scenario == AIR_MOVES:
        for rec in recs:
            save_recording(rec, out / f"{rec.name}.nc", parents=True)
        console.print(f"wrote {len(recs)} air moves to {out}/: {', '.join(r.name for r in recs)}", markup=False)
        return
    if column_map is not None:
        from drivesense.io import write_csv

        write_csv(recs[0], out, column_map=column_map)
    else:
        save_recording(recs[0], out)
    console.print(f"wrote {out}: {recs[0]!r}", markup=False)


# ------------------------------------------------------------------ estimate
def _parse_event(text: str):
    """``--event KIND@TIME[:VALUE]`` -> a simulator ProcessEvent."""
    from drivesense.errors import ConfigError
    from drivesense.sim.process_events import EVENT_SIM_KINDS, ProcessEvent

    kind, _, rest = text.partition("@")
    when, _, value = rest.partition(":")
    if kind not in EVENT_SIM_KINDS or not when:
        raise ConfigError(f"--event {text!r}: write KIND@TIME[:VALUE] with KIND one of {', '.join(EVENT_SIM_KINDS)}")
    try:
        t = float(when)
        v = float(value) if value else None
    except ValueError:
        raise ConfigError(f"--event {text!r}: TIME and VALUE must be numbers") from None
    extra = {"chipping": {"edge_loss": 0.4 if v is None else v},
             "collision": {"force_n": 500.0 if v is None else v, "rise_s": 2e-4},
             "overload": {"force_n": 300.0 if v is None else v, "rise_s": 0.3},
             "feed_override": {"factor": 0.6 if v is None else v}}.get(kind, {})
    return ProcessEvent(kind, t, **extra)


#: What an estimate without --idle or --tare means, and what to add.
_NO_COMPENSATION = ("no friction compensation (neither --idle nor --tare): friction and offsets are not removed, "
                    "so the estimate reads them as process force; add --idle IDLE.csv runs (the cutting trajectory "
                    "without cutting) or, for an axis that stands, --tare START:END [s] before the cut")


@app.command()
@friendly
def estimate(
    trace: Annotated[Path, typer.Argument(help="CSV (name [unit] header) or .nc Recording.")],
    out: Annotated[Path, typer.Option("--out", help="Output .csv (time [s], force_x [N]; model: force_x/y/z) or "
                                                    ".nc (netCDF, lossless): the format follows the suffix.")],
    axis_file: Annotated[Optional[Path], typer.Option("--axis", help="AXIS.toml with [axis] and [signal].")] = None,
    method: Annotated[str, typer.Option(help="current | rigid | medob | vibration (--axis); model | regression "
                                              "(--axes); lstm | hybrid (--model)")] = "vibration",
    idle: Annotated[Optional[list[Path]], typer.Option(help="Idle (air-cut) run(s) for the friction map.")] = None,
    tare: Annotated[Optional[str], typer.Option(help="START:END [s] of a tare window (standing axis).")] = None,
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write a JSON summary here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write a PNG of the estimate (and reference, if any): the "
                                                      "whole trace, a close-up and the spectrum.")] = None,
    plot_window: Annotated[Optional[str], typer.Option(
        "--plot-window", help="START:END [s] of the plot's close-up (default: a few tooth periods in the middle of "
                              "the cut, from the spindle speed if the trace has it; else 0.1 s).")] = None,
    axis_name: Annotated[str, typer.Option("--axis-name", help="Axis letter of the channels.")] = "x",
    axes_file: Annotated[Optional[Path], typer.Option("--axes", help="AXES.toml (linear-motor X/Y/Z) for --method model.")] = None,
    model_dir: Annotated[Optional[Path], typer.Option("--model", help="Trained model folder for --method lstm|hybrid.")] = None,
    per_axis: Annotated[str, typer.Option(
        "--per-axis", metavar="model|auto",
        help="--method model with an AXES.toml of 'identify nc': auto takes, on each axis where the identification "
             "found the regression better on held-out data, that regression (named per axis in the JSON).")] = "model",
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
    columns: ColumnsOpt = None,
) -> None:
    """Estimate the process force from a trace of current reference, motor angle and table position."""
    from drivesense.errors import ConfigError
    from drivesense.estimate.design import lowpass_sos

    check_recording_suffix(out)
    if per_axis not in ("model", "auto"):
        raise ConfigError(f"--per-axis {per_axis!r}: choose model or auto")
    if per_axis == "auto" and method != "model":
        raise ConfigError(f"--per-axis auto chooses between the model and its regression: it needs --method model, "
                          f"not {method}")
    read_trace = trace_reader(fs, resample, assume_si, bad_samples, columns)
    est = build_estimator(method, axis_file=axis_file, axes_file=axes_file, model_dir=model_dir,
                          axis_name=axis_name)
    if per_axis == "auto":
        from drivesense.estimate import make

        est = make("model", axes=est.model, per_axis="auto")
    zoom = parse_window(plot_window, "--plot-window") if plot_window is not None else None
    if zoom is not None and plot is None:
        raise ConfigError("--plot-window sets the close-up of --plot PNG: give --plot too")
    if est.drive != "ballscrew":
        from drivesense.cli.identify_linear import estimate_model

        if idle or tare:
            raise ConfigError(f"--method {method} takes no --idle/--tare (it reads a 3-axis NC trace)")
        if zoom is not None:
            raise ConfigError(f"--plot-window applies to the ball-screw methods; --method {method} plots the "
                              "whole trace per axis")
        return estimate_model(trace, est, out, json_path, plot, read=read_trace)
    signal = est.signal
    rec = read_trace(trace, axis_name)
    if idle and tare:
        raise ConfigError("give either --idle runs or --tare, not both")
    if zoom is not None and not (zoom[0] < rec.t0 + rec.duration and zoom[1] > rec.t0):
        raise ConfigError(f"--plot-window {plot_window!r} lies outside the trace ({rec.t0:g} to "
                          f"{rec.t0 + rec.duration:g} s)")
    info: dict = {"method": method, "trace": str(trace), "fs": rec.fs, "samples": rec.n_samples, "warnings": []}
    if idle:
        est.fit([read_trace(p, axis_name) for p in idle])
        info["compensation"] = "friction map"
        info["friction_map_repeatability_n"] = est.friction_map.repeatability_rms
    elif tare:
        info["compensation"] = "tare"
        info["tare_n"] = est.tare(rec, *parse_window(tare))
    else:
        info["compensation"] = "none"
        info["warnings"].append(_NO_COMPENSATION)
        warn(_NO_COMPENSATION)
    force = est.estimate(rec)
    save_recording(force, out)
    f = force[est.output_channel]
    info.update({"latency_s": force.meta["latency_s"], "sign": force.meta["sign"], "output": str(out),
                 "force_n": {"mean": float(f.mean()), "min": float(f.min()), "max": float(f.max()),
                             "std": float(f.std())}})
    if est.output_channel in rec.channels:
        from drivesense.score import score_estimate

        window = (rec.t0 + est.settle_time(rec.fs), rec.t0 + rec.duration)
        s = score_estimate(force, rec, channel=est.output_channel, window=tuple(rec.meta.get("score_window", window)),
                           sos=lowpass_sos(signal, rec.fs))
        info["score_vs_reference"] = s.to_dict()
    if plot:
        from drivesense.plot import plot_estimates, save_figure
        from drivesense.plot.estimates import cut_zoom_window

        # without a reference force the estimate is drawn alone, never as the truth
        truth = rec if est.output_channel in rec.channels else None
        window = (rec.t0 + est.settle_time(rec.fs), rec.t0 + rec.duration)
        zoom = zoom or cut_zoom_window(rec, tuple(rec.meta.get("score_window", window)))
        fig = plot_estimates(truth, {method: force}, channel=est.output_channel, sos=lowpass_sos(signal, rec.fs),
                             window=window, zoom=zoom, max_freq=min(1.5 * signal.lpf_hz, 0.5 * rec.fs),
                             title=f"{method} estimate: {trace.name}")
        save_figure(fig, plot)
        info["plot"] = str(plot)
        info["plot_window_s"] = [float(zoom[0]), float(zoom[1])]
    table = Table(title=escape(f"{method} estimate of {trace.name}"), show_header=False)
    table.add_row("samples", f"{rec.n_samples} at {rec.fs:g} Hz")
    table.add_row("compensation", info["compensation"] + (f" ({info['tare_n']:.2f} N)" if "tare_n" in info else ""))
    table.add_row("latency", f"{info['latency_s'] * 1e3:.3f} ms")
    table.add_row("sign", escape(info["sign"]))
    table.add_row(f"{est.output_channel} mean / min / max",
                  f"{f.mean():.2f} / {f.min():.2f} / {f.max():.2f} N")
    if "score_vs_reference" in info:
        s = info["score_vs_reference"]
        table.add_row("vs reference", f"RMSE {s['rmse_n']:.2f} N, NRMSE {s['nrmse'] * 100:.2f} %")
    console.print(table)
    console.print(f"wrote {out}", markup=False)
    write_json(json_path, info)


# ------------------------------------------------------------------ friction
@app.command()
@friendly
def friction(
    idle: Annotated[list[Path], typer.Argument(help="Idle (air-cut) runs over the same trajectory.")],
    axis_file: Annotated[Path, typer.Option("--axis", help="AXIS.toml with [axis] and [signal].")],
    method: Annotated[str, typer.Option(help="current | rigid | medob | vibration")] = "rigid",
    bin_width: Annotated[float, typer.Option(help="Position bin [um].")] = 1.0,
    plot: Annotated[Optional[Path], typer.Option(help="Write a PNG (map per run + wavelength spectrum).")] = None,
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write a JSON summary here.")] = None,
    axis_name: Annotated[str, typer.Option("--axis-name", help="Axis letter of the channels.")] = "x",
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Friction map from idling runs: position dependence, repeatability, dominant wavelengths."""
    import numpy as np

    from drivesense.dsp import dominant_wavelengths, wavelength_spectrum
    from drivesense.errors import ConfigError

    est = build_estimator(method, axis_file=axis_file, axis_name=axis_name)
    if est.drive != "ballscrew":
        raise ConfigError(f"friction maps are built by the ball-screw methods; --method {method} is not one")
    read_trace = trace_reader(fs, resample, assume_si, bad_samples)
    est.fit([read_trace(p, axis_name) for p in idle], bin_width=bin_width * 1e-6)
    fmap = est.friction_map
    peaks = dominant_wavelengths(*wavelength_spectrum(fmap.force, fmap.position), 5)
    info = {"method": method, "runs": len(idle), "bins": int(fmap.position.size), "bin_width_m": fmap.bin_width,
            "position_range_m": [float(fmap.position[0]), float(fmap.position[-1])],
            "mean_n": float(fmap.force.mean()), "peak_to_peak_n": float(np.ptp(fmap.force)),
            "repeatability_rms_n": fmap.repeatability_rms, "dominant_wavelengths": peaks}
    table = Table(title=f"{method} friction map from {len(idle)} idle run(s)", show_header=False)
    table.add_row("table positions", f"{info['position_range_m'][0] * 1e3:.3f} to "
                  f"{info['position_range_m'][1] * 1e3:.3f} mm in {info['bins']} bins")
    table.add_row("mean / peak-to-peak", f"{info['mean_n']:.2f} / {info['peak_to_peak_n']:.2f} N")
    table.add_row("repeatability (run-to-run std, rms)", f"{fmap.repeatability_rms:.3f} N")
    table.add_row("dominant wavelengths", ", ".join(f"{p['wavelength_m'] * 1e3:.3g} mm ({p['amplitude']:.2f} N)"
                                                    for p in peaks))
    console.print(table)
    if plot:
        from drivesense.plot import plot_friction_maps, save_figure

        save_figure(plot_friction_maps({method: fmap}), plot)
        info["plot"] = str(plot)
    write_json(json_path, info)


# --------------------------------------------------------------------- bench
@app.command()
@friendly
def bench(
    kind: Annotated[str, typer.Argument(help="accuracy | speed | identify | learn | wear | io | nc | events | "
                                              "monitor | fleet | all")] = "all",
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the bench JSON here.")] = None,
    real: Annotated[Optional[Path], typer.Option(
        "--real", metavar="DIR", help="bench nc on real traces: a folder of one machine's cuts and air cuts "
                                      "(*aircut* in the name); identify on one cut and its air cut, score every "
                                      "other cut beside the regression.")] = None,
    columns: ColumnsOpt = None,
    calibration: Annotated[Optional[str], typer.Option(
        "--calibration", metavar="FILE", help="--real: the calibration cut's file name (default: the first cut).")] = None,
    air: Annotated[Optional[str], typer.Option(
        "--air", metavar="FILE", help="--real: the air cut's file name (default: the one sharing the longest name "
                                      "prefix with the calibration cut).")] = None,
    vertical: Annotated[Optional[str], typer.Option("--vertical", metavar="AXIS",
                                                    help="--real: the vertical axis (identify nc --vertical).")] = None,
    carries: Annotated[Optional[str], typer.Option("--carries", metavar="AXIS=AXIS",
                                                   help="--real: kinematics (identify nc --carries).")] = None,
    hybrid: Annotated[Optional[int], typer.Option(
        "--hybrid", metavar="N", help="--real: also train the hybrid on N (1 or 2) cuts and score it on the "
                                      "rest.")] = None,
) -> None:
    """Accuracy and speed benchmarks (speed as ratios to baselines measured in the same run)."""
    from drivesense.bench import run_bench
    from drivesense.errors import ConfigError

    real_options = {"--columns": columns, "--calibration": calibration, "--air": air, "--vertical": vertical,
                    "--carries": carries, "--hybrid": hybrid}
    if real is None and any(v is not None for v in real_options.values()):
        given = [k for k, v in real_options.items() if v is not None]
        raise ConfigError(f"{', '.join(given)} apply to real traces: give --real DIR (with bench nc)")
    if real is not None:
        if kind != "nc":
            raise ConfigError(f"--real DIR runs bench nc on real traces; it does not apply to bench {kind}")
        return _real_nc_bench(real, columns, calibration, air, vertical, carries, hybrid or 0, json_path)
    with progress_bar() as progress:
        # steps per part vary (e.g. io runs more with a PostgreSQL server): count them, no fixed total
        task = progress.add_task(f"bench {kind}", total=None)
        result = run_bench(kind, progress=lambda label: progress.advance(task))
    if "accuracy" in result:
        console.print(accuracy_table(result["accuracy"], "Accuracy (full physics)"))
    if "speed" in result:
        sp = result["speed"]
        table = Table(title="Speed (same-run baselines)", show_header=False)
        for key in ("estimator_realtime_factor", "estimator_vs_sosfilt", "stream_realtime_factor",
                    "stream_max_dev_n", "simulator_realtime_factor", "estimator_peak_mb", "stream_state_bytes"):
            table.add_row(key, f"{sp[key]:.4g}")
        console.print(table)
    if "identify" in result:
        ident = result["identify"]
        table = Table(title="FRF identification vs truth: error in % (T_b: in ms)", box=box.SIMPLE, padding=(0, 1))
        names = ("J_r", "M_t", "C_t", "C_k", "D_r", "K_r", "T_b")
        table.add_column("excitation")
        for name in names:
            table.add_column(name, justify="right")
        table.add_column("ok")
        for row in ident["frf"]:
            cells = [f"{row['error'][n] * 1e3:+.4f}" if n == "T_b" else f"{row['error'][n] * 100:+.2f}" for n in names]
            table.add_row(row["excitation"], *cells, "yes" if row["all_within_targets"] else "NO")
        console.print(table)
        console.print(f"VibrationMode with the chirp-identified axis: worst NRMSE "
                      f"{ident['vibration_with_identified_worst_nrmse'] * 100:.2f} % over the 10 conditions",
                      markup=False)
    for part in ("wear", "io", "learn", "nc", "events", "monitor", "fleet"):
        if part in result and isinstance(result[part], dict):
            _print_targets(part, result[part])
    write_json(json_path, result)


def _real_nc_bench(folder: Path, columns, calibration, air, vertical, carries, hybrid: int, json_path) -> None:
    """``bench nc --real DIR``: the per-file table and the targets."""
    from drivesense.bench.machine import machine_info
    from drivesense.bench.nc_real import run_real_nc_bench
    from drivesense.cli.identify_nc import parse_carries
    from drivesense.errors import ConfigError

    if hybrid not in (0, 1, 2):
        raise ConfigError(f"--hybrid {hybrid}: train the hybrid on 1 or 2 cuts (0: not at all)")
    with progress_bar() as progress, show_warnings():
        task = progress.add_task(f"bench nc --real {folder.name}", total=None)
        result = run_real_nc_bench(folder, columns=columns, calibration=calibration, air=air, vertical=vertical,
                                   carries=parse_carries(carries) if carries else None, hybrid_cuts=hybrid,
                                   progress=lambda label: progress.advance(task))
    res = result["nc_real"]
    table = Table(title=escape(f"NRMSE on held-out cuts: identified on {res['calibration']} + {res['air']}"),
                  box=box.SIMPLE)
    shown = ["regression", "model", "auto", *(["hybrid"] if "over_model" in res.get("hybrid", {}) else [])]
    table.add_column("file", overflow="fold")
    table.add_column("axis")
    for m in shown:
        table.add_column(m, justify="right")
    table.add_column("auto / regression", justify="right")
    for row in res["files"]:
        for a in ("x", "y", "z"):
            table.add_row(escape(row["file"]) if a == "x" else "", a,
                          *("-" if row["nrmse"][m][a] is None else f"{row['nrmse'][m][a] * 100:.1f} %" for m in shown),
                          f"{row['ratio']['auto'][a]:.2f}x")
    console.print(table)
    for m in shown[1:]:
        summary = res["summary"][m]
        console.print(f"{m} / regression: mean {summary['mean_ratio']:.2f}x, worst {summary['worst_ratio']:.2f}x, per "
                      f"axis {', '.join(f'{a} ' + ('-' if v is None else f'{v:.2f}x') for a, v in summary['per_axis_mean_ratio'].items())}",
                      markup=False)
    for row in res["files"]:
        odd = {a: v["follows"] for a, v in row["reference_frame"].items() if not v["as_calibrated"]}
        if odd:
            warn(f"{row['file']}: the reference's frame differs from the calibration cut's (the estimate of "
                 + ", ".join(f"{a} follows {f}" for a, f in odd.items()) + "): a dynamometer or part turned on "
                 "the table; no method can be scored fairly on it")
    _print_targets("nc --real", res)
    write_json(json_path, {"machine": machine_info(), **result})


def _print_targets(part: str, section: dict) -> None:
    """A short table of a bench section: its targets (met or not) or its scalar figures."""
    table = Table(title=f"bench {part}", show_header=False, box=box.SIMPLE)
    targets = section.get("targets")
    if isinstance(targets, dict) and all(isinstance(v, dict) for v in targets.values()):
        for name, t in targets.items():
            table.add_row(name, f"{t.get('value', '')!s:.8}", str(t.get("target", "")),
                          "met" if t.get("met") else "NOT met")
    elif isinstance(targets, list) and all(isinstance(t, dict) for t in targets):
        for t in targets:
            measured = t.get("measured")
            shown = f"{measured:.4g}" if isinstance(measured, float) else str(measured)
            table.add_row(escape(str(t.get("target", ""))), escape(shown[:40]), "met" if t.get("met") else "NOT met")
    else:
        for name, value in section.items():
            if isinstance(value, (int, float)):
                table.add_row(name, f"{value:.4g}")
            elif isinstance(value, dict) and all(isinstance(v, (int, float)) for v in value.values()):
                table.add_row(name, ", ".join(f"{k} {v:.4g}" for k, v in value.items()))
    console.print(table)


# ---------------------------------------------------------------------- axis
@app.command("axis")
@friendly
def axis_cmd(
    out: Annotated[Path, typer.Option("--out", help="Where to write the AXIS.toml.")],
    preset: Annotated[str, typer.Option(help="Parameter set: table1 (the first paper's stage).")] = "table1",
) -> None:
    """Write an AXIS.toml from a preset, to edit for your own machine."""
    from drivesense.errors import ConfigError
    from drivesense.io.axis_file import write_axis_file
    from drivesense.machine.presets import table1_axis, table1_signal

    if preset != "table1":
        raise ConfigError(f"unknown preset {preset!r} (known: table1)")
    write_axis_file(out, table1_axis(), table1_signal())
    console.print(f"wrote {out}", markup=False)


def register(root: typer.Typer) -> None:
    """Add this module's commands to the root application."""
    for info in app.registered_commands:
        root.registered_commands.append(info)
