"""Recording: uniformly sampled multichannel drive signals with metadata.

A :class:`Recording` wraps an :class:`xarray.Dataset` with one dimension,
``time`` (coordinate in s, ``t0 + arange(n) / fs``), one data variable per
channel (float64, SI, unit string in ``attrs["units"]``) and two dataset
attributes: ``fs`` [Hz] and ``drivesense_meta`` (the metadata as a JSON string,
so that it survives netCDF, XML and databases unchanged).  Recordings are
immutable: every method returns a new one.

Canonical channel names and their units are listed in DESIGN.md and checked via
:func:`drivesense.units.quantity_of_channel`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike

from . import units as _units
from .errors import (
    ConfigError,
    InvalidSignalError,
    MissingChannelError,
    SignalTooShortError,
    TimebaseError,
    UnitError,
)
from .metadata import meta_to_json as _meta_to_json
from .timebase import check_fs, check_timebase, format_time, validate_timebase

__all__ = ["Recording", "validate_timebase", "META_ATTR"]

#: Dataset attribute holding the metadata as a JSON string.
META_ATTR = "drivesense_meta"


# ----------------------------------------------------------------- helpers
def _check_channel_name(name: Any) -> str:
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"channel names must be non-empty strings, got {name!r}")
    if name == "time":
        raise ConfigError("'time' is the time coordinate, not a channel: give fs and t0, "
                          "or use Recording.from_time_arrays")
    if "/" in name:
        raise ConfigError(f"channel name {name!r} contains '/', which netCDF does not allow")
    return name


def _si_unit_for(name: str, unit: str | None) -> tuple[str, float]:
    """Return (canonical SI unit, factor) for a unit given on channel `name`."""
    quantity = _units.quantity_of_channel(name)
    if unit is None:
        return (_units.si_unit(quantity) if quantity else "1"), 1.0
    info = _units.unit_info(unit, quantity=quantity, name=name)
    return _units.SI_UNITS[info.quantity], info.factor


def _channel_array(name: str, values: ArrayLike, unit: str | None,
                   n: int | None) -> tuple[np.ndarray, str]:
    """Convert one channel to a new 1-D float64 SI array; check its shape."""
    _check_channel_name(name)
    if unit is None:
        unit = _si_unit_for(name, None)[0]
    arr, si = _units.to_si(values, unit, quantity=_units.quantity_of_channel(name), name=name)
    if arr.ndim != 1:
        raise InvalidSignalError(f"channel {name!r} must be 1-D, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise InvalidSignalError(f"channel {name!r} has {arr.shape[0]} samples, expected {n}")
    return arr, si


def _check_finite(name: str, arr: np.ndarray, t0: float, fs: float) -> None:
    ok = np.isfinite(arr)
    if ok.all():
        return
    bad = np.flatnonzero(~ok)
    i = int(bad[0])
    kind = "NaN" if np.isnan(arr[i]) else ("inf" if arr[i] > 0 else "-inf")
    raise InvalidSignalError(f"channel {name!r} has {bad.size} non-finite values (first {kind} "
                             f"at sample {i}, t={format_time(t0 + i / fs, fs)} s)")


def _build_dataset(arrays: Mapping[str, tuple[np.ndarray, str]], fs: float, t0: float,
                   meta_json: str) -> xr.Dataset:
    n = next(iter(arrays.values()))[0].shape[0] if arrays else 0
    return xr.Dataset(
        {k: ("time", a, {"units": u}) for k, (a, u) in arrays.items()},
        coords={"time": ("time", t0 + np.arange(n) / fs, {"units": "s"})},
        attrs={"fs": fs, META_ATTR: meta_json},
    )


# ----------------------------------------------------------------- the class
class Recording:
    """Uniformly sampled multichannel drive signals with metadata.

    Parameters
    ----------
    dataset : xarray.Dataset
        Dimension ``time``; ``attrs["fs"]`` [Hz]; one 1-D data variable per
        channel with ``attrs["units"]`` (SI); optional ``attrs["drivesense_meta"]``
        (JSON string).  The ``time`` coordinate [s], if present, must match
        ``t0 + arange(n) / fs``; it is rebuilt exactly from ``fs`` and its first
        value (``attrs["t0"]``, default 0, when absent).
    validate : bool, optional
        Check shapes, finite values, units (known, SI, fitting the channel's
        quantity), at least 2 samples and the metadata (default True).

    Raises
    ------
    InvalidSignalError, SignalTooShortError, TimebaseError, UnitError, ConfigError
        When `validate` finds a problem; messages name the channel.

    Notes
    -----
    Unit aliases with factor 1 (``"Nm"``, ``"m/s2"``, ``"-"``) are rewritten to
    the canonical SI string; units with another factor (``"mm"``) are refused —
    convert with :meth:`from_arrays` (``units=``) or :func:`drivesense.units.to_si`.
    """

    def __init__(self, dataset: xr.Dataset, *, validate: bool = True) -> None:
        if not isinstance(dataset, xr.Dataset):
            raise TypeError(f"Recording wraps an xarray.Dataset, got {type(dataset).__name__}")
        ds = dataset.copy(deep=False)
        if "time" not in ds.dims:
            raise InvalidSignalError(f"dataset has no 'time' dimension (dims: {tuple(ds.dims)})")
        if "fs" not in ds.attrs:
            raise TimebaseError("dataset has no attrs['fs'] (sampling rate in Hz); build it with "
                                "Recording.from_arrays or Recording.from_time_arrays")
        fs = check_fs(ds.attrs["fs"])
        n = int(ds.sizes["time"])
        has_time = "time" in ds.coords and n > 0
        t0 = float(ds["time"].values[0]) if has_time else float(ds.attrs.get("t0", 0.0))
        grid = t0 + np.arange(n) / fs
        ds.attrs.setdefault(META_ATTR, "{}")
        ds.attrs["fs"] = fs
        ds.attrs.pop("t0", None)
        for name in list(ds.data_vars):
            var = ds[name]
            if var.dtype != np.float64:
                if var.dtype.kind not in "biuf":
                    raise InvalidSignalError(f"channel {name!r} has dtype {var.dtype}, "
                                             "expected real numbers")
                ds[name] = var.astype(np.float64)
        if validate:
            self._validate(ds, n, fs, t0, grid, has_time)
        self._ds = ds.assign_coords(time=("time", grid, {"units": "s"}))
        self._fs, self._t0, self._n = fs, t0, n

    @staticmethod
    def _validate(ds: xr.Dataset, n: int, fs: float, t0: float, grid: np.ndarray,
                  has_time: bool) -> None:
        try:
            meta = json.loads(ds.attrs[META_ATTR])
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"attrs[{META_ATTR!r}] is not a JSON string ({exc})") from None
        if not isinstance(meta, dict):
            raise ConfigError(f"attrs[{META_ATTR!r}] must hold a JSON object, got {meta!r:.60}")
        ds.attrs[META_ATTR] = _meta_to_json(meta)
        who = f"recording {meta['name']!r}" if meta.get("name") else "recording"
        if n < 2:
            raise SignalTooShortError(f"{who} has {n} sample(s); a Recording needs at least 2")
        if has_time:
            err = np.abs(ds["time"].values.astype(np.float64) - grid)
            i = int(np.argmax(err))
            if not err[i] <= 1e-6 / fs + 4 * np.finfo(float).eps * abs(grid[i]):
                raise TimebaseError(
                    f"{who}: the time coordinate disagrees with fs={fs:g} Hz at sample {i} "
                    f"(t={float(ds['time'].values[i])!r} s, the grid has {float(grid[i])!r} s)")
        for name, var in ds.data_vars.items():
            _check_channel_name(name)
            if var.dims != ("time",):
                raise InvalidSignalError(f"channel {name!r} has dims {var.dims}, "
                                         "expected ('time',)")
            if "units" not in var.attrs:
                raise UnitError(f"channel {name!r} has no attrs['units']")
            unit = var.attrs["units"]
            si, factor = _si_unit_for(name, unit)
            if factor != 1.0:
                raise UnitError(f"channel {name!r} is in {unit!r}, but a Recording holds SI "
                                f"({si!r}); convert with Recording.from_arrays(units=...)")
            var.attrs["units"] = si
            _check_finite(name, var.values, t0, fs)

    # ------------------------------------------------------------ builders
    @classmethod
    def from_arrays(cls, channels: Mapping[str, ArrayLike], *, fs: float, t0: float = 0.0,
                    units: Mapping[str, str] | None = None, meta: Mapping | None = None,
                    validate: bool = True) -> Recording:
        """Build a Recording from equally long 1-D arrays.

        Parameters
        ----------
        channels : mapping of str to array_like
            Channel name -> samples [unit from `units`, default SI] (at least
            one channel, at least 2 samples).
        fs : float
            Sampling rate [Hz].
        t0 : float, optional
            Time of the first sample [s] (default 0).
        units : mapping of str to str, optional
            Unit of each channel's values; non-SI units (``"mm"``) are converted
            to SI.  Default: the SI unit of the channel's quantity, ``"1"`` for
            names outside the data model.
        meta : mapping, optional
            JSON-serialisable metadata (numpy scalars and arrays are converted).
        validate : bool, optional
            Check finite values and the rest (default True).

        Returns
        -------
        Recording
        """
        fs = check_fs(fs)
        if not (isinstance(t0, (int, float, np.integer, np.floating)) and math.isfinite(t0)):
            raise TimebaseError(f"t0 must be a finite number of seconds, got {t0!r}")
        units = dict(units or {})
        extra = [k for k in units if k not in channels]
        if extra:
            raise ConfigError(f"units given for channel(s) not in channels: {extra}")
        if not channels:
            raise InvalidSignalError("from_arrays needs at least one channel")
        arrays: dict[str, tuple[np.ndarray, str]] = {}
        n = None
        for name, values in channels.items():
            arrays[name] = _channel_array(name, values, units.get(name), n)
            n = arrays[name][0].shape[0]
        return cls(_build_dataset(arrays, fs, float(t0), _meta_to_json(meta)), validate=validate)

    @classmethod
    def from_computed(cls, channels: Mapping[str, np.ndarray], units: Mapping[str, str], *, fs: float,
                      t0: float, meta: Mapping) -> Recording:
        """Wrap arrays the caller owns and vouches for (float64, 1-D, SI, finite) without copies.

        The fast path for computed results (estimator outputs), which are
        built from validated inputs; :meth:`from_arrays` validates.

        Parameters
        ----------
        channels : mapping of str to ndarray
            Channel name -> float64 samples [SI unit of the channel], equally
            long, finite.
        units : mapping of str to str
            SI unit of each channel.
        fs : float
            Sampling rate [Hz].
        t0 : float
            Time of the first sample [s].
        meta : mapping
            JSON-serialisable metadata.
        """
        n = next(iter(channels.values())).shape[0]
        grid = float(t0) + np.arange(n) / float(fs)
        ds = xr.Dataset({k: ("time", a, {"units": units[k]}) for k, a in channels.items()},
                        coords={"time": ("time", grid, {"units": "s"})},
                        attrs={"fs": float(fs), META_ATTR: _meta_to_json(meta)})
        rec = cls.__new__(cls)
        rec._ds = ds
        rec._fs, rec._t0, rec._n = float(fs), float(t0), n
        return rec

    @classmethod
    def from_time_arrays(cls, time: ArrayLike, channels: Mapping[str, ArrayLike],
                         units: Mapping[str, str] | None = None, meta: Mapping | None = None,
                         rel_tol: float = 1e-3) -> Recording:
        """Build a Recording from explicit, (nearly) uniform time stamps.

        Parameters
        ----------
        time : array_like
            Time stamps [s] (or in the unit ``units["time"]``, if given).
        channels : mapping of str to array_like
            Channel name -> samples [unit from `units`, default SI], as long as `time`.
        units : mapping of str to str, optional
            Units of the channels (converted to SI) and optionally of ``"time"``.
        meta : mapping, optional
            JSON-serialisable metadata.
        rel_tol : float, optional
            Allowed step jitter as a fraction of the median step [-], see
            :func:`validate_timebase`.

        Returns
        -------
        Recording
            fs from :func:`validate_timebase`, t0 = first stamp; the stamps are
            replaced by the uniform grid, and the provenance says so.
        """
        units = dict(units or {})
        t, _ = _units.to_si(time, units.pop("time", "s"), quantity=_units.TIME, name="time")
        fs, jitter = check_timebase(t, rel_tol, "time", None, "sample")
        for name, values in channels.items():
            if np.shape(values)[:1] != (t.size,):
                raise InvalidSignalError(f"channel {name!r} has shape {np.shape(values)}, "
                                         f"but there are {t.size} time stamps")
        rec = cls.from_arrays(channels, fs=fs, t0=float(t[0]), units=units, meta=meta)
        return rec.with_provenance(f"from_time_arrays: uniform grid fs={fs:.12g} Hz from "
                                   f"{t.size} stamps (max step jitter {100 * jitter:.3g} %)")

    # ------------------------------------------------------------ properties
    @property
    def fs(self) -> float:
        """Sampling rate [Hz]."""
        return self._fs

    @property
    def dt(self) -> float:
        """Sampling period [s]."""
        return 1.0 / self._fs

    @property
    def t0(self) -> float:
        """Time of the first sample [s]."""
        return self._t0

    @property
    def time(self) -> np.ndarray:
        """Sample times [s], ``t0 + arange(n) / fs`` (read-only array)."""
        return self._readonly(self._ds["time"].values)

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return self._n

    @property
    def duration(self) -> float:
        """Duration n_samples * dt [s]."""
        return self._n / self._fs

    @property
    def channels(self) -> list[str]:
        """Channel names, in order."""
        return [str(k) for k in self._ds.data_vars]

    @property
    def meta(self) -> dict:
        """Metadata (a fresh copy; change it with :meth:`with_meta`)."""
        return json.loads(self._ds.attrs[META_ATTR])

    @property
    def name(self) -> str | None:
        """``meta["name"]``, or None."""
        return self.meta.get("name")

    @property
    def dataset(self) -> xr.Dataset:
        """The underlying dataset (a shallow copy; do not modify its arrays)."""
        return self._ds.copy(deep=False)

    @staticmethod
    def _readonly(a: np.ndarray) -> np.ndarray:
        v = a.view()
        v.flags.writeable = False
        return v

    def __len__(self) -> int:
        return self._n

    def __contains__(self, name: object) -> bool:
        return name in self._ds.data_vars

    def __iter__(self) -> Iterator[str]:
        return iter(self.channels)

    def __getitem__(self, name: str) -> np.ndarray:
        """Samples of channel `name` (float64, SI, read-only view)."""
        self.require(name)
        return self._readonly(self._ds.variables[name].values)     # the Variable: no DataArray built (20x faster)

    def units(self, name: str) -> str:
        """SI unit string of channel `name`.

        Parameters
        ----------
        name : str

        Returns
        -------
        str
        """
        self.require(name)
        return self._ds[name].attrs["units"]

    def require(self, *names: str) -> None:
        """Check that channels are present.

        Parameters
        ----------
        *names : str
            Channel names.

        Raises
        ------
        MissingChannelError
            Naming the recording, the missing channels and the ones it has.
        """
        missing = [n for n in names if n not in self._ds.data_vars]
        if missing:
            name = self.name
            who = f"recording {name!r}" if name else "recording"
            raise MissingChannelError(
                f"{who} lacks channel(s) {', '.join(repr(m) for m in missing)} "
                f"(has: {', '.join(self.channels) or 'none'})")

    # ------------------------------------------------------------ derived
    def _derive(self, ds: xr.Dataset) -> Recording:
        return type(self)(ds, validate=False)

    def slice_time(self, start: float | None = None, end: float | None = None) -> Recording:
        """Samples with start <= t < end (absolute times [s]).

        Parameters
        ----------
        start, end : float, optional
            Window [s]; None means the first / past the last sample.  A bound
            within 1e-6 samples of a sample time counts as that sample.

        Returns
        -------
        Recording

        Raises
        ------
        SignalTooShortError
            If fewer than 2 samples fall in the window.
        """
        def index(t: float | None, default: int) -> int:
            if t is None:
                return default
            if not (isinstance(t, (int, float, np.integer, np.floating)) and math.isfinite(t)):
                raise ConfigError(f"slice_time bounds must be finite seconds, got {t!r}")
            return int(min(max(math.ceil((t - self._t0) * self._fs - 1e-6), 0), self._n))

        i0, i1 = index(start, 0), index(end, self._n)
        if i1 - i0 < 2:
            who = f"recording {self.name!r}" if self.name else "recording"
            raise SignalTooShortError(
                f"{who}: slice_time(start={start}, end={end}) keeps {max(i1 - i0, 0)} sample(s), "
                f"a Recording needs 2; the data span t={self._t0:g} .. "
                f"{self._t0 + self.duration:g} s")
        return self._derive(self._ds.isel(time=slice(i0, i1)))

    def with_channels(self, channels: Mapping[str, ArrayLike],
                      units: Mapping[str, str] | None = None) -> Recording:
        """Add or replace channels on the same time base.

        Parameters
        ----------
        channels : mapping of str to array_like
            Name -> n_samples values [unit from `units`, default SI].
        units : mapping of str to str, optional
            Units of the given values (converted to SI); default SI.

        Returns
        -------
        Recording
        """
        units = dict(units or {})
        extra = [k for k in units if k not in channels]
        if extra:
            raise ConfigError(f"units given for channel(s) not in channels: {extra}")
        ds = self._ds.copy(deep=False)
        for name, values in channels.items():
            arr, si = _channel_array(name, values, units.get(name), self._n)
            _check_finite(name, arr, self._t0, self._fs)
            ds[name] = xr.Variable(("time",), arr, {"units": si})
        return self._derive(ds)

    def select(self, *names: str) -> Recording:
        """Keep only some channels (in the order given).

        Parameters
        ----------
        *names : str
            Channel names.

        Returns
        -------
        Recording
        """
        if not names:
            raise ConfigError("select() needs at least one channel name")
        self.require(*names)
        return self._derive(self._ds[list(dict.fromkeys(names))])

    def with_meta(self, **updates: Any) -> Recording:
        """Copy with metadata keys added or replaced.

        Parameters
        ----------
        **updates
            JSON-serialisable values.

        Returns
        -------
        Recording
        """
        ds = self._ds.copy(deep=False)
        ds.attrs = {**ds.attrs, META_ATTR: _meta_to_json({**self.meta, **updates})}
        return self._derive(ds)

    def with_provenance(self, step: str) -> Recording:
        """Copy with `step` appended to ``meta["provenance"]``.

        Parameters
        ----------
        step : str
            What was done, e.g. ``"read_csv cut_03.csv: converted ..."``.

        Returns
        -------
        Recording
        """
        if not isinstance(step, str):
            raise ConfigError(f"a provenance step must be a string, got {step!r}")
        prov = self.meta.get("provenance", [])
        if not isinstance(prov, list):
            raise ConfigError(f"meta['provenance'] must be a list of strings, got {prov!r:.60}")
        return self.with_meta(provenance=[*prov, step])

    # ------------------------------------------------------------ output
    def equals(self, other: Recording) -> bool:
        """Whether two recordings hold bit-identical data, units, fs, t0 and meta.

        Parameters
        ----------
        other : Recording

        Returns
        -------
        bool
        """
        return (isinstance(other, Recording) and self._fs == other._fs
                and self._t0 == other._t0 and self._n == other._n
                and self.channels == other.channels and self.meta == other.meta
                and all(self.units(c) == other.units(c)
                        and np.array_equal(self._ds[c].values, other._ds[c].values)
                        for c in self.channels))

    def __repr__(self) -> str:
        chans = self.channels
        shown = ", ".join(chans[:6]) + (", ..." if len(chans) > 6 else "")
        name = f" {self.name!r}" if self.name else ""
        return (f"<Recording{name}: {len(chans)} channel(s) [{shown}], {self._n} samples "
                f"@ {self._fs:g} Hz, {self.duration:g} s from t0={self._t0:g} s>")
