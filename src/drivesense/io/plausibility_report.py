"""The data model of the plausibility check: its limits, the flagged samples and the report.

:class:`PlausibilityLimits` holds every number the checks of
:mod:`drivesense.io.plausibility` use; a check returns a
:class:`PlausibilityReport` of :class:`BadSample` entries, each naming its
channel, its place (file line or sample index), its value (in the file's unit
where known, else SI) and why it was flagged; :meth:`PlausibilityReport.located`
sets the file lines, :meth:`PlausibilityReport.summary` and
:meth:`PlausibilityReport.unrepairable` word the messages.
:class:`BadSampleWarning` is the warning a repair raises.  Everything here is
re-exported by :mod:`drivesense.io.plausibility` and :mod:`drivesense.io`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .. import units as _units
from ..errors import ConfigError

__all__ = ["PlausibilityLimits", "BadSample", "PlausibilityReport", "BadSampleWarning", "RPM", "SHOWN",
           "shows_rpm"]

#: One rpm [rad/s].
RPM = 2.0 * math.pi / 60.0
_RPM_UNITS = ("rpm", "RPM", "1/min", "min^-1", "rev/min")
#: How many flagged samples a message lists before "... and N more".
SHOWN = 5


class BadSampleWarning(UserWarning):
    """Implausible samples were repaired by interpolation (``--bad-samples repair``), or a channel is
    implausible as a whole (:attr:`PlausibilityReport.notes`)."""


@dataclass(frozen=True)
class PlausibilityLimits:
    """The numbers behind the plausibility checks (all SI).

    Attributes
    ----------
    spindle_speed_max : float
        Physical limit of ``|spindle_speed|`` [rad/s] (default 100 000 rpm).
    velocity_max : float
        Physical limit of ``|{ax}_velocity|`` [m/s] (default 10 m/s = 600 m/min).
    acceleration_max : float
        Physical limit of ``|{ax}_acceleration|`` [m/s^2] (default 1000 m/s^2, about 100 g).
    position_speed_max : float
        Fastest motion a position may show between two samples when the trace
        has no velocity channel of its axis [m/s] (default 2 m/s = 120 m/min).
    position_factor : float
        A position step may be this many times the logged speed (the largest
        ``|{ax}_velocity|`` within `position_window` samples) times the
        sample step [-] (default 3: filters and delays between the channels,
        a doubled time step).
    position_window : int
        Samples on each side of a step whose logged velocity counts [-].
    position_tolerance : float
        Added to every allowed position step [m] (default 10 um: quantisation
        and noise of the scale).
    spike_spread_factor : float
        A spike is off its neighbours by more than this many times the
        channel's spread, ``p99 - p1`` of its values [-].
    spike_mad_factor : float
        ... and by more than this many robust standard deviations of its
        sample-to-sample differences, ``1.4826 * MAD`` [-].
    spike_floor : dict of str to float
        ... and by more than this, per quantity [SI unit of the quantity]:
        velocity 0.01 m/s, acceleration 2 m/s^2, current 1 A, angular speed
        100 rpm.
    spike_run : int
        Longest run of consecutive samples that counts as a spike [-]
        (default 1: an isolated sample; a short acceleration phase at 50 Hz
        lasts 2-3 samples and is no glitch).
    position_run : int
        Longest run of consecutive samples that counts as one position glitch
        (a jump and back) [-].
    max_repair : int
        Longest run of consecutive flagged samples that ``repair`` interpolates
        over [-]; longer runs are refused.
    """

    spindle_speed_max: float = 100_000 * RPM
    velocity_max: float = 10.0
    acceleration_max: float = 1000.0
    position_speed_max: float = 2.0
    position_factor: float = 3.0
    position_window: int = 3
    position_tolerance: float = 10e-6
    spike_spread_factor: float = 5.0
    spike_mad_factor: float = 30.0
    spike_floor: dict = field(default_factory=lambda: {
        _units.VELOCITY: 0.01, _units.ACCELERATION: 2.0, _units.CURRENT: 1.0, _units.ANGULAR_SPEED: 100 * RPM})
    spike_run: int = 1
    position_run: int = 3
    max_repair: int = 5

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "spike_floor":
                if not all(isinstance(v, (int, float)) and v >= 0 for v in value.values()):
                    raise ConfigError(f"PlausibilityLimits.spike_floor: values must be numbers >= 0, got {value!r}")
                continue
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                    and value >= 0):
                raise ConfigError(f"PlausibilityLimits.{f.name} must be a finite number >= 0, got {value!r}")
        for name, least in (("spike_run", 1), ("position_run", 1), ("position_window", 0), ("max_repair", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or value < least:
                raise ConfigError(f"PlausibilityLimits.{name} must be a whole number of samples >= {least}, "
                                  f"got {value!r}")


@dataclass(frozen=True)
class BadSample:
    """One flagged sample.

    Attributes
    ----------
    channel : str
        Channel name (canonical, as in the Recording).
    index : int
        Sample index in the trace (0-based) [-].
    line : int or None
        Line of the source file (1-based, header and comments counted), or
        None when the trace does not come from a text file.
    value : float
        The sample's value [`unit`] (nan or inf for non-finite samples).
    unit : str
        Unit of `value`: the file's unit of the column where known, else SI.
    reason : str
        Why the sample is implausible (with numbers in `unit`).
    repairable : bool
        Whether interpolation of its neighbours can stand in for it (False for
        a position step that stays).
    """

    channel: str
    index: int
    line: int | None
    value: float
    unit: str
    reason: str
    repairable: bool = True

    @property
    def where(self) -> str:
        """``"line 17"`` (CSV) or ``"sample 16"``."""
        return f"line {self.line}" if self.line is not None else f"sample {self.index}"

    def describe(self) -> str:
        """One line: channel, place, value and reason."""
        return f"{self.channel}, {self.where}: {_fmt_value(self.value, self.unit, self.channel)} {self.reason}"

    def to_dict(self) -> dict:
        """JSON-ready dict (a non-finite value as its text, ``"nan"``/``"inf"``/``"-inf"``)."""
        value = self.value if math.isfinite(self.value) else repr(float(self.value))
        return {"channel": self.channel, "line": self.line, "sample": self.index, "value": value,
                "unit": self.unit, "reason": self.reason, "repairable": self.repairable}


@dataclass(frozen=True)
class PlausibilityReport:
    """The samples a plausibility check flagged in one trace.

    Attributes
    ----------
    samples : tuple of BadSample
        Flagged samples, by channel, then by index.
    source : str
        What was checked (file name or recording name), for messages.
    checked : tuple of str
        Channels checked beyond non-finite values (limits, spikes, jumps).
    n_samples : int
        Samples in the trace [-].
    limits : PlausibilityLimits
        The numbers used.
    notes : tuple of str
        Findings about whole channels rather than samples: a position that
        outruns its velocity channel (or the hard speed) in many steps points
        to a wrong unit or rate, not to glitches; these samples are not
        flagged, the note says so (and :func:`~drivesense.io.plausibility.enforce_policy` warns it).
    """

    samples: tuple[BadSample, ...]
    source: str
    checked: tuple[str, ...]
    n_samples: int
    limits: PlausibilityLimits = field(default_factory=PlausibilityLimits)
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """Whether nothing was flagged."""
        return not self.samples

    def __len__(self) -> int:
        return len(self.samples)

    def __iter__(self) -> Iterator[BadSample]:
        return iter(self.samples)

    def by_channel(self) -> dict[str, list[BadSample]]:
        """Flagged samples grouped by channel (in order of appearance)."""
        out: dict[str, list[BadSample]] = {}
        for s in self.samples:
            out.setdefault(s.channel, []).append(s)
        return out

    def unrepairable(self) -> list[str]:
        """Why interpolation cannot repair this trace: one text per problem ([] when it can)."""
        problems = [s.describe() for s in self.samples if not s.repairable]
        for channel, flagged in self.by_channel().items():
            idx = np.array([s.index for s in flagged])
            for run in _runs(idx):
                if run.size > self.limits.max_repair:
                    first = flagged[int(np.searchsorted(idx, run[0]))]
                    last = flagged[int(np.searchsorted(idx, run[-1]))]
                    problems.append(f"{channel}: {run.size} consecutive flagged samples ({first.where} to "
                                    f"{last.where.split()[-1]}), more than {self.limits.max_repair} to interpolate "
                                    "over")
        return problems

    def located(self, lines: ArrayLike | Callable[[], ArrayLike]) -> PlausibilityReport:
        """The report with each sample's file line set from `lines` (index -> line).

        Parameters
        ----------
        lines : array_like of int, or callable returning one
            File line of each sample (1-based); a callable is only called when
            something was flagged (finding line numbers may mean reading the
            file again).

        Returns
        -------
        PlausibilityReport
        """
        if self.ok:
            return self
        table = np.asarray(lines() if callable(lines) else lines)
        return dataclasses.replace(self, samples=tuple(dataclasses.replace(s, line=int(table[s.index]))
                                                       for s in self.samples))

    def summary(self, shown: int = SHOWN) -> str:
        """``"trace.csv: 2 implausible samples: ...; ..."``, listing the first `shown` [-] samples.

        Parameters
        ----------
        shown : int, optional
            How many samples to describe [-]; the rest are counted.
        """
        if self.ok:
            return f"{self.source}: no implausible samples ({len(self.checked)} channels checked)"
        n = len(self.samples)
        parts = [s.describe() for s in self.samples[:shown]]
        more = f"; and {n - shown} more" if n > shown else ""
        return f"{self.source}: {n} implausible sample{'s' if n != 1 else ''}: " + "; ".join(parts) + more

    def to_dict(self) -> dict:
        """JSON-ready dict: source, counts, the checked channels, the flagged samples and the limits."""
        return {"source": self.source, "n_samples": self.n_samples, "n_flagged": len(self.samples),
                "checked": list(self.checked), "samples": [s.to_dict() for s in self.samples],
                "notes": list(self.notes), "limits": dataclasses.asdict(self.limits)}


# ------------------------------------------------------------------ formatting
def shows_rpm(channel: str, unit: str) -> bool:
    """Whether a value of `channel` in `unit` is worth restating in rpm: an angular speed in another unit.

    Parameters
    ----------
    channel : str
        Canonical channel name (its quantity decides).
    unit : str
        Unit the value is stated in.

    Returns
    -------
    bool
        True for an angular speed given in a unit other than rpm (e.g. ``deg/s``).
    """
    return _units.quantity_of_channel(channel) == _units.ANGULAR_SPEED and unit.strip() not in _RPM_UNITS


def _fmt_value(value: float, unit: str, channel: str) -> str:
    """``-1.98e+07 deg/s (-3.3e+06 rpm)``; rpm added for angular speeds in other units."""
    if not math.isfinite(value):
        return repr(float(value))
    text = f"{value:.6g} {unit}".rstrip()
    if shows_rpm(channel, unit):
        text += f" ({value * _units.unit_info(unit).factor / RPM:.4g} rpm)"
    return text


def _runs(idx: np.ndarray) -> list[np.ndarray]:
    """Sorted indices split into runs of consecutive values."""
    if idx.size == 0:
        return []
    return np.split(idx, np.flatnonzero(np.diff(idx) != 1) + 1)
