"""``drivesense xml validate|export|import|transform``: the XML experiment format."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly, trace_reader,
                                   write_json)

__all__ = ["register", "xml_app"]

xml_app = typer.Typer(no_args_is_help=True,
                      help="The XML experiment format (schema-validated, lossless): validate, export, import, "
                           "transform.")


@xml_app.command("validate")
@friendly
def validate(
    file: Annotated[Path, typer.Argument(help="Experiment file (.xml).")],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the summary as JSON here.")] = None,
) -> None:
    """Check a file completely: safe XML, schema, base64, lengths, units; errors name line and element."""
    from drivesense.io.xml_format import validate_xml

    summary = validate_xml(file)
    n_ch = sum(len(m["channels"]) for m in summary["measurements"])
    n_s = sum(len(m["channels"]) * m["samples"] for m in summary["measurements"])
    console.print(f"valid: {file} (format {summary['format_version']}, id {summary['id']}, "
                  f"{len(summary['measurements'])} measurement(s), {n_ch} channel(s), {n_s} samples)",
                  markup=False, highlight=False)
    write_json(json_path, summary)


@xml_app.command("export")
@friendly
def export(
    recordings: Annotated[list[Path], typer.Argument(help="Recording(s) (.nc or .csv): one measurement each.")],
    out: Annotated[Path, typer.Option("--out", help="Output experiment file (.xml).")],
    encoding: Annotated[str, typer.Option(help="Sample encoding: base64 (fast) or text.")] = "base64",
    dtype: Annotated[str, typer.Option(help="base64 precision: float64 (bit-exact) or float32.")] = "float64",
    experimenter: Annotated[Optional[str], typer.Option(
        help="Experimenter named when the metadata names nobody (default: your login).")] = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Write recordings as one experiment file (atomically)."""
    from drivesense.io.xml_format import write_xml

    read_trace = trace_reader(fs, resample, assume_si, bad_samples)
    recs = [read_trace(p) for p in recordings]
    write_xml(recs, out, encoding=encoding, dtype=dtype, experimenter=experimenter)
    console.print(f"wrote {out}: {len(recs)} measurement(s)", markup=False, highlight=False)


@xml_app.command("import")
@friendly
def import_(
    file: Annotated[Path, typer.Argument(help="Experiment file (.xml).")],
    out: Annotated[Path, typer.Option("--out", help="Output recording: .nc (lossless) or .csv.")],
    measurement: Annotated[Optional[str], typer.Option(
        help="Measurement name or 0-based index (needed when the file holds several; a name several "
             "measurements share is refused, listing their indices).")] = None,
) -> None:
    """Read one measurement of an experiment file into a recording file."""
    from drivesense.cli.common import save_recording
    from drivesense.io.xml_format import read_xml

    which = int(measurement) if measurement is not None and measurement.lstrip("-").isdigit() else measurement
    rec = read_xml(file, measurement=which)
    save_recording(rec, out)
    console.print(f"wrote {out}: {rec!r}", markup=False, highlight=False)


@xml_app.command("transform")
@friendly
def transform(
    file: Annotated[Path, typer.Argument(help="Experiment file (.xml).")],
    xslt: Annotated[Optional[Path], typer.Option(
        "--xslt", help="XSLT 1.0 sheet (default: the shipped CSV summary of measurements and channels).")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", help="Write the result here (default: print).")] = None,
) -> None:
    """Apply an XSLT sheet (it may not read or write files or the network)."""
    from drivesense.io import atomic_output
    from drivesense.io.xml_format import transform_xml

    text = transform_xml(file, xslt)
    if out is None:
        typer.echo(text, nl=False)
        return
    with atomic_output(out) as tmp:
        tmp.write_text(text, encoding="utf-8")
    console.print(f"wrote {out}", markup=False, highlight=False)


def register(root: typer.Typer) -> None:
    """Add the ``xml`` command group to the root application."""
    root.add_typer(xml_app, name="xml")
