"""Reading and writing Recordings: CSV, netCDF4; the plausibility check of traces (:mod:`.plausibility`).

Every writer here is atomic: it writes a temporary file in the target's
directory and moves it into place with :func:`os.replace`, so a crash never
leaves half a file under the target name (see :func:`atomic_output`).
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar, Self

from ..errors import ConfigError

__all__ = [
    "ColumnMap",
    "read_column_map",
    "resolve_column_map",
    "shipped_maps",
    "read_csv",
    "write_csv",
    "save_netcdf",
    "load_netcdf",
    "read_recording",
    "read_trace",
    "write_recording",
    "atomic_output",
    "write_text_file",
    "write_json_file",
    "strict_json",
    "read_json_file",
    "JsonFileMixin",
    "BAD_SAMPLE_POLICIES",
    "PlausibilityLimits",
    "PlausibilityReport",
    "BadSample",
    "BadSampleWarning",
    "check_plausibility",
    "check_channels",
    "screen_recording",
]


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Context manager giving a temporary path that replaces `path` on success.

    Parameters
    ----------
    path : str or Path
        Final file.  Its directory must exist.

    Yields
    ------
    Path
        Temporary file (already created, empty) in the same directory; write
        it inside the ``with`` block.  On an exception it is deleted and `path`
        is left untouched.

    Raises
    ------
    FileNotFoundError
        If the directory of `path` does not exist.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {path.parent} does not exist")
    # like tempfile.mkstemp, but created by open() so it gets the usual (umask) mode
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    open(tmp, "x").close()
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_file(path: str | Path, text: str) -> Path:
    """Write ``text`` as a UTF-8 file, atomically (see :func:`atomic_output`).

    Parameters
    ----------
    path : str or Path
        Target file (its folder is created; replaced only once fully written).
    text : str
        The whole content.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def _finite(obj):
    """`obj` with every NaN/inf float (nested in dicts, lists, tuples, numpy arrays/scalars) as None."""
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def strict_json(payload, *, indent: int | None = 2) -> str:
    """``payload`` as strict JSON text: NaN and +-inf become ``null`` (JSON has no such numbers).

    Numpy scalars and arrays are written as numbers and lists; other objects
    through ``float()``.

    Parameters
    ----------
    payload : object
        JSON-serialisable data.
    indent : int, optional
        Indentation [characters per level] (None: compact).

    Returns
    -------
    str
    """
    import json

    return json.dumps(_finite(payload), indent=indent, default=lambda o: _finite(float(o)), allow_nan=False)


def write_json_file(path: str | Path, payload, *, indent: int | None = 2) -> Path:
    """Write ``payload`` as strict JSON (see :func:`strict_json`: NaN/inf as ``null``), atomically.

    Parameters
    ----------
    path : str or Path
        Target file (its folder is created).
    payload : object
        JSON-serialisable data.
    indent : int, optional
        Indentation [characters per level] (None: compact).

    Returns
    -------
    Path
        The file written.
    """
    return write_text_file(path, strict_json(payload, indent=indent) + "\n")


def _parse_text_file(path: str | Path, what: str, parse, errors: tuple, problem: str):
    """Read a UTF-8 text file and parse it; the messages name the file (``what``) and the problem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} '{path}' does not exist")
    try:
        return parse(path.read_text(encoding="utf-8"))
    except (*errors, UnicodeDecodeError) as exc:
        raise ConfigError(f"{what} '{path}': {problem} ({exc})") from None


def read_json_file(path: str | Path, what: str):
    """Parse a JSON file, naming it (``what``, e.g. ``"model file"``) in every error.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for messages.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ConfigError
        The file is not valid JSON.
    """
    import json

    return _parse_text_file(path, what, json.loads, (ValueError,), "not JSON")

def read_toml(path: str | Path, what: str) -> dict:
    """Parse a TOML file, naming it (``what``, e.g. ``"axis file"``) in every error.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for messages.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ConfigError
        The file is not valid TOML.
    """
    import tomllib

    return _parse_text_file(path, what, tomllib.loads, (tomllib.TOMLDecodeError,), "not valid TOML")


class JsonFileMixin:
    """JSON :meth:`save` and :meth:`load` for a class with ``to_dict()`` and ``from_dict(data)``.

    A class using it names its files in :attr:`json_what` (read errors say
    e.g. ``model file 'm.json': not JSON``) and may write them compact with
    :attr:`json_indent` ``= None``.
    """

    #: What the file is, named in every read error (e.g. ``"model file"``).
    json_what: ClassVar[str] = "JSON file"
    #: Indentation of the written JSON [characters per level]; None: compact, one line.
    json_indent: ClassVar[int | None] = 2

    def save(self, path: str | Path) -> Path:
        """Write ``to_dict()`` as JSON.

        Parameters
        ----------
        path : str or Path
            Target file (replaced atomically; its folder is created).

        Returns
        -------
        Path
        """
        return write_json_file(path, self.to_dict(), indent=self.json_indent)

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """Read a file written by :meth:`save` (through ``from_dict``).

        Parameters
        ----------
        path : str or Path
            JSON file.

        Returns
        -------
        object
            An instance of the class.

        Raises
        ------
        FileNotFoundError
            The file does not exist.
        ConfigError
            The file is not JSON, or ``from_dict`` refuses its content.
        """
        return cls.from_dict(read_json_file(path, cls.json_what))


from .column_map import ColumnMap, read_column_map, resolve_column_map, shipped_maps  # noqa: E402
from .csv import read_csv, write_csv  # noqa: E402  (atomic_output must exist first)
from .netcdf import load_netcdf, save_netcdf  # noqa: E402
from .plausibility import (BAD_SAMPLE_POLICIES, BadSample, BadSampleWarning, PlausibilityLimits,  # noqa: E402
                           PlausibilityReport, check_channels, check_plausibility, screen_recording)


def read_recording(path: str | Path, *, bad_samples: str | None = None, **kw: Any):
    """Read a Recording, choosing the reader by the file suffix.

    Parameters
    ----------
    path : str or Path
        ``.csv`` (:func:`read_csv`), ``.nc`` (:func:`load_netcdf`) or ``.xml``
        (the XML experiment format; its first measurement).
    bad_samples : {"refuse", "repair", "off"}, optional
        Plausibility check of the samples (``--bad-samples``, see
        :mod:`drivesense.io.plausibility`).  Default: ``refuse`` for CSV
        (traces from other tools, named by file line), no check for ``.nc``
        and ``.xml`` (named by sample index when asked for).
    **kw
        Passed to :func:`read_csv` (``axis``, ``mapping``, ``fs``, ...);
        netCDF files take none.

    Returns
    -------
    Recording

    Raises
    ------
    ConfigError
        Unknown suffix, or keywords given for a netCDF file.
    ImplausibleSampleError
        Physically impossible samples, under ``refuse`` (see `bad_samples`).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return read_csv(path, **kw) if bad_samples is None else read_csv(path, bad_samples=bad_samples, **kw)
    if suffix == ".nc":
        if kw:
            raise ConfigError(f"{path}: netCDF files take no reader options, got {sorted(kw)}")
        rec = load_netcdf(path)
    elif suffix == ".xml":
        if kw:
            raise ConfigError(f"{path}: XML experiment files take no reader options, got {sorted(kw)}")
        from .xml_format import read_xml

        rec = read_xml(path)
    else:
        rec = None
    if rec is not None:
        if bad_samples is None:
            return rec
        from .plausibility import screen_recording

        return screen_recording(rec, bad_samples, source=path.name, stacklevel=2)
    raise ConfigError(f"{path}: unknown file type {suffix or '(no suffix)'!r} "
                      "(known: .csv, .nc, .xml)")


def read_trace(path: str | Path, axis_name: str = "x", *, fs: float | None = None, resample: float | None = None,
               assume_si: bool = False, bad_samples: str | None = None, columns: Any = None):
    """Read a drive-signal trace as the commands do: CSV options only for CSV files.

    Parameters
    ----------
    path : str or Path
        A CSV (bare channel names get the axis prefix), a saved recording (.nc) or an XML experiment.
    axis_name : str
        Axis letter of a CSV's bare channel names (``--axis-name``).
    fs : float, optional
        Sample rate [Hz] of a CSV without a time column (``--fs``).
    resample : float, optional
        Resample a CSV's jittery time base to this rate [Hz] (``--resample``).
    assume_si : bool
        Take a CSV's unit-less columns as SI (``--assume-si``).
    bad_samples : {"refuse", "repair", "off"}, optional
        ``--bad-samples``: None refuses impossible samples of CSV traces and leaves .nc/.xml unchecked;
        given, it applies to every format.
    columns : str, Path or ColumnMap, optional
        ``--columns``: the CSV export's column map (a file or a shipped map's name,
        :mod:`drivesense.io.column_map`).

    Returns
    -------
    Recording
    """
    if Path(path).suffix.lower() != ".csv":
        if columns is not None:
            raise ConfigError(f"{path}: --columns maps the columns of CSV exports; this file is not a CSV")
        return read_recording(path, bad_samples=bad_samples)
    kw = {"column_map": resolve_column_map(columns)} if columns is not None else {}
    return read_recording(path, axis=axis_name, fs=fs, resample=resample, assume_si=assume_si,
                          bad_samples=bad_samples, **kw)


def write_recording(recording, path: str | Path, **kw: Any) -> Path:
    """Write a Recording, choosing the format by the file suffix (the inverse of :func:`read_recording`).

    Parameters
    ----------
    recording : Recording
        The data.
    path : str or Path
        ``.nc`` (netCDF4, lossless: :func:`save_netcdf`), ``.csv``
        (:func:`write_csv`) or ``.xml`` (the XML experiment format); written
        atomically.
    **kw
        Passed to :func:`write_csv` (``units``, ``channels``); the other
        formats take none.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ConfigError
        Unknown suffix, or keywords given for a netCDF or XML file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return write_csv(recording, path, **kw)
    if suffix not in (".nc", ".xml"):
        raise ConfigError(f"output '{path}': use a .nc (netCDF, lossless), .csv or .xml suffix")
    if kw:
        raise ConfigError(f"{path}: {suffix} files take no writer options, got {sorted(kw)}")
    if suffix == ".nc":
        return save_netcdf(recording, path)
    from .xml_format import write_xml

    return write_xml(recording, path)
