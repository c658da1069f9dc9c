"""``drivesense identify nc``: the controller-rate model of any machine from its own controller traces."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, ColumnsOpt, FsOpt, ResampleOpt, console, friendly,
                                   show_warnings, trace_reader, warn, write_json)

__all__ = ["register", "parse_axis_values", "parse_carries"]


def parse_axis_values(text: str, option: str, unit: str) -> dict[str, float]:
    """Parse ``x=-520,z=610`` into ``{axis: value}`` for the CLI option ``option``.

    Parameters
    ----------
    text : str
        The option's value.
    option : str
        The option's name, for messages (e.g. ``"--km"``).
    unit : str
        Unit of the values, for messages (e.g. ``"N/A"``).
    """
    from drivesense.errors import ConfigError

    out: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name.isidentifier():
            raise ConfigError(f"{option} item {item!r}: expected AXIS=VALUE [{unit}], e.g. x=-520")
        try:
            out[name] = float(value)
        except ValueError:
            raise ConfigError(f"{option} item {item!r}: {value.strip()!r} is not a number [{unit}]") from None
    if not out:
        raise ConfigError(f"{option}: give AXIS=VALUE [{unit}] items separated by commas")
    return out


def parse_carries(text: str) -> dict[str, list[str]]:
    """Parse ``--carries y=x,z=x+y`` into ``{"y": ["x"], "z": ["x", "y"]}``.

    Parameters
    ----------
    text : str
        The option's value.
    """
    from drivesense.errors import ConfigError

    out: dict[str, list[str]] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        carrier, sep, carried = item.partition("=")
        names = [c.strip() for c in carried.split("+") if c.strip()]
        if not sep or not carrier.strip().isidentifier() or not names or not all(n.isidentifier() for n in names):
            raise ConfigError(f"--carries item {item!r}: expected AXIS=AXIS[+AXIS], e.g. y=x (Y carries X)")
        out.setdefault(carrier.strip(), []).extend(names)
    if not out:
        raise ConfigError("--carries: give AXIS=AXIS[+AXIS] items separated by commas, e.g. y=x")
    return out


def _fmt(value: float, ci: float) -> str:
    return f"{value:.4g} +- {ci:.2g}"


def identify_nc(
    traces: Annotated[list[Path], typer.Argument(
        help="Controller traces (.csv, .nc or .xml) at one rate >= 25 Hz: air cuts (no force columns) and "
             "calibration cuts (with force_x/y/z from a dynamometer).")],
    out: Annotated[Path, typer.Option("--out", help="AXES.toml to write (feeds 'estimate --method model --axes').")],
    air: Annotated[Optional[list[Path]], typer.Option(
        "--air", help="An air cut (the program run without material), repeatable: its force columns, if the "
                      "dynamometer was logging, are left out (no process force there).")] = None,
    vertical: Annotated[Optional[str], typer.Option(
        "--vertical", metavar="AXIS", help="The vertical axis, the only one carrying a weight (e.g. z on a vertical, "
                                           "y on a horizontal machining centre); the others' offsets are bounded "
                                           "to a current-sensor offset.")] = None,
    carries: Annotated[Optional[str], typer.Option(
        "--carries", metavar="AXIS=AXIS[+AXIS],...",
        help="Kinematics, e.g. y=x (Y carries X): a carrier's moved mass is at least that of what it "
             "carries.")] = None,
    km: Annotated[Optional[str], typer.Option(
        "--km", help="Force constants of some axes as logged, sign included, e.g. x=-520,z=610 [N/A] "
                     "(default: identified from the calibration cuts).")] = None,
    period: Annotated[Optional[str], typer.Option(
        "--period", help="Spatial period of an axis's position-periodic terms, e.g. x=0.01 [m] (the screw lead; "
                         "default: searched over 3-60 mm).")] = None,
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the identification report as JSON here.")] = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
    columns: ColumnsOpt = None,
) -> None:
    """Identify force constants, masses, weight, friction and ripple from a calibration cut and air cuts."""
    from drivesense.identify.controller import as_air_cut, identify_controller, is_calibration_cut
    from drivesense.io.axes_file import write_axes_file

    kinematics = parse_carries(carries) if carries else None
    read = trace_reader(fs, resample, assume_si, bad_samples, columns)
    recs = [read(p) for p in traces]
    recs += [as_air_cut(read(p)) for p in air or []]
    traces = [*traces, *(air or [])]
    with show_warnings():
        report = identify_controller(recs, km=parse_axis_values(km, "--km", "N/A") if km else None,
                                     period=parse_axis_values(period, "--period", "m") if period else None,
                                     vertical=vertical, carries=kinematics)
    model = report.model
    n_cal = sum(is_calibration_cut(r) for r in recs)
    write_axes_file(out, model, header=f"identified by 'drivesense identify nc' from {n_cal} calibration cut(s) and "
                                       f"{len(recs) - n_cal} air cut(s) at {model.rate_hz:g} Hz")
    axes = list(model.axes)
    table = Table(title=f"Controller-rate model from {n_cal} calibration cut(s) and {len(recs) - n_cal} air cut(s)")
    table.add_column("term (95 % CI)")
    for a in axes:
        table.add_column(a, justify="right")
    table.add_row("K_m [N/A]", *(_fmt(model.axis(a).K_m, model.axis(a).K_m_ci95) for a in axes))
    if any(model.axis(a).force_sign < 0 for a in axes):
        table.add_row("reference reads the load", *("against the drive (-1)" if model.axis(a).force_sign < 0
                                                    else "with the drive (+1)" for a in axes))
    names = list(dict.fromkeys(t.name for a in axes for t in model.axis(a).terms))
    for n in names:
        cells = []
        for a in axes:
            t = model.axis(a).term(n)
            cells.append(_fmt(t.value, t.ci95) if t is not None else "dropped" if n in model.axis(a).dropped else "-")
        unit = next(t.unit for a in axes for t in model.axis(a).terms if t.name == n)
        table.add_row(escape(f"{n} [{unit}]"), *cells)
    table.add_row("residual rms air / cal [N]", *(
        " / ".join("-" if v is None else f"{v:.3g}" for v in report.axes[a]["residual_rms_n"].values()) for a in axes))
    table.caption = (f"logging window {model.window_s * 1e3:.3g} ms, delay behind the force {model.delay_s * 1e3:.3g} ms; "
                     f"{report.seconds:.2f} s")
    console.print(table)
    active = [(a, n, why) for a in axes for n, why in report.axes[a].get("active_bounds", {}).items()]
    if active:
        bounds = Table(title="Terms at a physical bound")
        for col in ("axis", "term", "why"):
            bounds.add_column(col)
        for a, n, why in active:
            bounds.add_row(a, n, escape(why))
        console.print(bounds)
    if report.regression_check:
        check = Table(title="Held-out NRMSE against the regression (calibration segments; air cuts within the "
                            "cuts' motion)")
        for col in ("axis", "model", "sliding", "regression", "--per-axis auto"):
            check.add_column(col, justify="right" if col != "axis" else "left")
        for a, row in report.regression_check.items():
            nrmse = row.get("nrmse", {})
            check.add_row(a, *("-" if nrmse.get(k) is None else f"{nrmse[k] * 100:.1f} %"
                               for k in ("model", "sliding", "regression")), row["choice"])
        console.print(check)
        console.print("sliding: the model while the axis moves, the regression while it stands (its guides hold the "
                      "force its current cannot see)", markup=False)
        for a, row in report.regression_check.items():
            if row.get("choice") == "regression":
                warn(row["note"] if row["note"].startswith("no physical model") else f"axis {a}: {row['note']}")
    dropped = Table(title="Terms the data did not determine")
    dropped.add_column("axis")
    dropped.add_column("term")
    dropped.add_column("why")
    for a in axes:
        for n, why in model.axis(a).dropped.items():
            dropped.add_row(a, n, escape(why))
    if dropped.row_count:
        console.print(dropped)
    for line in report.limits:
        console.print(f"limit: {line}", markup=False)
    for a in axes:
        note = report.axes[a].get("force_sign_note")
        if note:
            console.print(f"axis {a}: {note}", markup=False)
    for line in report.warnings:
        warn(line)
    console.print(f"wrote {out}", markup=False)
    write_json(json_path, {"traces": [str(p) for p in traces], "axes_file": str(out), **report.to_dict()})


def register(identify_app: typer.Typer) -> None:
    """Add ``nc`` to the ``identify`` group."""
    identify_app.command("nc")(friendly(identify_nc))
