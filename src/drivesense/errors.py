"""Exception hierarchy of drivesense.

Every class subclasses :class:`DriveSenseError` *and* the built-in exception a
caller would naturally catch (``ValueError``, ``KeyError``...), so that both
``except ds.errors.DriveSenseError`` and ``except ValueError`` work.  Messages
name the channel, field or file concerned and say what is wrong with it.
"""

from __future__ import annotations

__all__ = [
    "DriveSenseError",
    "InvalidSignalError",
    "TimebaseError",
    "SignalTooShortError",
    "SampleRateError",
    "ImplausibleSampleError",
    "MissingChannelError",
    "UnitError",
    "ConfigError",
    "CoverageError",
    "NotFittedError",
    "IdentificationError",
]


class DriveSenseError(Exception):
    """Base class of every error raised on purpose by drivesense."""


class InvalidSignalError(DriveSenseError, ValueError):
    """A signal holds values that cannot be used (NaN, inf, wrong shape...)."""


class TimebaseError(InvalidSignalError):
    """A time axis is not monotonic or not uniform within the tolerance."""


class SignalTooShortError(InvalidSignalError):
    """A trace is shorter than the filters or the method need."""


class SampleRateError(InvalidSignalError):
    """A trace's sample rate cannot resolve what a method models (a mode above the Nyquist frequency)."""


class ImplausibleSampleError(InvalidSignalError):
    """A trace holds physically impossible samples (a spindle at -3.3e6 rpm, a position jump...).

    The message names each sample's channel, line (or sample index), value and
    why; the :class:`~drivesense.io.plausibility.PlausibilityReport` behind it
    is the exception's ``report`` attribute (None when raised without one).
    """

    report = None


class MissingChannelError(DriveSenseError, KeyError):
    """A required channel (or column, or key) is absent."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


class UnitError(DriveSenseError, ValueError):
    """A unit is unknown, or does not fit the quantity of its channel."""


class ConfigError(DriveSenseError, ValueError):
    """A configuration (axis file, parameter set) has missing or bad fields."""


class CoverageError(DriveSenseError, ValueError):
    """Calibration data (e.g. idle runs) do not cover what they must."""


class NotFittedError(DriveSenseError, RuntimeError):
    """A method needs ``fit`` (or a tare) before it can be used this way."""


class IdentificationError(DriveSenseError, ValueError):
    """Measurements cannot determine a parameter (named in the message)."""
