"""``drivesense dataset build`` and ``drivesense train lstm|hybrid``: the learned reconstruction."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, check_output_folder, console,
                                   err_console, friendly, progress_bar, trace_reader, write_json)

__all__ = ["register"]

dataset_app = typer.Typer(no_args_is_help=True, help="Training data for the learned reconstruction.")


@dataset_app.command("build")
@friendly
def dataset_build(
    out: Annotated[Optional[Path], typer.Option("--out", help="Dataset folder (default: the user cache).")] = None,
    air_cuts: Annotated[int, typer.Option(help="Air cuts (zero force) added to the training split; "
                                               "0: the paper's cutting runs only.")] = 34,
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the index summary here.")] = None,
) -> None:
    """Simulate the third paper's process grid (seeded, cached; about 190 cutting runs plus air cuts)."""
    from drivesense.bench.learn import default_dataset_dir
    from drivesense.errors import ConfigError
    from drivesense.learn.dataset import build_dataset, plan_runs

    if out is not None:
        check_output_folder(out, "--out")
    out = out or default_dataset_dir()
    if air_cuts < 0:
        raise ConfigError(f"'--air-cuts' must be >= 0, got {air_cuts}")
    runs = plan_runs(n_air=air_cuts)
    with progress_bar() as bar:
        task = bar.add_task("simulate runs", total=len(runs))
        index = build_dataset(out, runs, progress=lambda name: bar.advance(task))
    splits: dict = {}
    for entry in index["runs"]:
        split = entry["spec"]["split"] + (" (air cuts)" if entry["spec"].get("air") else "")
        splits[split] = splits.get(split, 0) + 1
    table = Table(title=escape(f"dataset in {out}"), show_header=False)
    table.add_row("runs", ", ".join(f"{k}: {v}" for k, v in splits.items()))
    table.add_row("held-out process type", escape(index["held_out_process"]))
    table.add_row("exclusion rule", escape(index["exclusion_rule"]))
    table.add_row("size on disk", f"{index['bytes_on_disk'] / 2**20:.1f} MiB")
    console.print(table)
    write_json(json_path, {k: v for k, v in index.items() if k != "runs"} | {"splits": splits, "folder": str(out)})


def train(
    kind: Annotated[str, typer.Argument(help="lstm | hybrid")],
    data: Annotated[Path, typer.Option("--data", help="Dataset folder (built, or your own .nc/.csv traces).")],
    out: Annotated[Path, typer.Option("--out", help="Model folder to write.")],
    axes: Annotated[Optional[Path], typer.Option(help="AXES.toml of the identified axes (hybrid only).")] = None,
    epochs: Annotated[int, typer.Option(help="Maximum epochs per network (early stopping on validation).")] = 100,
    seed: Annotated[int, typer.Option(help="Seed.")] = 0,
    harmonics: Annotated[int, typer.Option(help="Pole-pitch harmonics of the positions added to the inputs "
                                                "(0: the paper's 14 inputs).")] = 3,
    pole_pitch_mm: Annotated[float, typer.Option(help="Pole pitch of the linear motors [mm].")] = 23.0,
    skip: Annotated[bool, typer.Option("--skip/--no-skip", help="Linear path from the inputs to the output "
                                                                "beside the LSTM (--no-skip: the paper's network).")] = True,
    skip_taps: Annotated[Optional[int], typer.Option(help="Samples the linear path looks back over (a causal FIR "
                                                          "filter; 1: instantaneous; default 16 ms for lstm, 32 "
                                                          "ms for hybrid at the model's rate: 4 and 8 samples at "
                                                          "250 Hz, 1 and 2 at 50 Hz).")] = None,
    presliding_um: Annotated[float, typer.Option(help="Nominal presliding distance of the guides [um] for the "
                                                      "presliding-state inputs (0: left out).")] = 10.0,
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the training record here.")] = None,
    assume_si: AssumeSiOpt = False,
    fs: FsOpt = None,
    resample: ResampleOpt = None,
    bad_samples: BadSamplesOpt = None,
) -> None:
    """Train one network per force component (and save state_dicts + config)."""
    from drivesense.errors import ConfigError
    from drivesense.learn import Hybrid, LSTM
    from drivesense.learn.dataset import load_dataset
    from drivesense.learn.model import TrainConfig, require_torch

    if epochs < 1:
        raise ConfigError(f"--epochs must be >= 1, got {epochs} (0 epochs would save an untrained model)")
    require_torch()
    if kind not in ("lstm", "hybrid"):
        raise ConfigError(f"unknown learned method {kind!r}; choose lstm or hybrid")
    kwargs = {}
    if kind == "hybrid":
        if axes is None:
            raise ConfigError("train hybrid needs --axes AXES.toml (from drivesense identify linear)")
        from drivesense.io.axes_file import read_axes_file

        kwargs["model_based"] = read_axes_file(axes)
    runs = [rec for _, rec in load_dataset(data, read=trace_reader(fs, resample, assume_si, bad_samples))]
    config = TrainConfig(epochs=epochs, seed=seed, position_harmonics=harmonics, pole_pitch=pole_pitch_mm * 1e-3,
                         linear_skip=skip, skip_taps=skip_taps, presliding_length=presliding_um * 1e-6)
    est = (Hybrid if kind == "hybrid" else LSTM)(config=config)
    est.fit(runs, progress=lambda line: err_console.print(line, highlight=False), **kwargs)
    est.save(out)
    hist = est.model.history
    console.print(f"trained {kind} on {hist['runs']['train']} run(s) at {hist['fs']:g} Hz in "
                  f"{hist['total_seconds']:.0f} s; validation: {hist['validation']}; epochs {hist['epochs']}; "
                  f"wrote {out}", markup=False)
    write_json(json_path, {"kind": kind, "model": str(out), "history": hist,
                           "interval_scale": est.model.interval_scale})


def register(root: typer.Typer) -> None:
    """Add ``dataset`` and ``train`` to the root application."""
    root.add_typer(dataset_app, name="dataset")
    root.command("train")(friendly(train))
