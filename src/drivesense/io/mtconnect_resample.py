"""MTConnect observations -> a uniformly sampled Recording, resampled explicitly.

MTConnect agents report samples when they change (and adapters poll at
irregular times), so a Recording needs a resampling step.  :func:`to_recording`
does it in the open: it picks (or is given) a rate, builds a grid from the
latest first observation to the last observation, interpolates each channel
linearly or holds its last value, bridges ``UNAVAILABLE`` stretches (listing
them as gaps) and records all of it in the provenance.  Events, messages,
alarms and conditions become time-stamped lists in ``meta["mtconnect"]``,
as do the assets of an SHDR log (cutting tools, their removals and updates).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from .. import units as _units
from ..errors import ConfigError, InvalidSignalError, SignalTooShortError
from ..recording import Recording
from .mtconnect import DeviceModel, Observation, snake_case, parse_devices, parse_shdr, parse_streams
from .mtconnect_assets import ASSET_KINDS

__all__ = ["to_recording", "read_mtconnect", "MAX_EVENTS", "MAX_SAMPLES"]

#: Events kept per data item in the metadata (the rest are counted, not kept).
MAX_EVENTS = 10_000
#: Largest grid :func:`to_recording` builds (samples per channel).
MAX_SAMPLES = 50_000_000
_VEC = ("x", "y", "z")


def _iso(us: int) -> str:
    return datetime.fromtimestamp(us // 1_000_000, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S") + \
        f".{us % 1_000_000:06d}Z"


def _expand(obs: Observation, rate: float | None, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Times [us] and values of a time-series observation (timestamp = last value)."""
    arr = obs.value
    if arr is None:
        return np.array([obs.time_us]), np.array([np.nan])
    if not rate:
        raise InvalidSignalError(f"time series {key!r} has no sampleRate (neither the observation nor "
                                 "the DataItem gives one)")
    n = arr.size
    times = obs.time_us - np.round((n - 1 - np.arange(n)) * 1e6 / rate).astype(np.int64)
    return times, arr.astype(float)


def _collect(observations: Sequence[Observation], devices: DeviceModel | None, native: bool
             ) -> tuple[dict, dict, dict, dict]:
    series: dict[str, list] = {}
    info: dict[str, dict] = {}
    events: dict[str, list] = {}
    skipped: dict[str, str] = {}
    for obs in observations:
        item = devices.lookup(obs.key) if devices else None
        label = (item.name or item.id) if item else obs.key
        numeric = obs.kind in ("SAMPLE", "TIME_SERIES") and not isinstance(obs.value, str)
        scale = item.scale(native) if item else (1.0, "1")
        if numeric and scale is None:
            skipped[label] = f"unit {item.native_units if native and item.native_units else item.units} has " \
                             "no SI entry in drivesense"
        if not numeric or scale is None:
            events.setdefault(label, []).append(obs)
            continue
        base = item.channel if item else snake_case(obs.key) or obs.key
        factor, unit = scale
        if obs.kind == "TIME_SERIES":
            rate = obs.extra.get("sample_rate") or (item.sample_rate if item else None)
            t, v = _expand(obs, rate, label)
            parts = [(base, t, v)]
        elif isinstance(obs.value, tuple):
            names = _VEC if len(obs.value) == 3 else [str(i) for i in range(len(obs.value))]
            parts = [(f"{base}_{s}", np.array([obs.time_us]), np.array([v])) for s, v in zip(names, obs.value)]
        else:
            parts = [(base, np.array([obs.time_us]), np.array([np.nan if obs.value is None else obs.value]))]
        for name, t, v in parts:
            q = _units.quantity_of_channel(name)
            if q is not None and _units.SI_UNITS[q] != unit:
                name = f"{name}_{snake_case(obs.key)}"  # e.g. a linear 'position' in degrees: not the canonical one
            series.setdefault(name, []).append((t, v * factor))
            info.setdefault(name, {"key": obs.key, "units": unit, **({
                "id": item.id, "type": item.type, "sub_type": item.sub_type,
                "mtconnect_units": item.native_units if native and item.native_units else item.units}
                if item else {"mtconnect_units": "unknown"})})
    return series, info, events, skipped


def _event_meta(events: dict[str, list], start_us: int) -> dict:
    out: dict[str, Any] = {"events": {}, "conditions": [], "messages": []}
    for label, obs_list in events.items():
        for k, obs in enumerate(obs_list):
            t = round((obs.time_us - start_us) * 1e-6, 6)
            value = obs.value if isinstance(obs.value, (str, type(None))) else \
                (list(np.atleast_1d(obs.value).tolist()) if obs.kind == "TIME_SERIES" else obs.value)
            if obs.kind == "CONDITION":
                out["conditions"].append({"t": t, "item": label, "level": value, **obs.extra})
            elif obs.kind in ("MESSAGE", "ALARM"):
                out["messages"].append({"t": t, "item": label, "text": value, **obs.extra})
            elif k < MAX_EVENTS:
                out["events"].setdefault(label, []).append([t, value])
        if len(obs_list) > MAX_EVENTS:
            out.setdefault("events_truncated", {})[label] = len(obs_list)
    return out


def _asset_meta(assets: Sequence[Observation], start_us: int) -> dict:
    """Assets, removals and updates in the order the adapter sent them (the order the agent applies them)."""
    out: dict[str, list] = {"assets": [], "asset_removals": [], "asset_updates": []}
    where = {"ASSET": "assets", "ASSET_REMOVED": "asset_removals", "ASSET_UPDATED": "asset_updates"}
    for obs in assets:  # not sorted: an adapter clears its assets, then resends them with older times
        entry: dict[str, Any] = {"t": round((obs.time_us - start_us) * 1e-6, 6), "time_utc": _iso(obs.time_us)}
        if obs.kind == "ASSET":
            entry.update(obs.value)
        elif obs.kind == "ASSET_REMOVED":
            entry.update({"asset_id": None if obs.extra.get("all") else obs.key, **obs.extra})
        else:
            entry.update({"asset_id": obs.key, "changes": obs.value})
        out[where[obs.kind]].append(entry)
    for key, entries in out.items():
        if len(entries) > MAX_EVENTS:
            out.setdefault("assets_truncated", {})[key] = len(entries)
            out[key] = entries[-MAX_EVENTS:]
    return out if assets else {}


def to_recording(observations: Sequence[Observation], devices: DeviceModel | None = None, *,
                 fs: float | None = None, method: str = "linear", native: bool = False,
                 name: str | None = None, source: str = "mtconnect", extra_meta: dict | None = None
                 ) -> Recording:
    """Resample MTConnect observations onto a uniform grid.

    Parameters
    ----------
    observations : sequence of Observation
        From :func:`~drivesense.io.mtconnect.parse_streams` or
        :func:`~drivesense.io.mtconnect.parse_shdr`.
    devices : DeviceModel, optional
        Maps keys to channels and units (without it, channels are named after
        the keys and units are unknown: ``"1"``, noted in the metadata).
    fs : float, optional
        Output rate [Hz]; default: the densest channel's median reporting rate
        (a time series' own rate if higher), rounded to 3 significant digits.
    method : {"linear", "hold"}, optional
        Linear interpolation between reports (default), or zero-order hold
        (each report holds until the next: right for on-change reporting).
    native : bool, optional
        Values are in the DataItems' native units (SHDR adapter logs).
    name : str, optional
        ``meta["name"]``.
    source : str, optional
        Where the data came from (file or URL), for the provenance.
    extra_meta : dict, optional
        Merged into ``meta["mtconnect"]`` (e.g. sequence ranges, lost data).

    Returns
    -------
    Recording
        t0 = 0 at the grid start (``meta["start_time_utc"]``); SI channels.
        SHDR assets go to ``meta["mtconnect"]`` in the order they were sent
        (their times may run backwards: each asset carries its own): ``assets``
        (``t`` [s] from the grid start, ``time_utc``, ``asset_id``, ``type``
        and a cutting tool's ``tool_id``, ``serial_number``, ``status``,
        ``tool_life``...), ``asset_removals`` and ``asset_updates``.

    Raises
    ------
    InvalidSignalError
        No numeric samples, or a grid over :data:`MAX_SAMPLES`.
    SignalTooShortError
        The observations span less than two samples at `fs`.
    """
    if method not in ("linear", "hold"):
        raise ConfigError(f"--method must be linear or hold (zero-order hold), got {method!r}")
    assets = [o for o in observations if o.kind in ASSET_KINDS]
    observations = [o for o in observations if o.kind not in ASSET_KINDS]
    series, info, events, skipped = _collect(observations, devices, native)
    if not series:
        raise InvalidSignalError(f"{source}: no numeric samples to resample ({len(observations)} observations, "
                                 "all events/conditions)")
    data: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for ch, parts in series.items():
        t = np.concatenate([p[0] for p in parts])
        v = np.concatenate([p[1] for p in parts])
        order = np.argsort(t, kind="stable")
        data[ch] = (t[order], v[order])
    valid = {ch: (t[np.isfinite(v)], v[np.isfinite(v)]) for ch, (t, v) in data.items()}
    empty = [ch for ch, (t, _) in valid.items() if t.size == 0]
    for ch in empty:
        skipped[ch] = "never available"
        del valid[ch]
    if not valid:
        raise InvalidSignalError(f"{source}: every numeric data item is UNAVAILABLE throughout")
    if fs is None:
        rates = []
        for ch, (t, _) in valid.items():
            d = np.diff(np.unique(t))
            if d.size:
                rates.append(1e6 / float(np.median(d)))
        if not rates:
            raise SignalTooShortError(f"{source}: one observation per data item; give the output rate with --fs HZ")
        fs = float(f"{max(rates):.3g}")
        how = "the densest reporting rate, median"
    else:
        fs = float(fs)
        if not (math.isfinite(fs) and fs > 0):
            raise ConfigError(f"--fs must be a positive number of Hz, got {fs!r}")
        how = "given"
    start = max(int(t[0]) for t, _ in valid.values())
    stop = max(int(t[-1]) for t, _ in valid.values())
    n = int(math.floor((stop - start) * 1e-6 * fs + 1e-9)) + 1
    if n < 2:
        raise SignalTooShortError(f"{source}: the observations overlap for {(stop - start) * 1e-6:g} s, less than "
                                  f"two samples at {fs:g} Hz")
    if n > MAX_SAMPLES:
        raise InvalidSignalError(f"{source}: {n} samples at {fs:g} Hz; choose a lower --fs")
    grid = np.arange(n) / fs
    channels, units, gaps = {}, {}, {}
    for ch, (t, v) in valid.items():
        rel = (t - start) * 1e-6
        rev_t, idx = np.unique(rel[::-1], return_index=True)  # last report wins at equal times
        vals = v[::-1][idx]
        if method == "linear":
            channels[ch] = np.interp(grid, rev_t, vals)
        else:
            channels[ch] = vals[np.clip(np.searchsorted(rev_t, grid, side="right") - 1, 0, None)]
        units[ch] = info[ch]["units"]
        t_all, v_all = data[ch]
        bad = np.flatnonzero(~np.isfinite(v_all))
        if bad.size:
            spans = []
            for b in bad:
                later = np.flatnonzero((t_all > t_all[b]) & np.isfinite(v_all))
                end_us = t_all[later[0]] if later.size else stop
                spans.append([round((t_all[b] - start) * 1e-6, 6), round((end_us - start) * 1e-6, 6)])
            gaps[ch] = spans
    meta_mtc = {"data_items": {ch: info[ch] for ch in channels}, **_event_meta(events, start),
                "gaps": gaps, "skipped": skipped, **_asset_meta(assets, start), **(extra_meta or {})}
    if devices and devices.devices:
        meta_mtc["device"] = devices.devices[0]
    meta = {"name": name or Path(str(source)).stem or "mtconnect", "source": "mtconnect",
            "start_time_utc": _iso(start), "mtconnect": meta_mtc}
    if devices and devices.devices:
        dev = devices.devices[0]
        meta["machine"] = " ".join(s for s in (dev.get("manufacturer"), dev.get("model"), dev.get("name")) if s)
    rec = Recording.from_arrays(channels, fs=fs, units=units, meta=meta)
    n_obs = sum(len(p) for p in series.values())
    step = (f"mtconnect {source}: {n_obs} irregular observations of {len(channels)} channel(s) resampled to a "
            f"uniform grid at fs={fs:g} Hz ({how}) by {'linear interpolation' if method == 'linear' else 'zero-order hold'}"
            f", {n} samples from {_iso(start)} (the latest first report) to {_iso(stop)}")
    if gaps:
        step += f"; UNAVAILABLE gaps bridged in {', '.join(sorted(gaps))} (see meta mtconnect.gaps)"
    if skipped:
        step += f"; not resampled: {', '.join(sorted(skipped))} (see meta mtconnect.skipped)"
    return rec.with_provenance(step)


def read_mtconnect(path: str | Path, devices: DeviceModel | str | Path | None = None, *, fs: float | None = None,
                   method: str = "linear") -> Recording:
    """Read a Streams document (``.xml``) or an SHDR log into a Recording.

    Parameters
    ----------
    path : str or Path
        A saved ``/sample`` (or ``/current``) answer, or an adapter's SHDR log
        (told apart by the first character: ``<`` is XML).
    devices : DeviceModel, str or Path, optional
        The Devices document (``/probe``) for channel names and units.
    fs : float, optional
        Output rate [Hz] (see :func:`to_recording`).
    method : {"linear", "hold"}, optional
        Resampling method.

    Returns
    -------
    Recording
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(2, "MTConnect file not found", str(path))
    if devices is not None and not isinstance(devices, DeviceModel):
        devices = parse_devices(devices)
    with open(path, "rb") as fh:
        head = fh.read(512).lstrip(b"\xef\xbb\xbf \t\r\n")
    if head.startswith(b"<"):
        doc = parse_streams(path)
        h = doc.header
        extra = {"instance_id": h.get("instance_id"),
                 "sequences": [doc.observations[0].sequence, doc.observations[-1].sequence]
                 if doc.observations else []}
        return to_recording(doc.observations, devices, fs=fs, method=method, source=path.name,
                            name=path.stem, extra_meta=extra)
    obs = parse_shdr(path, devices)
    return to_recording(obs, devices, fs=fs, method=method, native=True, source=path.name, name=path.stem)
