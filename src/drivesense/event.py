"""A detected process or tool-condition event: what the detectors (:mod:`drivesense.events`) and the live wear
monitor (:mod:`drivesense.condition.wear_live`) raise, the service logs and the dashboard shows.

Below both, so that either raises the same record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drivesense.errors import ConfigError

__all__ = ["EVENT_KINDS", "Event", "finite_or_none"]

#: Kinds an event may have.
EVENT_KINDS = ("breakage", "chipping", "chatter", "collision", "overload", "missing_tool", "limit", "wear")


@dataclass(frozen=True)
class Event:
    """One detected process or tool-condition event.

    Attributes
    ----------
    kind : str
        One of :data:`EVENT_KINDS`.
    time_s : float
        Time the detector raised it [s] (on the force stream's time base).
    axis : str
        Force axis it was seen on (``"x"``), or ``"spindle"``.
    confidence : float
        How far the statistic went past its threshold, 0..1 (1: far) [-].
    latency_s : float
        Detection latency the detector declares [s] (the estimator's adds:
        :func:`drivesense.events.attach_latency`).
    detector : str
        Name of the detector that raised it.
    evidence : dict
        What crossed (statistic, threshold, ratio, frequency...), JSON-safe numbers and strings.
    """

    kind: str
    time_s: float
    axis: str
    confidence: float
    latency_s: float
    detector: str
    evidence: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise ConfigError(f"event kind must be one of {', '.join(EVENT_KINDS)}, got {self.kind!r}")
        object.__setattr__(self, "confidence", float(min(max(self.confidence, 0.0), 1.0)))

    def to_json(self) -> dict:
        """A strict-JSON dict (finite numbers only)."""
        evidence = {k: (finite_or_none(v) if isinstance(v, float) else v) for k, v in self.evidence.items()}
        return {"kind": self.kind, "time_s": finite_or_none(self.time_s), "axis": self.axis,
                "confidence": finite_or_none(self.confidence), "latency_s": finite_or_none(self.latency_s),
                "detector": self.detector, "evidence": evidence}


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, or None where it is NaN or infinite (strict JSON has neither).

    Parameters
    ----------
    value : float
        Any number [any unit].
    """
    value = float(value)
    return value if math.isfinite(value) else None
