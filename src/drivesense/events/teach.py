"""Teach-in limits, the industry's standard: bands learnt from good runs of one NC program.

:func:`teach` cuts every good run into bins -- of program time (``align="time"``),
of tool path length (``align="path"``: the distance travelled by the
table-position channels, so a feed-rate override does not shift the bands),
or per tool and block of the NC program (``align="block"``, from the NC's
context: the bins of each visit of a block count the path, or the time, from
where the block began, so a dwell, a skipped block or an override ahead
cannot shift the bands of the blocks after it) -- and takes per bin and
channel the mean magnitude of the signal (force [N], spindle power [W]).  The band is the runs' range widened by ``tolerance``
and a noise floor::

    upper = max_runs * (1 + tolerance) + floor,     lower = min_runs * (1 - tolerance) - floor

:class:`TeachInDetector` streams a new run through the same bins and raises an
event when ``persist_bins`` bins in a row leave the band: ``limit`` (too high:
overload, wear; too low: a broken or chipped tool) or ``missing_tool`` (a bin
the good runs cut in, at the level of air).  The limits are strict JSON
(:meth:`TeachLimits.to_json`), written atomically by the CLI
(``drivesense teach``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from drivesense.errors import ConfigError, MissingChannelError, SignalTooShortError
from drivesense.machine.milling import check_int, check_number
from drivesense.events.detector import Detector
from drivesense.recording import Recording

__all__ = ["TeachLimits", "teach", "TeachInDetector", "PathMeter", "path_length", "PATH_CHORD_M"]

_ALIGN = ("time", "path", "block")
_FORMAT = "drivesense teach-in limits 1"
_FORMAT_BLOCKS = "drivesense teach-in limits 2"     # with the blocks' bins: written only when align="block"


def _path_channels(names: Sequence[str]) -> list[str]:
    """Table-position channels that measure the tool path (``*_table_position``)."""
    return sorted(c for c in names if c.endswith("_table_position"))


#: Chord of the path meter [m]: the path grows by straight steps of at least this length, so that the
#: table's vibration and the scale's noise (nm to um, at every sample) add nothing to it.
PATH_CHORD_M = 0.1e-3


@njit(cache=True, nogil=True)
def _chord_path(pos, anchor, acc, chord):  # pragma: no cover - compiled
    """Path [m] at each sample: the chords so far plus the farthest the table has gone from the last chord's
    end (never back: a bin must not be left and entered again on a vibration); ``acc``: [chords, farthest]."""
    k, n = pos.shape
    out = np.empty(n)
    for i in range(n):
        d2 = 0.0
        for a in range(k):
            d = pos[a, i] - anchor[a]
            d2 += d * d
        d = np.sqrt(d2)
        if d >= chord:
            acc[0] += d
            acc[1] = 0.0
            for a in range(k):
                anchor[a] = pos[a, i]
        elif d > acc[1]:
            acc[1] = d
        out[i] = acc[0] + acc[1]
    return out


class PathMeter:
    """Distance travelled along the tool path [m], sample by sample, carried across chunks.

    Summing every sample's step would add the table's vibration under the cut to the path, and more of it
    the longer a run takes: a run slowed by an override would read millimetres further than the taught runs
    at the same place of the part (2.9 mm against 0.6 mm after 17 s in one bench program).
    The meter adds straight chords of at least ``chord`` instead.

    Parameters
    ----------
    chord : float
        Least chord [m].
    """

    def __init__(self, chord: float = PATH_CHORD_M) -> None:
        self.chord = check_number(chord, "chord", positive=True)
        self.anchor: np.ndarray | None = None
        self.acc = np.zeros(2)

    def advance(self, positions: Sequence[np.ndarray]) -> np.ndarray:
        """The path at each of the next samples [m].

        Parameters
        ----------
        positions : sequence of ndarray
            Position per axis [m], equally long.
        """
        if not positions:
            raise MissingChannelError("path alignment needs table-position channels (*_table_position)")
        pos = np.ascontiguousarray(np.vstack([np.asarray(p, dtype=float) for p in positions]))
        if pos.shape[1] == 0:
            return np.zeros(0)
        if self.anchor is None or self.anchor.size != pos.shape[0]:
            self.anchor = pos[:, 0].copy()
        return _chord_path(pos, self.anchor, self.acc, self.chord)


def _positions(arrays: Mapping[str, np.ndarray]) -> list[np.ndarray]:
    """The table positions [m] (the ``*_table_position`` channels) that measure the tool path."""
    return [np.asarray(arrays[c], dtype=float) for c in _path_channels(list(arrays))]


def path_length(positions: Sequence[np.ndarray]) -> np.ndarray:
    """Distance travelled along the given position channels [m] (:class:`PathMeter` over a whole run).

    Parameters
    ----------
    positions : sequence of ndarray
        Position per axis [m], equally long.
    """
    return PathMeter().advance(positions)


@dataclass
class TeachLimits:
    """Bands per bin and channel, learnt from good runs.

    Attributes
    ----------
    channels : tuple of str
        Channels the bands are for (``force_x`` [N], ``spindle_power`` [W] ...).
    align : {"time", "path", "block"}
        Bins of program time [s], of tool-path length [m], or per tool and block (:attr:`segments`).
    bin_width : float
        Width of a bin [s] or [m].
    mean, upper, lower : dict of str to ndarray
        Per channel and bin: the runs' mean magnitude and the band [unit of the channel].
    runs : int
        Good runs taught.
    force_limit_n : float
        Collision/overload limit derived from the runs: ``limit_factor`` times their largest force [N].
    feed : ndarray or None
        The runs' mean feed speed per bin [m/s] (when they had ``feed_speed``): a run at another feed
        (an override) has its band widened by the ratio, down for a slower feed, up for a faster one.
    segments : tuple of (tool, block, visit, first bin, bins), optional
        ``align="block"``: where each visit of a block (with its tool) has its bins (the k-th time the
        program entered that block with that tool, k from 0).
    within : str
        ``align="block"``: what the bins count from the block's start, ``"path"`` [m] or ``"time"`` [s].
    override : ndarray or None
        The runs' mean feed override per bin [-] (when they had ``feed_override``): the NC's ratio, which
        widens the band as the measured feed does, without waiting for the axes.
    """

    channels: tuple
    align: str
    bin_width: float
    mean: dict
    upper: dict
    lower: dict
    runs: int
    force_limit_n: float
    feed: np.ndarray | None = None
    segments: tuple = ()
    within: str = "path"
    override: np.ndarray | None = None

    @property
    def unit(self) -> str:
        """Unit of a bin's width: ``"s"`` or ``"m"``."""
        return "s" if self.align == "time" or (self.align == "block" and self.within == "time") else "m"

    @property
    def bins(self) -> int:
        """Number of bins."""
        return len(next(iter(self.mean.values())))

    def to_json(self) -> dict:
        """Strict JSON (no NaN): the document ``drivesense teach --out`` writes."""
        doc = {"format": _FORMAT_BLOCKS if self.align == "block" else _FORMAT, "channels": list(self.channels),
               "align": self.align, "bin_width": self.bin_width, "bin_unit": self.unit, "runs": self.runs,
               "force_limit_n": self.force_limit_n,
               "feed_m_per_s": None if self.feed is None else self.feed.tolist(),
               "bands": {c: {"mean": self.mean[c].tolist(), "upper": self.upper[c].tolist(),
                             "lower": self.lower[c].tolist()} for c in self.channels}}
        if self.align == "block":
            doc.update({"within": self.within, "feed_override": None if self.override is None else
                        self.override.tolist(),
                        "segments": [{"tool": t, "block": b, "visit": v, "first_bin": f, "bins": n}
                                     for t, b, v, f, n in self.segments]})
        return doc

    @classmethod
    def from_json(cls, doc: Mapping) -> "TeachLimits":
        """Read limits written by :meth:`to_json` (checked field by field).

        Parameters
        ----------
        doc : mapping
            The parsed LIMITS.json.
        """
        if not isinstance(doc, Mapping) or doc.get("format") not in (_FORMAT, _FORMAT_BLOCKS):
            raise ConfigError(f"--limits: not a teach-in limits file (its 'format' must be {_FORMAT!r} or "
                              f"{_FORMAT_BLOCKS!r}; write one with 'drivesense teach')")
        try:
            channels = tuple(str(c) for c in doc["channels"])
            align = str(doc["align"])
            width = check_number(doc["bin_width"], "bin_width", positive=True)
            bands = doc["bands"]
            arrays = {k: {c: np.asarray(bands[c][k], dtype=float) for c in channels}
                      for k in ("mean", "upper", "lower")}
            runs = check_int(doc["runs"], "runs")
            limit = check_number(doc["force_limit_n"], "force_limit_n", positive=True)
            feed = doc.get("feed_m_per_s")
            feed = None if feed is None else np.asarray(feed, dtype=float)
            override = doc.get("feed_override")
            override = None if override is None else np.asarray(override, dtype=float)
            segments = tuple((float(g["tool"]), float(g["block"]), int(g["visit"]), int(g["first_bin"]),
                              int(g["bins"])) for g in doc.get("segments", []))
            within = str(doc.get("within", "path"))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"--limits: a field is missing or malformed ({exc})") from None
        if align not in _ALIGN:
            raise ConfigError(f"--limits: 'align' must be 'time', 'path' or 'block', got {align!r}")
        if align == "block" and (not segments or within not in ("path", "time")):
            raise ConfigError("--limits: block-aligned limits need their 'segments' and 'within' (path or time)")
        sizes = {a.size for d in arrays.values() for a in d.values()}
        if len(sizes) != 1 or not all(np.all(np.isfinite(a)) for d in arrays.values() for a in d.values()):
            raise ConfigError("--limits: the bands must be finite and equally long")
        shape = next(iter(arrays["mean"].values())).shape
        for name, extra in (("feed_m_per_s", feed), ("feed_override", override)):
            if extra is not None and (extra.shape != shape or not np.all(np.isfinite(extra))):
                raise ConfigError(f"--limits: {name!r} must be finite and as long as the bands")
        if segments and sum(g[4] for g in segments) != shape[0]:
            raise ConfigError("--limits: the segments' bins do not add up to the bands' length")
        return cls(channels, align, width, arrays["mean"], arrays["upper"], arrays["lower"], runs, limit, feed,
                   segments, within, override)

    def dumps(self) -> str:
        """The JSON text (strict)."""
        return json.dumps(self.to_json(), indent=1, allow_nan=False)


class _BlockClock:
    """Where a run is in its NC program, sample by sample, carried across chunks: the tool, block and visit
    of each sample (the k-th entry into that block with that tool) and the path [m] (or time [s]) since the
    visit began."""

    def __init__(self, within: str, fs: float) -> None:
        self.within, self.fs = within, float(fs)
        self.key: tuple | None = None
        self.visits: dict = {}
        self.origin = self.done = 0.0          # position where the visit began; position so far
        self.meter = PathMeter()
        self.samples = 0

    def advance(self, arrays: Mapping[str, np.ndarray]) -> tuple[list[tuple], np.ndarray, np.ndarray]:
        """(the visits' keys, each sample's index into them, each sample's position in its visit)."""
        block = np.asarray(arrays["block_number"], dtype=float)
        n = block.size
        tool = np.asarray(arrays["tool_number"], dtype=float) if "tool_number" in arrays else np.zeros(n)
        if self.within == "path":
            s = self.meter.advance(_positions(arrays))
        else:
            s = (self.samples + np.arange(n)) / self.fs
        self.samples += n
        starts = np.flatnonzero((np.diff(block, prepend=np.nan) != 0) | (np.diff(tool, prepend=np.nan) != 0))
        keys, which, origin = [], np.zeros(n, dtype=np.int64), np.empty(n)
        bounds = np.append(starts, n)
        for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            here = (float(tool[a]), float(block[a]))
            if j > 0 or self.key is None or here != self.key[:2]:
                visit = self.visits.get(here, -1) + 1
                self.visits[here] = visit
                self.key, self.origin = (*here, visit), float(s[a - 1]) if a > 0 else self.done
            keys.append(self.key)
            which[a:b] = j
            origin[a:b] = self.origin
        self.done = float(s[-1]) if n else self.done
        return keys, which, s - origin


def _block_index(keys: list[tuple], which: np.ndarray, pos: np.ndarray, width: float,
                 offsets: Mapping[tuple, tuple[int, int]]) -> np.ndarray:
    """Flat bin of each sample (-1 where its block visit has no bins, or is past them)."""
    out = np.full(which.size, -1, dtype=np.int64)
    local = np.floor(pos / width).astype(np.int64)
    for j, key in enumerate(keys):
        if key in offsets:
            first, count = offsets[key]
            sel = (which == j) & (local < count)
            out[sel] = first + local[sel]
    return out


def _bin_index(rec: Recording, align: str, width: float) -> np.ndarray:
    if align == "time":
        return np.floor((rec.time - rec.t0) / width).astype(np.int64)
    chans = _path_channels(rec.channels)
    return np.floor(path_length([rec[c] for c in chans]) / width).astype(np.int64)


def _block_layout(runs: Sequence[Recording], within: str, width: float):
    """The visits every run makes with their bins (the fewest any run covers), and each run's sample bins."""
    clocks = [_BlockClock(within, r.fs).advance({c: r[c] for c in r.channels}) for r in runs]
    # a whole run: each visit is one stretch of samples and its own key (the visit count tells repeats apart)
    per_run = [{key: int(np.floor(pos[which == j].max() / width)) for j, key in enumerate(keys)}
               for keys, which, pos in clocks]
    common = [k for k in per_run[0] if all(k in c for c in per_run[1:])]
    segments, offsets, first = [], {}, 0
    for key in common:
        count = min(c[key] for c in per_run)            # the last bin of the shortest visit may be partial
        if count < 1:
            continue
        segments.append((*key, first, count))
        offsets[key] = (first, count)
        first += count
    indices = [_block_index(keys, which, pos, width, offsets) for keys, which, pos in clocks]
    return tuple(segments), indices, first


def _bin_means(values: np.ndarray, index: np.ndarray, bins: int) -> np.ndarray:
    keep = (index >= 0) & (index < bins)
    total = np.bincount(index[keep], weights=np.abs(values[keep]), minlength=bins)[:bins]
    count = np.bincount(index[keep], minlength=bins)[:bins]
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def teach(runs: Sequence[Recording], channels: Sequence[str] | None = None, *, align: str = "auto",
          bin_width: float | None = None, tolerance: float = 0.3, floor: float | None = None,
          limit_factor: float = 3.0) -> TeachLimits:
    """Learn teach-in bands from good runs of one NC program.

    Parameters
    ----------
    runs : sequence of Recording
        Good runs (estimated forces [N] and/or ``spindle_power`` [W], with table positions for path
        alignment), each from the program's start.
    channels : sequence of str, optional
        Channels to band (default: every ``force_*`` and ``spindle_power`` channel).
    align : {"auto", "time", "path", "block"}
        ``auto``: block when the runs carry the NC's ``block_number``, else path when they have table
        positions, else time.
    bin_width : float, optional
        Bin width [s] or [m] (default 0.05 s or 0.5 mm).
    tolerance : float
        Relative widening of the runs' range [-].
    floor : float, optional
        Absolute widening [unit of the channel] (default: 3 times the median spread between the runs
        per bin, at least 0.5 and at least 10 % of the largest bin mean: an estimate's error at another
        feed is of that order in air).
    limit_factor : float
        Collision/overload limit as a multiple of the largest force in the runs [-].

    Returns
    -------
    TeachLimits

    Raises
    ------
    SignalTooShortError
        Fewer than 2 runs, or runs shorter than 4 bins.
    MissingChannelError
        A run without a banded channel, or without positions for ``align="path"``.
    """
    runs = list(runs)
    if len(runs) < 2:
        raise SignalTooShortError(f"teach-in needs at least 2 good runs of the program, got {len(runs)}")
    if align not in ("auto",) + _ALIGN:
        raise ConfigError(f"--align must be auto, time, path or block, got {align!r}")
    has_path = all(_path_channels(r.channels) for r in runs)
    if align == "auto":
        align = "block" if all("block_number" in r.channels for r in runs) else "path" if has_path else "time"
    if align == "block" and not all("block_number" in r.channels for r in runs):
        raise MissingChannelError("--align block needs the NC's block_number channel in every run")
    within = "path" if has_path else "time"
    per_time = align == "time" or (align == "block" and within == "time")
    width = bin_width if bin_width is not None else (0.05 if per_time else 0.5e-3)
    width = check_number(width, "bin_width", positive=True)
    tolerance = check_number(tolerance, "tolerance", nonneg=True)
    if channels is None:
        channels = [c for c in runs[0].channels if c.startswith("force_") or c == "spindle_power"]
    channels = tuple(channels)
    if not channels:
        raise MissingChannelError("teach-in: the runs have no force_* or spindle_power channel to band")
    for k, r in enumerate(runs):
        missing = [c for c in channels if c not in r.channels]
        if missing:
            raise MissingChannelError(f"teach-in run {k + 1} ({r.meta.get('name', 'trace')}) lacks "
                                      f"{', '.join(missing)}")
    segments: tuple = ()
    if align == "block":
        segments, indices, bins = _block_layout(runs, within, width)
    else:
        indices = [_bin_index(r, align, width) for r in runs]
        bins = int(min(idx.max() for idx in indices))      # the last bin of the shortest run may be partial
    if bins < 4:
        raise SignalTooShortError(f"teach-in: the runs cover only {bins} bin(s) of {width:g} "
                                  f"{'s' if per_time else 'm'}; use a smaller --bin-width")
    mean, upper, lower = {}, {}, {}
    peak = 0.0
    for c in channels:
        per_run = np.vstack([_bin_means(r[c], idx, bins) for r, idx in zip(runs, indices)])
        per_run = np.where(np.isnan(per_run), np.nanmean(per_run, axis=0), per_run)
        spread = np.median(np.std(per_run, axis=0))
        fl = floor if floor is not None else max(3.0 * spread, 0.5, 0.1 * float(np.max(per_run.mean(axis=0))))
        mean[c] = per_run.mean(axis=0)
        upper[c] = per_run.max(axis=0) * (1 + tolerance) + fl
        lower[c] = np.maximum(per_run.min(axis=0) * (1 - tolerance) - fl, 0.0)
        if c.startswith("force_"):
            peak = max(peak, max(float(np.max(np.abs(r[c]))) for r in runs))
    limit = check_number(limit_factor, "limit_factor", positive=True) * max(peak, 1.0)
    feed = override = None
    if all("feed_speed" in r.channels for r in runs):
        per_run = np.vstack([_bin_means(r["feed_speed"], idx, bins) for r, idx in zip(runs, indices)])
        feed = np.nanmean(per_run, axis=0)
    if align == "block" and all("feed_override" in r.channels for r in runs):
        per_run = np.vstack([_bin_means(r["feed_override"], idx, bins) for r, idx in zip(runs, indices)])
        override = np.nan_to_num(np.nanmean(per_run, axis=0), nan=1.0)
    return TeachLimits(channels, align, float(width), mean, upper, lower, len(runs), float(limit), feed,
                       segments, within, override)


class TeachInDetector(Detector):
    """Alarm when a run leaves the bands taught from good runs (see the module docstring).

    Parameters
    ----------
    limits : TeachLimits
        The taught bands.
    persist_bins : int
        Bins in a row out of band for an event.
    missing_share : float
        A bin below the band at less than this share of the taught mean is a missing tool [-].
    """

    name = "teach-in"

    def __init__(self, limits: TeachLimits, *, persist_bins: int = 2, missing_share: float = 0.25) -> None:
        if not isinstance(limits, TeachLimits):
            raise ConfigError(f"'limits' must be TeachLimits, got {type(limits).__name__}")
        self.limits = limits
        self._offsets = {tuple(g[:3]): (g[3], g[4]) for g in limits.segments}
        self.persist_bins = check_int(persist_bins, "persist_bins")
        self.missing_share = check_number(missing_share, "missing_share", positive=True)
        first = limits.channels[0]
        self._axis = first.split("_", 1)[1] if first.startswith("force_") else "spindle"

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The banded channels."""
        return tuple(self.limits.channels)

    def latency_s(self, fs: float) -> float:
        """``persist_bins + 1`` bins: of time, or of path at the taught runs' median feed (1 mm/s if unknown) [s].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        feed = 1e-3
        if self.limits.feed is not None and np.any(self.limits.feed > 0):
            feed = float(np.median(self.limits.feed[self.limits.feed > 0]))
        per_bin = self.limits.bin_width if self.limits.unit == "s" else self.limits.bin_width / feed
        return (self.persist_bins + 1) * per_bin

    def new_state(self, fs: float) -> dict:
        """The running bin's sums, the path so far, the out-of-band count (constant size).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        k = len(self.limits.channels)
        state = {"fs": float(fs), "bin": 0, "sum": np.zeros(k), "count": 0, "feed": 0.0, "override": 0.0,
                 "meter": PathMeter(), "out": 0, "samples": 0, "latched": False}
        if self.limits.align == "block":
            state["clock"] = _BlockClock(self.limits.within, fs)
        return state

    def process(self, state: dict, arrays: Mapping[str, np.ndarray], start: int):
        """Events, the first channel's running mean magnitude in its bin, and the bin's upper band.

        Parameters
        ----------
        state : dict
            From :meth:`new_state`; updated in place.
        arrays : mapping of str to ndarray
            The chunk's channels [SI unit of each channel: N, rad/s, m/s, m], equally long.
        start : int
            Index of the chunk's first sample since the stream began.
        """
        lim = self.limits
        n = len(arrays[lim.channels[0]])
        if lim.align == "block":
            if "block_number" not in arrays:
                raise MissingChannelError("teach-in limits taught per block need the NC's block_number channel")
            keys, which, pos = state["clock"].advance(arrays)
            idx = _block_index(keys, which, pos, lim.bin_width, self._offsets)
        elif lim.align == "time":
            idx = np.floor((state["samples"] + np.arange(n)) / state["fs"] / lim.bin_width).astype(np.int64)
        else:
            s = state["meter"].advance(_positions(arrays))
            idx = np.floor(s / lim.bin_width).astype(np.int64)
        state["samples"] += n
        values = np.vstack([np.abs(np.asarray(arrays[c], dtype=float)) for c in lim.channels])
        feed = np.abs(np.asarray(arrays["feed_speed"], dtype=float)) if "feed_speed" in arrays else None
        override = np.asarray(arrays["feed_override"], dtype=float) \
            if lim.override is not None and "feed_override" in arrays else None
        stat = np.full(n, np.nan)
        thr = np.full(n, np.nan)
        events = []
        # bin boundaries inside the chunk: close the running bin at each
        change = np.flatnonzero(np.diff(np.concatenate([[state["bin"]], idx])) != 0)
        edges = np.concatenate([[0], change, [n]])
        first = lim.channels[0]
        for a, b in zip(edges[:-1], edges[1:]):
            if b > a and idx[a] == state["bin"]:
                # the statistic: the running mean of the bin so far (causal: the same in any chunking)
                run = state["sum"][0] + np.cumsum(values[0, a:b])
                if 0 <= state["bin"] < lim.bins:
                    stat[a:b] = run / (state["count"] + np.arange(1, b - a + 1))
                    thr[a:b] = lim.upper[first][state["bin"]]
                state["sum"] += values[:, a:b].sum(axis=1)
                state["count"] += int(b - a)
                if feed is not None:
                    state["feed"] += float(feed[a:b].sum())
                if override is not None:
                    state["override"] += float(override[a:b].sum())
            if b < n:                               # bin state["bin"] is complete at sample b
                ev = self._close_bin(state, start + int(b))
                if ev is not None:
                    events.append(ev)
                state["bin"] = int(idx[b])
                state["sum"][:] = 0.0
                state["count"] = 0
                state["feed"] = 0.0
                state["override"] = 0.0
        return events, stat, thr

    def _close_bin(self, state: dict, index: int):
        lim = self.limits
        b = state["bin"]
        if not (0 <= b < lim.bins) or state["count"] == 0:
            return None
        means = state["sum"] / state["count"]
        ratio = 1.0
        if lim.override is not None and state["override"] > 0.0 and lim.override[b] > 0.0:
            ratio = state["override"] / state["count"] / lim.override[b]   # the NC's ratio: no ramp to wait for
        elif lim.feed is not None and state["feed"] > 0.0 and lim.feed[b] > 0.0:
            ratio = state["feed"] / state["count"] / lim.feed[b]
        worst = None
        for k, c in enumerate(lim.channels):
            # a slower feed (an override) thins the chip and lowers the force, a faster one raises it
            v, mu = means[k], lim.mean[c][b]
            up = lim.upper[c][b] * max(1.0, ratio)
            lo = lim.lower[c][b] * min(1.0, ratio)
            if v > up:
                cand = ("limit", v / up, {"channel": c, "side": "high", "value": float(v), "band": float(up),
                                          "bin": int(b)})
            elif v < lo:
                kind = "missing_tool" if v < self.missing_share * mu else "limit"
                cand = (kind, lo / max(v, 1e-9), {"channel": c, "side": "low", "value": float(v), "band": float(lo),
                                                 "bin": int(b)})
            else:
                continue
            if worst is None or cand[1] > worst[1]:
                worst = cand
        if worst is None:
            state["out"] = 0
            state["latched"] = False
            return None
        state["out"] += 1
        if state["out"] < self.persist_bins or state["latched"]:
            return None
        state["latched"] = True
        kind, ratio, evidence = worst
        return (index, kind, min(1.0, 0.5 + 0.5 * (ratio - 1.0)), evidence)

    def check_ready(self, state: dict) -> None:
        """Nothing to learn: the bands are given.

        Parameters
        ----------
        state : dict
            The state after the whole trace.
        """
        if state["samples"] == 0:
            raise SignalTooShortError("teach-in detector: the trace is empty")

