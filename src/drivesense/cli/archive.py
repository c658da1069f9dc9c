"""``drivesense archive add|search|show|export|rm``: the experiment archive."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly, key_column,
                                   trace_reader, write_json)

__all__ = ["register", "archive_app"]

archive_app = typer.Typer(no_args_is_help=True,
                          help="The experiment archive (SQLite by default, or PostgreSQL): add, search, show, "
                               "export, rm.")

ArchiveOpt = Annotated[Optional[str], typer.Option(
    "--archive", envvar="DRIVESENSE_ARCHIVE",
    help="SQLite file or postgresql:// DSN (default: archive.sqlite in your data folder).")]
JsonOpt = Annotated[Optional[str], typer.Option("--json", help="Write JSON to this file ('-': print it).")]


def _open(archive: Optional[str], *, create: bool = False):
    """The archive of ``--archive``; only ``archive add`` creates one (reading a missing one is an error)."""
    from drivesense.archive import open_archive

    return open_archive(archive, create=create)


def _emit(json_path: Optional[str], payload) -> bool:
    if json_path is None:
        return False
    if json_path == "-":
        from drivesense.io import strict_json

        typer.echo(strict_json(payload))
    else:
        write_json(Path(json_path), payload)
    return True


def _range(text: str, option: str) -> tuple[str, tuple]:
    from drivesense.errors import ConfigError

    key, sep, bounds = text.partition("=")
    low, colon, high = bounds.partition(":")
    try:
        lo = float(low) if low.strip() else None
        hi = float(high) if high.strip() else (lo if not colon else None)
    except ValueError:
        lo = hi = "bad"
    if not sep or not key.strip() or lo == "bad" or (lo is None and hi is None):
        raise ConfigError(f"{option} {text!r}: expected KEY=LOW:HIGH (either end may be empty) or KEY=VALUE, "
                          "e.g. feed_rate=0.05:0.2")
    return key.strip(), (lo, hi)


@archive_app.command("add")
@friendly
def add(
    files: Annotated[list[Path], typer.Argument(help="Experiment files (.xml) or recordings (.nc, .csv).")],
    archive: ArchiveOpt = None,
    json_path: JsonOpt = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Import experiments; each import is atomic (all or nothing)."""
    read_trace = trace_reader(fs, resample, assume_si, bad_samples)
    rows = []
    with _open(archive, create=True) as store:
        for f in files:
            if not Path(f).is_file():
                raise FileNotFoundError(2, "file not found", str(f))
            eid = store.add(read_trace(f) if Path(f).suffix.lower() == ".csv" else f)
            rows.append({"file": str(f), "id": eid})
            if json_path is None:
                console.print(f"added {f} as {eid}", markup=False, highlight=False)
        location = store.location
    _emit(json_path, {"archive": location, "added": rows})


@archive_app.command("search")
@friendly
def search(
    words: Annotated[Optional[list[str]], typer.Argument(
        help="Words that must all occur anywhere in the experiment ('a phrase', prefix*).")] = None,
    machine: Annotated[Optional[str], typer.Option(help="Machine contains this text.")] = None,
    tool: Annotated[Optional[str], typer.Option(help="Tool contains this text.")] = None,
    material: Annotated[Optional[str], typer.Option(help="Material contains this text.")] = None,
    operator: Annotated[Optional[str], typer.Option(help="Operator / experimenter contains this text.")] = None,
    since: Annotated[Optional[str], typer.Option(help="Created on or after (ISO 8601, e.g. 2024-05-01).")] = None,
    until: Annotated[Optional[str], typer.Option(help="Created on or before (a bare date includes the day).")] = None,
    start: Annotated[Optional[list[str]], typer.Option(
        help="Start-state range KEY=LOW:HIGH (SI values; repeatable).")] = None,
    end: Annotated[Optional[list[str]], typer.Option(help="End-state range KEY=LOW:HIGH (repeatable).")] = None,
    limit: Annotated[int, typer.Option(help="Most results.")] = 50,
    archive: ArchiveOpt = None,
    json_path: JsonOpt = None,
) -> None:
    """Find experiments by any word in them and by structured filters (never reads samples)."""
    text = " ".join(f'"{w}"' if " " in w else w for w in (words or []))
    with _open(archive) as store:
        hits = store.search(text or None, machine=machine, tool=tool, material=material, operator=operator,
                            since=since, until=until, start=dict(_range(s, "--start") for s in start or []),
                            end=dict(_range(s, "--end") for s in end or []), limit=limit)
    if _emit(json_path, {"query": text, "hits": [h.to_dict() for h in hits]}):
        return
    table = Table(title=f"{len(hits)} experiment(s)", caption="ids are shortened: any unique prefix works")
    fields = [f for f in ("machine", "tool", "material", "operator") if any(getattr(h, f) for h in hits)]
    for col in ("id", "created", "name", *fields, "samples"):
        if col == "tool":                    # a key: never cut, whatever the terminal's width (the others fold)
            key_column(table, col, [getattr(h, col) or "" for h in hits])
        else:
            table.add_column(col, overflow="fold", no_wrap=col in ("id", "created", "samples"),
                             justify="right" if col == "samples" else "left")
    for h in hits:
        table.add_row(h.id[:8], h.created[:10], escape(h.name or ""), *(escape(getattr(h, f) or "") for f in fields),
                      f"{h.samples:,}")
    console.print(table)


@archive_app.command("show")
@friendly
def show(
    experiment: Annotated[str, typer.Argument(help="Experiment id (or a unique prefix).")],
    archive: ArchiveOpt = None,
    json_path: JsonOpt = None,
) -> None:
    """Metadata of one experiment: measurements, channels, configuration (no samples)."""
    with _open(archive) as store:
        info = store.show(experiment)
    if _emit(json_path, info):
        return
    console.print(f"experiment {info['id']}  created {info['created']}  format {info['format_version']}",
                  markup=False, highlight=False)
    for key in ("machine", "tool", "material", "operator"):
        if info[key]:
            console.print(f"  {key}: {info[key]}", markup=False, highlight=False)
    for m in info["measurements"]:
        table = Table(title=escape(f"measurement {m['name'] or '(unnamed)'}: {m['samples']} samples @ "
                                   f"{m['fs_hz']:g} Hz, {m['duration_s']:g} s"))
        key_column(table, "channel", [c["name"] for c in m["channels"]])
        for col in ("units", "interface", "sensor"):
            table.add_column(col, overflow="fold")
        for c in m["channels"]:
            table.add_row(*(escape(c[k]) for k in ("name", "units", "interface", "sensor")))
        console.print(table)
        shown = {k: v for k, v in m["meta"].items() if k not in ("provenance",)}
        console.print(json.dumps(shown, indent=1, ensure_ascii=False)[:4000], markup=False, highlight=False)


@archive_app.command("export")
@friendly
def export(
    experiment: Annotated[str, typer.Argument(help="Experiment id (or a unique prefix).")],
    out: Annotated[Path, typer.Option("--out", help="Output: .xml (whole experiment), .nc or .csv (one "
                                                    "measurement).")],
    measurement: Annotated[Optional[int], typer.Option(help="0-based measurement for .nc/.csv.")] = None,
    archive: ArchiveOpt = None,
) -> None:
    """Write an archived experiment to a file (atomically), bit-exact as imported."""
    with _open(archive) as store:
        path = store.export(experiment, out, measurement=measurement)
    console.print(f"wrote {path}", markup=False, highlight=False)


@archive_app.command("rm")
@friendly
def rm(
    experiments: Annotated[list[str], typer.Argument(help="Experiment ids (or unique prefixes).")],
    archive: ArchiveOpt = None,
) -> None:
    """Delete experiments (metadata, index and samples)."""
    with _open(archive) as store:
        for e in experiments:
            full = store.resolve(e)
            store.remove(full)
            console.print(f"removed {full}", markup=False, highlight=False)


def register(root: typer.Typer) -> None:
    """Add the ``archive`` command group to the root application."""
    root.add_typer(archive_app, name="archive")
