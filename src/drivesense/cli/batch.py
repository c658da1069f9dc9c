"""``drivesense batch estimate|detect|wear|identify``: one method over a folder or an archive, on Dask."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly, parse_window,
                                   progress_bar, warn, write_json)
from drivesense.cli.detect import (AxesOpt, AxisNameOpt, AxisOpt, ForceLimitOpt, IdleOpt, LimitsOpt, MethodOpt,
                                   ModelOpt, SpindleRpmOpt, TareOpt, TeethOpt, check_detector_options)

__all__ = ["register", "batch_app"]

batch_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                        help="Run one method over many recordings (a folder or an archive query) on a Dask "
                             "cluster: one Parquet summary row per input, resumable, failures recorded.")

InputsArg = Annotated[Optional[list[str]], typer.Argument(
    help="Files, folders (their .nc/.csv/.xml) or glob patterns ('runs/**/*.nc'); or use --archive.")]
WearInputsArg = Annotated[Optional[list[str]], typer.Argument(
    help="Session tables (CSV), folders of them or glob patterns ('sessions/*.csv').")]
OutOpt = Annotated[Path, typer.Option("--out", help="Output folder: results/, rows/, summary.parquet.")]
ArchiveInOpt = Annotated[Optional[str], typer.Option(
    "--archive", help="Take the inputs from this archive (SQLite file or postgresql:// DSN); results go back "
                      "into it.")]
QueryOpt = Annotated[Optional[str], typer.Option(
    "--query", help="Words every archived input must contain (as 'archive search'); default: all.")]
MachineOpt = Annotated[Optional[str], typer.Option("--machine", help="Archived inputs: machine contains this text.")]
WorkersOpt = Annotated[Optional[int], typer.Option(
    "--workers", help="Local Dask worker processes (default: one per core; 0 runs in this process).")]
SchedulerOpt = Annotated[Optional[str], typer.Option(
    "--scheduler", help="A running Dask scheduler, tcp://HOST:8786 (its workers must see the same paths).")]
RetryOpt = Annotated[bool, typer.Option("--retry-failed", help="Run inputs that failed before again.")]
JsonOpt = Annotated[Optional[Path], typer.Option("--json", help="Write the batch report as JSON here.")]


def _inputs(inputs, archive, query, machine, out: Path):
    from drivesense.errors import ConfigError
    from drivesense.fleet.inputs import archive_inputs, file_inputs, files_from_patterns

    if bool(inputs) == bool(archive):
        raise ConfigError("give either input files/folders/patterns or --archive (with --query), not "
                          + ("both" if inputs else "neither"))
    if archive is None and (query is not None or machine is not None):
        raise ConfigError("--query and --machine select archived inputs: give --archive too")
    if archive is not None:
        return archive_inputs(archive, query=query, machine=machine)
    out.mkdir(parents=True, exist_ok=True)
    return file_inputs(files_from_patterns(list(inputs)), cache=out / "digests.json")


def _run(job, inputs, archive, query, machine, out: Path, workers, scheduler, retry_failed, json_path) -> None:
    from drivesense.errors import ConfigError
    from drivesense.fleet.batch import run_batch

    if workers is not None and workers < 0:
        raise ConfigError(f"--workers must be >= 0, got {workers!r}")
    items = _inputs(inputs, archive, query, machine, out)
    n_workers = (os.cpu_count() or 1) if workers is None else workers
    with progress_bar() as bar:
        task = bar.add_task(f"batch {job.kind}", total=None)

        def started(info: dict) -> None:
            bar.update(task, total=info["to_run"])
            where = (f"Dask dashboard: {info['dashboard']}" if info["dashboard"] else
                     "in this process" if not info["workers"] else f"{info['workers']} Dask worker(s)")
            bar.console.print(f"{len(items)} input(s): {info['to_run']} to run, {info['skipped']} done before; "
                              f"{where}", markup=False, soft_wrap=True)

        report = run_batch(job, items, out, workers=n_workers, scheduler=scheduler, retry_failed=retry_failed,
                           progress=lambda done, total, row: bar.update(task, completed=done), on_start=started)
    table = Table(title=escape(f"batch {job.kind}: {report.inputs} input(s)"), show_header=False)
    for name, value in (("ran now", report.ran), ("done before (skipped)", report.skipped),
                        ("failed", report.failed), ("wall time", f"{report.seconds:.1f} s"),
                        ("workers", report.workers or "this process"), ("summary", str(report.summary)),
                        *((("written to the archive", report.archived),) if archive else ())):
        table.add_row(name, escape(str(value)))
    console.print(table)
    failures = [r for r in report.rows if r.get("status") == "error"]
    for r in failures[:5]:
        console.print(f"failed: {r['input']}: {r['error']}", markup=False, soft_wrap=True)
    if len(failures) > 5:
        console.print(f"... and {len(failures) - 5} more (the summary's 'error' column)", markup=False)
    unknown = [r for r in report.rows if job.kind == "detect" and r.get("status") == "ok" and r.get("teeth") is None]
    if unknown:
        warn(f"{len(unknown)} input(s) without a known tooth count (e.g. {unknown[0]['input']}): breakage/chipping "
             f"detection was off there (the reason is in each .events.json); --teeth N turns it on")
    write_json(json_path, report.to_dict())
    if report.failed:                                  # the batch ran through; the exit status tells a script
        raise typer.Exit(1)


def _estimate_fields(method, axis_file, axes_file, model_dir, idle, tare, axis_name) -> dict:
    return {"method": method, "axis_file": axis_file, "axes_file": axes_file, "model_dir": model_dir,
            "idle": list(idle or []), "tare": parse_window(tare) if tare else None, "axis_name": axis_name}


def _reader(fs, resample, assume_si, bad_samples) -> dict:
    return {"fs": fs, "resample": resample, "assume_si": assume_si, "bad_samples": bad_samples}


@batch_app.command("estimate")
@friendly
def estimate(
    inputs: InputsArg = None,
    out: OutOpt = Path("batch-out"),
    axis_file: AxisOpt = None,
    method: MethodOpt = "vibration",
    idle: IdleOpt = None,
    tare: TareOpt = None,
    axis_name: AxisNameOpt = "x",
    axes_file: AxesOpt = None,
    model_dir: ModelOpt = None,
    archive: ArchiveInOpt = None,
    query: QueryOpt = None,
    machine: MachineOpt = None,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    retry_failed: RetryOpt = False,
    json_path: JsonOpt = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Force estimate of every input (a .force.nc each; force statistics and the score against a reference
    force, when the trace has one, in the summary)."""
    from drivesense.fleet.jobs import EstimateJob

    job = EstimateJob(reader=_reader(fs, resample, assume_si, bad_samples),
                      **_estimate_fields(method, axis_file, axes_file, model_dir, idle, tare, axis_name))
    _run(job, inputs, archive, query, machine, out, workers, scheduler, retry_failed, json_path)


@batch_app.command("detect")
@friendly
def detect(
    inputs: InputsArg = None,
    out: OutOpt = Path("batch-out"),
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
    axis_name: AxisNameOpt = "x",
    axes_file: AxesOpt = None,
    model_dir: ModelOpt = None,
    archive: ArchiveInOpt = None,
    query: QueryOpt = None,
    machine: MachineOpt = None,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    retry_failed: RetryOpt = False,
    json_path: JsonOpt = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Events in every input ('detect' on each: an .events.json each; counts and kinds in the summary)."""
    from drivesense.fleet.jobs import DetectJob

    check_detector_options(spindle_rpm=spindle_rpm, teeth=teeth, baseline_revs=baseline_revs,
                           force_limit=force_limit)
    job = DetectJob(reader=_reader(fs, resample, assume_si, bad_samples), teeth=teeth, spindle_rpm=spindle_rpm,
                    limits=limits, force_limit=force_limit, baseline_revs=baseline_revs,
                    **_estimate_fields(method, axis_file, axes_file, model_dir, idle, tare, axis_name))
    _run(job, inputs, archive, query, machine, out, workers, scheduler, retry_failed, json_path)


@batch_app.command("wear")
@friendly
def wear(
    inputs: WearInputsArg = None,
    out: OutOpt = Path("batch-out"),
    diameter: Annotated[Optional[float], typer.Option(help="Tool diameter [mm] if a table has none.")] = None,
    flutes: Annotated[Optional[int], typer.Option(help="Number of flutes if a table has none.")] = None,
    mode: Annotated[str, typer.Option(help="up | down: milling mode of radial_depth rows.")] = "down",
    reference: Annotated[Optional[int], typer.Option(help="Cut (0-based, in the first calibration) for the "
                                                          "percent-power indicator.")] = None,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    retry_failed: RetryOpt = False,
    json_path: JsonOpt = None,
) -> None:
    """Wear history of every session table ('wear track' on each CSV: state, mode, alarm in the summary)."""
    from drivesense.errors import ConfigError
    from drivesense.fleet.jobs import WearJob

    if diameter is not None and not diameter > 0:
        raise ConfigError(f"--diameter must be > 0 [mm], got {diameter!r}")
    job = WearJob(diameter=None if diameter is None else diameter * 1e-3, flutes=flutes, mode=mode,
                  reference=reference)
    _run(job, inputs, None, None, None, out, workers, scheduler, retry_failed, json_path)


@batch_app.command("identify")
@friendly
def identify(
    inputs: InputsArg = None,
    out: OutOpt = Path("batch-out"),
    fix: Annotated[str, typer.Option(help="Known values, SI: K_t=...,lead=... (required) [,T_a=,omega_cc=, any "
                                          "fit parameter].")] = "",
    fmin: Annotated[float, typer.Option(help="Lowest frequency fitted [Hz].")] = 5.0,
    fmax: Annotated[float, typer.Option(help="Highest frequency fitted [Hz].")] = 2000.0,
    nperseg: Annotated[int, typer.Option(help="Welch segment length [samples].")] = 8192,
    axis_name: AxisNameOpt = "x",
    archive: ArchiveInOpt = None,
    query: QueryOpt = None,
    machine: MachineOpt = None,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    retry_failed: RetryOpt = False,
    json_path: JsonOpt = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """FRF fit of every excitation trace ('identify frf' on each: an AXIS.toml each, the parameters in the
    summary)."""
    from drivesense.cli.identify_frf import parse_fix
    from drivesense.fleet.jobs import IdentifyJob

    job = IdentifyJob(reader=_reader(fs, resample, assume_si, bad_samples), fix=parse_fix(fix), fmin=fmin,
                      fmax=fmax, nperseg=nperseg, axis_name=axis_name)
    _run(job, inputs, archive, query, machine, out, workers, scheduler, retry_failed, json_path)


def register(app: typer.Typer) -> None:
    """Add ``batch`` to the root app."""
    app.add_typer(batch_app, name="batch")
