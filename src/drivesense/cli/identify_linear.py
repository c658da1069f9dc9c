"""``drivesense identify linear``: linear-motor axes by the four-step method; ``estimate --method model``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly, read_trace,
                                   save_recording, show_warnings, trace_reader, write_json)

__all__ = ["register", "parse_motor_constants", "estimate_model"]


def parse_motor_constants(text: str) -> dict[str, float]:
    """Parse ``x=180,y=260,z=140`` (N/A) into a dict; ConfigError naming the bad item."""
    from drivesense.errors import ConfigError

    out: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in ("x", "y", "z"):
            raise ConfigError(f"--km item {item!r}: expected AXIS=VALUE with AXIS x, y or z (N/A), e.g. x=180")
        try:
            out[name] = float(value)
        except ValueError:
            raise ConfigError(f"--km item {item!r}: {value!r} is not a number") from None
        if not out[name] > 0:
            raise ConfigError(f"--km item {item!r}: the motor constant must be > 0 N/A")
    missing = [a for a in ("x", "y", "z") if a not in out]
    if missing:
        raise ConfigError(f"--km lacks axis/axes {', '.join(missing)} (give x=...,y=...,z=... in N/A)")
    return out


def identify_linear(
    air_moves: Annotated[list[Path], typer.Argument(help="NC traces (.nc or .csv) of air moves of x, y and z.")],
    out: Annotated[Path, typer.Option("--out", help="AXES.toml to write.")],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the identification report as JSON here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write a PNG of the cogging tables and Stribeck curves.")] = None,
    km: Annotated[Optional[str], typer.Option("--km", help="Motor constants x=..,y=..,z=.. [N/A] (default: the traces' metadata).")] = None,
    pole_pitch: Annotated[float, typer.Option(help="Pole pitch of the motors [m].")] = 0.023,
    table_size: Annotated[int, typer.Option(help="Points of the cogging table over one pole pitch.")] = 64,
    presliding: Annotated[bool, typer.Option("--presliding/--no-presliding",
                                             help="Step 5: identify the presliding distance (beyond the paper).")] = True,
    strict: Annotated[bool, typer.Option("--strict", help="Refuse when the speeds do not determine the Stribeck "
                                         "curve (default: Coulomb + viscous friction, marked undetermined).")] = False,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Identify restoring force, cogging, Stribeck friction, masses and presliding of X/Y/Z and write AXES.toml."""
    from drivesense.identify.linear_axis import run_identification
    from drivesense.io.axes_file import write_axes_file

    read_trace = trace_reader(fs, resample, assume_si, bad_samples)
    recs = [read_trace(p) for p in air_moves]
    with show_warnings():
        report = run_identification(recs, motor_constants=parse_motor_constants(km) if km else None,
                                    pole_pitch=pole_pitch, table_size=table_size, presliding=presliding,
                                    strict=strict)
    model = report.model
    write_axes_file(out, model, header=f"identified by the four-step method from {len(recs)} air move(s)")
    stacked = model.stacked_masses()
    table = Table(title=f"Linear axes identified from {len(recs)} air move(s)")
    table.add_column("parameter")
    for a in ("x", "y", "z"):
        table.add_column(a, justify="right")
    rows = [("K_m [N/A] (given)", lambda ax, st, a: f"{ax.K_m:.4g}"),
            ("k [N/m]", lambda ax, st, a: f"{ax.k:.4g}"),
            ("s_r [mm]", lambda ax, st, a: f"{ax.s_r * 1e3:.2f}"),
            ("own mass m [kg]", lambda ax, st, a: f"{ax.m:.1f}"),
            ("moved mass (Eq. 2) [kg]", lambda ax, st, a: f"{stacked[a]:.1f}"),
            ("F_C [N]", lambda ax, st, a: f"{ax.F_C:.2f}"),
            ("F_br [N]", lambda ax, st, a: f"{ax.F_br:.2f}" + ("*" if "F_br" in ax.undetermined else "")),
            ("v_s [mm/s]", lambda ax, st, a: "undetermined" if "v_s" in ax.undetermined else f"{ax.v_s * 1e3:.3g}"),
            ("sigma [N s/m]", lambda ax, st, a: f"{ax.sigma:.4g}"),
            ("cogging 1st harmonic [N]", lambda ax, st, a: f"{st['cogging']['amplitudes_n'][0]:.2f}"),
            ("presliding x_pre [um] (step 5)", lambda ax, st, a: f"{ax.x_pre * 1e6:.1f}" if ax.x_pre > 0
             else "not determined"),
            ("rms step 1 / 3 / 4 [N]", lambda ax, st, a: f"{st['restoring']['rms_n']:.2f} / "
                                                         f"{st['friction']['rms_n']:.2f} / {st['mass']['rms_n']:.2f}")]
    for label, fmt in rows:
        table.add_row(escape(label), *(fmt(model.axis(a), report.steps[a], a) for a in ("x", "y", "z")))
    if any(model.axis(a).undetermined for a in ("x", "y", "z")):
        table.caption = "* undetermined by the air moves: F_br = F_C (Coulomb + viscous friction)"
    console.print(table)
    console.print("seconds per axis: " + ", ".join(f"{k} {v:.3f}" for k, v in report.seconds.items()), markup=False)
    console.print(f"wrote {out}", markup=False)
    if plot:
        from drivesense.plot import plot_identification, save_figure

        save_figure(plot_identification(report), plot)
        console.print(f"wrote {plot}", markup=False)
    write_json(json_path, {"air_moves": [str(p) for p in air_moves], "axes_file": str(out), **report.to_dict()})


def estimate_model(trace: Path, est, out: Path, json_path: Optional[Path] = None,
                   plot: Optional[Path] = None, read=read_trace) -> None:
    """``drivesense estimate TRACE --method model|lstm|hybrid``: X/Y/Z force from a 3-axis NC trace.

    ``read`` reads the trace (:func:`~drivesense.cli.common.trace_reader` of the command's options).

    ``est`` is a ModelBased, LSTM or Hybrid estimator (anything with ``name``
    and ``estimate(recording)`` returning ``force_x/y/z``).
    """
    from drivesense.score import score_estimate

    rec = read(trace)
    force = est.estimate(rec)
    save_recording(force, out)
    info: dict = {"method": est.name, "trace": str(trace), "fs": rec.fs, "samples": rec.n_samples,
                  "latency_s": force.meta["latency_s"], "sign": force.meta["sign"], "output": str(out),
                  "force_n": {}, "score_vs_reference": {}, "warnings": []}
    table = Table(title=escape(f"{est.name} estimate of {trace.name}"), show_header=False)
    table.add_row("samples", f"{rec.n_samples} at {rec.fs:g} Hz")
    if getattr(est, "per_axis", "model") == "auto":
        info["per_axis"] = {a: "regression" if a in est.regression_axes else "sliding" if a in est.sliding_axes
                            else "model" for a in est.axes}
        table.add_row("per axis (auto)", ", ".join(f"{a}: {how}" for a, how in info["per_axis"].items())
                      + ("  (sliding: the model while the axis moves, the regression while it stands)"
                         if "sliding" in info["per_axis"].values() else ""))
    table.add_row("latency", f"{info['latency_s'] * 1e3:.3f} ms (the method's and the trace's declared delay)")
    window = tuple(rec.meta.get("score_window", (rec.t0, rec.t0 + rec.duration)))
    for ch in force.channels:
        f = force[ch]
        info["force_n"][ch] = {"mean": float(f.mean()), "min": float(f.min()), "max": float(f.max()),
                               "std": float(f.std())}
        row = f"{f.mean():.2f} / {f.min():.2f} / {f.max():.2f} N"
        if ch in rec.channels:
            s = score_estimate(force, rec, channel=ch, window=window)
            info["score_vs_reference"][ch] = s.to_dict()
            row += f"   vs reference: RMSE {s.rmse_n:.2f} N, NRMSE {s.nrmse * 100:.2f} %"
        table.add_row(f"{ch} mean / min / max", row)
    console.print(table)
    console.print(f"wrote {out}", markup=False)
    if plot:
        from drivesense.plot import plot_force_estimate, save_figure

        save_figure(plot_force_estimate(rec, force, title=f"{est.name} estimate: {trace.name}"), plot)
        info["plot"] = str(plot)
    write_json(json_path, info)


def register(identify_app: typer.Typer) -> None:
    """Add ``linear`` to the ``identify`` group."""
    identify_app.command("linear")(friendly(identify_linear))
