"""netCDF4 files of Recordings (the lossless native format).

The file is the Recording's dataset as is: dimension ``time`` (coordinate in
s), one float64 variable per channel with ``units``, and the global attributes
``fs`` [Hz] and ``drivesense_meta`` (metadata as JSON).  Saving and loading
round-trip bit-exactly.
"""

from __future__ import annotations

import errno
from pathlib import Path
from typing import TYPE_CHECKING

import xarray as xr

from ..errors import DriveSenseError, InvalidSignalError

if TYPE_CHECKING:  # pragma: no cover
    from ..recording import Recording

__all__ = ["save_netcdf", "load_netcdf"]


def save_netcdf(rec: Recording, path: str | Path) -> Path:
    """Write a Recording to a netCDF4 file, atomically.

    Parameters
    ----------
    rec : Recording
        The data.
    path : str or Path
        Target file (conventionally ``.nc``); replaced only once fully written.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    FileNotFoundError
        If the target directory does not exist.
    """
    from . import atomic_output

    path = Path(path)
    ds = rec.dataset.drop_encoding()
    encoding = {name: {"dtype": "float64", "_FillValue": None} for name in ds.variables}
    with atomic_output(path) as tmp:
        ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=encoding)
    return path


def load_netcdf(path: str | Path) -> Recording:
    """Read a Recording written by :func:`save_netcdf`.

    Parameters
    ----------
    path : str or Path
        A netCDF4 file.

    Returns
    -------
    Recording
        Validated; values, units, fs, t0 and metadata as saved.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    InvalidSignalError
        If the file is not netCDF, or not a drivesense recording (no ``time``
        dimension or no ``fs`` attribute); validation errors are prefixed with
        the file name.
    """
    from ..recording import Recording

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(errno.ENOENT, "netCDF file not found", str(path))
    try:
        with xr.open_dataset(path, engine="netcdf4", decode_times=False,
                             decode_timedelta=False) as ds:
            ds = ds.load()
    except (OSError, ValueError) as exc:
        raise InvalidSignalError(f"{path}: not a readable netCDF file ({exc})") from None
    missing = [what for what, ok in (("the 'time' dimension", "time" in ds.dims),
                                     ("the global attribute 'fs' (sampling rate in Hz)",
                                      "fs" in ds.attrs)) if not ok]
    if missing:
        raise InvalidSignalError(f"{path}: not a drivesense recording: {' and '.join(missing)} "
                                 "missing")
    try:
        return Recording(ds.drop_encoding())
    except DriveSenseError as exc:
        raise type(exc)(f"{path.name}: {exc}") from exc
