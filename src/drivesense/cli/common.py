"""Shared pieces of the command line: error handling, JSON output, progress bars, reading traces."""

from __future__ import annotations

import contextlib
import functools
import warnings
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

__all__ = ["console", "err_console", "friendly", "warn", "key_column", "write_json", "progress_bar", "accuracy_table",
           "read_trace", "trace_reader", "build_estimator", "save_recording", "check_recording_suffix", "show_warnings", "AssumeSiOpt",
           "FsOpt", "ResampleOpt", "BadSamplesOpt", "ColumnsOpt", "check_output", "check_output_folder", "OUTPUT_OPTIONS"]

console = Console(emoji=False)          # user text such as "--tare START:END" is never an emoji code
err_console = Console(stderr=True, emoji=False)


#: Parameter names of the commands' output options (files, or a folder the command creates) -> the option.
#: :func:`friendly` checks each before the command runs (:func:`check_output`).
OUTPUT_OPTIONS = {"out": "--out", "json_path": "--json", "plot": "--plot", "out_dir": "--out-dir"}


def check_output(path, option: str) -> None:
    """The one rule of every output option: the folder it writes into must exist; nothing is created on the way.

    Raises ConfigError ``--json: folder '/x/y' does not exist`` (``-``, standard output, passes).
    """
    from drivesense.errors import ConfigError

    if path is None or str(path) == "-":
        return
    parent = Path(path).parent
    if parent.exists() and not parent.is_dir():
        raise ConfigError(f"{option}: '{parent}' is a file, not a folder")
    if not parent.is_dir():
        raise ConfigError(f"{option}: folder '{parent}' does not exist")


def check_output_folder(path: Path, option: str) -> None:
    """An output that is a folder the command creates (or fills): it may exist, but not as a file."""
    from drivesense.errors import ConfigError

    check_output(path, option)
    if Path(path).exists() and not Path(path).is_dir():
        raise ConfigError(f"{option}: '{path}' is a file; give a folder (it is created if missing)")


def friendly(fn):
    """Turn expected errors into ``error: ...`` and exit code 2; check the output options first.

    Every output option named in :data:`OUTPUT_OPTIONS` is checked with :func:`check_output` before the
    command runs, so a typo in a folder costs nothing and creates nothing.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from drivesense.errors import DriveSenseError

        try:
            for name, option in OUTPUT_OPTIONS.items():
                if isinstance(kwargs.get(name), (str, Path)):
                    check_output(kwargs[name], option)
            return fn(*args, **kwargs)
        except (DriveSenseError, FileNotFoundError, IsADirectoryError, NotADirectoryError, FileExistsError,
                PermissionError, KeyError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
            err_console.print(f"[bold red]error:[/] {escape(str(msg))}", highlight=False, soft_wrap=True)
            raise typer.Exit(2) from None

    return wrapper


def warn(text: str) -> None:
    """One yellow ``warning: ...`` line on stderr (the text is printed as is: no markup)."""
    err_console.print(f"[bold yellow]warning:[/] {escape(text)}", highlight=False, soft_wrap=True)


def key_column(table: Table, header: str, values, *, max_width: int = 36, **kwargs) -> None:
    """Add a column that is never truncated (scenario, channel, state, tool names).

    Key columns must survive 80-column terminals and piped output.  Values up to `max_width` characters
    keep their full width and are not wrapped; longer ones (a tool's description) wrap at spaces and fold
    a word too long for the column: nothing ends in an ellipsis.  The other columns wrap around it.
    """
    texts = [str(v) for v in values]
    longest = max(map(len, texts), default=1)
    if longest <= max_width:
        table.add_column(header, no_wrap=True, overflow="fold", min_width=longest, **kwargs)
    else:
        longest_word = max((len(w) for t in texts for w in t.split()), default=1)
        table.add_column(header, overflow="fold", min_width=min(longest_word, max_width), **kwargs)


def write_json(path: Optional[Path], payload: dict) -> None:
    """Write a command's JSON result (nothing without ``--json``) and say so."""
    if path is None:
        return
    from drivesense.io import write_json_file

    check_output(path, "--json")

    console.print(f"wrote {write_json_file(path, payload)}", markup=False)


def progress_bar() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=err_console, transient=False)


def accuracy_table(rows: list[dict], title: str) -> Table:
    methods = list(dict.fromkeys(r["method"] for r in rows))
    table = Table(title=title, caption="NRMSE = RMSE / peak-to-peak of the filtered true force; RMSE [N] in the JSON")
    key_column(table, "scenario", [r["scenario"] for r in rows])
    table.add_column("dir", no_wrap=True)
    table.add_column("F p2p [N]", justify="right", overflow="fold")
    for m in methods:
        table.add_column(m, justify="right", overflow="fold")
    by = {}
    for r in rows:
        by.setdefault(r["scenario"], {})[r["method"]] = r
    for scen, per in by.items():
        first = next(iter(per.values()))
        cells = [f"{per[m]['nrmse'] * 100:.1f} %" if m in per else "-" for m in methods]
        table.add_row(escape(scen), first["direction"], f"{first['peak_to_peak_n']:.1f}", *cells)
    return table


#: ``--assume-si``, ``--fs HZ``, ``--resample HZ`` and ``--bad-samples``: the options of every command that
#: reads traces (give them to :func:`read_trace` or :func:`trace_reader`).
AssumeSiOpt = Annotated[bool, typer.Option(
    "--assume-si", help="CSV traces: read columns without a unit in the header as SI (m, rad, A, s...); "
                        "without this they are refused.")]
FsOpt = Annotated[Optional[float], typer.Option(
    "--fs", metavar="HZ", help="CSV traces without a time column: their sample rate [Hz].")]
ColumnsOpt = Annotated[Optional[str], typer.Option(
    "--columns", metavar="MAP.toml|NAME",
    help="CSV exports of a controller or edge device: the column map (which column is which channel, its unit, "
         "scale and sign; unnamed columns are left out): a TOML file or a shipped map's name (e.g. kit-dmc60h).")]
ResampleOpt = Annotated[Optional[float], typer.Option(
    "--resample", metavar="HZ", help="CSV traces with jittery time stamps: resample them explicitly onto a "
                                     "uniform grid at HZ [Hz] (linear interpolation, noted in the provenance).")]
BadSamplesOpt = Annotated[Optional[Literal["refuse", "repair", "off"]], typer.Option(
    "--bad-samples", metavar="refuse|repair|off", show_default=False,
    help="Physically impossible samples in a trace (non-finite, a spindle beyond 100000 rpm, isolated spikes, "
         "position jumps the logged velocity cannot explain): refuse them naming channel, line, value and why; "
         "repair them by linear interpolation of their neighbours (listed in the recording's metadata and as "
         "warnings); or off: read the values as they are.  Default: refuse for CSV traces; .nc and .xml "
         "recordings (drivesense's own, lossless) are checked only when this option is given.")]


def read_trace(path: Path, axis_name: str = "x", *, fs: Optional[float] = None, resample: Optional[float] = None,
               assume_si: bool = False, bad_samples: Optional[str] = None, columns=None):
    """Read a CSV (bare channel names get the axis prefix), a saved recording (.nc) or an XML experiment.

    ``fs``, ``resample`` and ``assume_si`` are the options ``--fs``, ``--resample`` and ``--assume-si``
    (:data:`FsOpt`, :data:`ResampleOpt`, :data:`AssumeSiOpt`); they concern CSV traces only (a .nc or .xml
    recording carries its time base and units).  ``bad_samples`` is ``--bad-samples`` (:data:`BadSamplesOpt`):
    None (not given) refuses impossible samples of CSV traces and leaves .nc/.xml recordings unchecked; given,
    it applies to every format (CSV samples named by file line, the others by sample index).  ``columns`` is
    ``--columns`` (:data:`ColumnsOpt`, a column map or its name).  Repairs and notes are printed as
    ``warning: ...`` lines.
    """
    from drivesense.io import read_trace as read

    with show_warnings():
        return read(path, axis_name, fs=fs, resample=resample, assume_si=assume_si, bad_samples=bad_samples,
                    columns=columns)


def trace_reader(fs: Optional[float] = None, resample: Optional[float] = None, assume_si: bool = False,
                 bad_samples: Optional[str] = None, columns: Optional[str] = None):
    """:func:`read_trace` with a command's ``--fs``, ``--resample``, ``--assume-si``, ``--bad-samples`` and
    ``--columns`` bound: ``read(path[, axis])`` (the column map is read once, here)."""
    column_map = None
    if columns is not None:
        from drivesense.io.column_map import resolve_column_map

        column_map = resolve_column_map(columns)
    return functools.partial(read_trace, fs=fs, resample=resample, assume_si=assume_si, bad_samples=bad_samples,
                             columns=column_map)


def build_estimator(method: str, *, axis_file: Optional[Path] = None, axes_file: Optional[Path] = None,
                    model_dir: Optional[Path] = None, axis_name: str = "x"):
    """Any registered method from the CLI's options (``--axis``, ``--axes`` or ``--model``): see
    :func:`drivesense.estimate.registry.make_from_files`."""
    from drivesense.estimate.registry import make_from_files

    return make_from_files(method, axis_file=axis_file, axes_file=axes_file, model_dir=model_dir,
                           axis_name=axis_name)


def check_recording_suffix(out: Path, option: str = "--out") -> None:
    """Refuse an output recording whose suffix names no format drivesense writes (before any work is done).

    The format follows the suffix: ``.nc`` (netCDF, lossless) or ``.csv``; anything else is a ConfigError
    naming `option`, never a file of one format under another's name.
    """
    from drivesense.errors import ConfigError

    if Path(out).suffix.lower() not in (".nc", ".csv"):
        raise ConfigError(f"{option} '{out}': the format follows the suffix: use .nc (netCDF, lossless) or .csv")


def save_recording(rec, out: Path, *, parents: bool = False) -> None:
    """Write a recording command's ``--out``: ``.nc`` (lossless) or ``.csv``, atomically.

    With ``parents`` the folder of `out` is created (after the suffix is checked).
    """
    from drivesense.io import write_recording

    check_recording_suffix(out)
    if parents:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, out)


@contextlib.contextmanager
def show_warnings():
    """Print the library's warnings raised inside as ``warning: ...`` lines on stderr, once each.

    Only ``UserWarning`` subclasses (drivesense's own: fallbacks, skipped input) are printed this way;
    other warnings go to Python's usual handler.  When the block fails, its error stands alone (the
    ``friendly`` one-line message): the warnings of a run that produced nothing are dropped.
    """
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        yield
    for w in {str(w.message): w for w in record}.values():  # outside catch_warnings: Python's showwarning again
        if issubclass(w.category, UserWarning):
            warn(str(w.message))
        else:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def parse_window(text: str, option: str = "--tare") -> tuple[float, float]:
    """``START:END`` [s] of a CLI option; ConfigError naming `option`."""
    import math

    from drivesense.errors import ConfigError

    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise ConfigError(f"{option} {text!r}: expected START:END in seconds, e.g. 0.5:1.4") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ConfigError(f"{option} {text!r}: START and END must be finite numbers of seconds")
    if not b > a:
        raise ConfigError(f"{option} {text!r}: END must be after START")
    return a, b
