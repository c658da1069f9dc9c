"""``drivesense identify frf``: ball-screw parameters from an FRF excitation trace."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly, read_trace,
                                   write_json)

__all__ = ["register", "parse_fix"]


def parse_fix(text: str) -> dict[str, float]:
    """Parse ``NAME=VALUE[,NAME=VALUE...]`` (SI) into a dict; ConfigError naming the bad item."""
    from drivesense.errors import ConfigError

    out: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--fix item {item!r}: expected NAME=VALUE (SI units), e.g. K_t=0.45")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--fix item {item!r}: {value!r} is not a number") from None
    return out


def identify_frf(
    trace: Annotated[Path, typer.Argument(help="Trace (.nc or .csv) taken while an excitation runs.")],
    fix: Annotated[str, typer.Option(help="Known values, SI: K_t=...,lead=... (required) [,T_a=,omega_cc=, any fit parameter].")],
    out: Annotated[Path, typer.Option("--out", help="AXIS.toml to write.")],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the fit as JSON here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write a PNG of measured vs fitted FRFs.")] = None,
    fmin: Annotated[float, typer.Option(help="Lowest frequency fitted [Hz].")] = 5.0,
    fmax: Annotated[float, typer.Option(help="Highest frequency fitted [Hz].")] = 2000.0,
    nperseg: Annotated[int, typer.Option(help="Welch segment length [samples].")] = 8192,
    axis_name: Annotated[str, typer.Option("--axis-name", help="Axis letter of the channels.")] = "x",
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Fit J_r, M_t, C_t, C_k, D_r, K_r and T_b to the measured FRFs and write AXIS.toml."""
    from drivesense.identify.frf import fit_frf, measure_frf, split_fix
    from drivesense.io.axis_file import write_axis_file

    K_t, lead, chain, given = split_fix(parse_fix(fix))
    rec = read_trace(trace, axis_name, fs=fs, resample=resample, assume_si=assume_si,
                     bad_samples=bad_samples)
    measured = measure_frf(rec, K_t=K_t, lead=lead, axis_name=axis_name, nperseg=nperseg, fmin=fmin, fmax=fmax)
    fit = fit_frf(measured, K_t=K_t, lead=lead, fixed=given, **chain)
    write_axis_file(out, fit.axis, fit.signal)
    table = Table(title=escape(f"FRF fit of {trace.name} ({measured.reference} reference, {measured.freq.size} "
                               "lines)"))
    for col in ("parameter", "value", "95 % interval", "std"):
        table.add_column(col, justify="right" if col != "parameter" else "left")
    for name in ("J_r", "M_t", "C_t", "C_k", "D_r", "K_r", "T_b"):
        value = fit.values[name]
        if name in fit.free:
            lo, hi = fit.ci95[name]
            std = f"{fit.rel_std[name] * 1e3:.3g} ms" if name == "T_b" else f"{fit.rel_std[name] * 100:.2g} %"
            table.add_row(name, f"{value:.5g}", f"{lo:.4g} .. {hi:.4g}", std)
        else:
            table.add_row(name, f"{value:.5g}", "fixed", "")
    console.print(table)
    console.print(f"normalised residual {fit.normalised_rms:.2f}, {fit.iterations} iterations, "
                  f"{fit.seconds:.2f} s; T_comp = T_a + T_b = {fit.signal.T_comp * 1e3:.4f} ms", markup=False)
    console.print(f"wrote {out}", markup=False)
    if plot:
        from drivesense.plot import plot_frf_fit, save_figure

        save_figure(plot_frf_fit(fit), plot)
        console.print(f"wrote {plot}", markup=False)
    write_json(json_path, {"trace": str(trace), "axis_file": str(out), **fit.to_dict()})


def register(identify_app: typer.Typer) -> None:
    """Add ``frf`` to the ``identify`` group."""
    identify_app.command("frf")(friendly(identify_frf))
