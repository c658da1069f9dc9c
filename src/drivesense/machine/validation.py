"""Input checks shared by the machine models: parameter tables and signal arrays.

The axis models (:class:`~drivesense.machine.ballscrew.BallScrewAxis`,
:class:`~drivesense.machine.linear_motor.LinearMotorAxis`) and the signal chain
(:class:`~drivesense.machine.signal_chain.SignalParams`) read their
``from_dict`` through :func:`dataclass_from_dict` (they differ only in which
keys may be absent); the linear-motor force terms and the presliding state
take their signals through :func:`signal_array`.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import fields

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError

__all__ = ["dataclass_from_dict", "signal_array"]


def dataclass_from_dict(cls, values, source: str, *, optional: Collection[str] | None = ()):
    """Build the dataclass ``cls`` from a mapping of its field names, naming ``source`` in every error.

    Parameters
    ----------
    cls : type
        A dataclass whose constructor validates the values (raising
        :class:`~drivesense.errors.ConfigError`).
    values : mapping
        Field name -> value [SI unit of the field].
    source : str
        Where the values come from (a file name, a table), to start error messages.
    optional : collection of str or None
        Fields that may be absent (they take their defaults); None: every
        field may be absent.  Default: every field is required.

    Returns
    -------
    object
        The ``cls`` instance.

    Raises
    ------
    ConfigError
        ``values`` is not a mapping; missing and unknown keys (all named in
        one message, with the expected ones); a value the constructor refuses.
    """
    if not isinstance(values, Mapping):
        raise ConfigError(f"{source}: expected a table of parameters, got {type(values).__name__}")
    names = [f.name for f in fields(cls)]
    missing = [] if optional is None else [n for n in names if n not in optional and n not in values]
    unknown = [str(k) for k in values if k not in names]
    problems = []
    if missing:
        problems.append(f"missing key(s) {', '.join(missing)}")
    if unknown:
        problems.append(f"unknown key(s) {', '.join(unknown)}")
    if problems:
        raise ConfigError(f"{source}: {'; '.join(problems)} (expected {', '.join(names)})")
    try:
        return cls(**values)
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"{source}: {exc}") from None


def signal_array(value, name: str) -> np.ndarray:
    """``value`` as a float64 scalar or 1-D array, or :class:`~drivesense.errors.InvalidSignalError` naming ``name``.

    Parameters
    ----------
    value : float or array_like
        The samples [any unit; returned unchanged].
    name : str
        Signal name for the message.

    Returns
    -------
    ndarray
        0-D or 1-D, float64.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"'{name}' must be numeric: {exc}") from None
    if arr.ndim > 1:
        raise InvalidSignalError(f"'{name}' must be a scalar or 1-D, got shape {arr.shape}")
    return arr
