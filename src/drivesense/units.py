"""Units of the channels drivesense reads and writes, and their conversion to SI.

Everything inside drivesense is SI (m, rad, A, s, N, m/s, m/s^2, rad/s, W, N*m,
V).  Units other than SI appear only at the edges (CSV columns, XML files,
controller traces); this module converts them with a plain table: each unit
belongs to one *quantity* and has a factor (and an offset, 0 for every unit
here) such that ``si_value = value * factor + offset``.

The canonical channel names of the data model (see DESIGN.md) each expect one
quantity; :func:`quantity_of_channel` gives it, so that a column
``table_position [A]`` is refused instead of silently read as metres.

Examples
--------
>>> to_si([1.0, 2.5], "mm", quantity="length")
(array([0.001 , 0.0025]), 'm')
>>> quantity_of_channel("x_motor_angle")
'angle'
"""

from __future__ import annotations

import math
import re
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from .errors import InvalidSignalError, UnitError
from .nc_context import CONTEXT_CHANNELS

__all__ = [
    "LENGTH",
    "ANGLE",
    "CURRENT",
    "TIME",
    "FORCE",
    "VELOCITY",
    "ACCELERATION",
    "ANGULAR_SPEED",
    "POWER",
    "TORQUE",
    "VOLTAGE",
    "DIMENSIONLESS",
    "QUANTITIES",
    "SI_UNITS",
    "UnitInfo",
    "unit_info",
    "is_known_unit",
    "quantity_of_unit",
    "known_units",
    "si_unit",
    "is_si_unit",
    "quantity_of_channel",
    "to_si",
    "from_si",
    "convert",
]

LENGTH = "length"
ANGLE = "angle"
CURRENT = "current"
TIME = "time"
FORCE = "force"
VELOCITY = "velocity"
ACCELERATION = "acceleration"
ANGULAR_SPEED = "angular_speed"
POWER = "power"
TORQUE = "torque"
VOLTAGE = "voltage"
DIMENSIONLESS = "dimensionless"

#: SI unit string of every quantity (the unit a Recording stores).
SI_UNITS: dict[str, str] = {
    LENGTH: "m",
    ANGLE: "rad",
    CURRENT: "A",
    TIME: "s",
    FORCE: "N",
    VELOCITY: "m/s",
    ACCELERATION: "m/s^2",
    ANGULAR_SPEED: "rad/s",
    POWER: "W",
    TORQUE: "N*m",
    VOLTAGE: "V",
    DIMENSIONLESS: "1",
}

#: The quantities known to drivesense, in a fixed order.
QUANTITIES: tuple[str, ...] = tuple(SI_UNITS)


class UnitInfo(NamedTuple):
    """One supported unit.

    Attributes
    ----------
    unit : str
        The unit as written (e.g. ``"mm"``).
    quantity : str
        The quantity it measures (e.g. ``"length"``).
    factor : float
        Multiply by this to get SI ... [SI unit per `unit`]
    offset : float
        ... then add this [SI unit] (0 for every unit in the table).
    """

    unit: str
    quantity: str
    factor: float
    offset: float = 0.0


_INCH = 0.0254  # m, exact by definition
_LBF = 4.4482216152605  # N, exact by definition (0.45359237 kg * 9.80665 m/s^2)
_HP = 745.69987158227022  # W, mechanical horsepower (550 ft*lbf/s)
_REV = 2.0 * math.pi  # rad

_TABLE: dict[str, list[tuple[str, float]]] = {
    LENGTH: [("m", 1.0), ("mm", 1e-3), ("um", 1e-6), ("µm", 1e-6), ("μm", 1e-6),
             ("nm", 1e-9), ("in", _INCH), ("inch", _INCH)],
    ANGLE: [("rad", 1.0), ("deg", math.pi / 180.0), ("°", math.pi / 180.0),
            ("degree", math.pi / 180.0), ("degrees", math.pi / 180.0), ("rev", _REV)],
    CURRENT: [("A", 1.0), ("mA", 1e-3)],
    TIME: [("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("µs", 1e-6), ("μs", 1e-6), ("min", 60.0)],
    FORCE: [("N", 1.0), ("kN", 1e3), ("lbf", _LBF)],
    VELOCITY: [("m/s", 1.0), ("mm/s", 1e-3), ("mm/min", 1e-3 / 60.0),
               ("m/min", 1.0 / 60.0), ("in/min", _INCH / 60.0)],
    ACCELERATION: [("m/s^2", 1.0), ("m/s2", 1.0), ("m/s²", 1.0), ("mm/s^2", 1e-3), ("mm/s2", 1e-3),
                   ("mm/s²", 1e-3), ("g", 9.80665)],
    ANGULAR_SPEED: [("rad/s", 1.0), ("rpm", _REV / 60.0), ("RPM", _REV / 60.0),
                    ("1/min", _REV / 60.0), ("min^-1", _REV / 60.0),
                    ("rev/min", _REV / 60.0), ("rev/s", _REV), ("deg/s", math.pi / 180.0),
                    ("°/s", math.pi / 180.0)],
    POWER: [("W", 1.0), ("kW", 1e3), ("hp", _HP), ("HP", _HP)],
    TORQUE: [("N*m", 1.0), ("N m", 1.0), ("Nm", 1.0), ("N.m", 1.0), ("N·m", 1.0)],
    VOLTAGE: [("V", 1.0), ("mV", 1e-3)],
    DIMENSIONLESS: [("1", 1.0), ("", 1.0), ("-", 1.0), ("%", 1e-2)],
}

_UNITS: dict[str, UnitInfo] = {}
for _q, _rows in _TABLE.items():
    for _u, _f in _rows:
        assert _u not in _UNITS, f"unit {_u!r} listed twice"
        _UNITS[_u] = UnitInfo(_u, _q, float(_f), 0.0)
del _q, _rows, _u, _f

_AXIS_CHANNELS: dict[str, str] = {
    "current_ref": CURRENT,
    "current": CURRENT,
    "motor_angle": ANGLE,
    "table_position": LENGTH,
    "position": LENGTH,
    "velocity": VELOCITY,
    "acceleration": ACCELERATION,
}
_FIXED_CHANNELS: dict[str, str] = {
    "time": TIME,
    "spindle_speed": ANGULAR_SPEED,
    "spindle_current": CURRENT,
    "spindle_power": POWER,
    **{name: DIMENSIONLESS for name in CONTEXT_CHANNELS},       # the NC's context (drivesense.nc_context)
}
_AXIS_RE = re.compile(r"^([xyz])_(.+)$")
_FORCE_RE = re.compile(r"^force_[xyz]$")


def _label(quantity: str) -> str:
    """``"angular_speed"`` -> ``"angular speed"`` (for messages)."""
    return quantity.replace("_", " ")


def _a(quantity: str) -> str:
    """Indefinite article + quantity label, e.g. ``"an angle"``."""
    label = _label(quantity)
    return ("an " if label[0] in "aeiou" else "a ") + label


def _who(name: str | None) -> str:
    return f"channel {name!r}" if name is not None else "value"


def _known_list(quantity: str | None) -> str:
    units = known_units(quantity)
    shown = ", ".join(repr(u) if u in ("", " ") else u for u in units)
    if quantity is None:
        return f"known units: {shown}"
    return f"known {_label(quantity)} units: {shown}"


def _check_quantity(quantity: str | None) -> None:
    if quantity is not None and quantity not in SI_UNITS:
        raise UnitError(
            f"unknown quantity {quantity!r} (known quantities: {', '.join(QUANTITIES)})"
        )


def unit_info(unit: str, *, quantity: str | None = None, name: str | None = None) -> UnitInfo:
    """Look a unit up, checking it measures the expected quantity.

    Parameters
    ----------
    unit : str
        Unit as written, e.g. ``"mm"`` (surrounding whitespace is ignored).
    quantity : str, optional
        Expected quantity (one of :data:`QUANTITIES`); ``None`` accepts any.
    name : str, optional
        Channel name, used in error messages.

    Returns
    -------
    UnitInfo
        Quantity, factor and offset of the unit.

    Raises
    ------
    UnitError
        If the unit is unknown, or measures another quantity than `quantity`.
    """
    _check_quantity(quantity)
    if not isinstance(unit, str):
        raise UnitError(f"{_who(name)}: unit must be a string, got {unit!r}")
    info = _UNITS.get(unit.strip())
    if info is None:
        prefix = f"channel {name!r}: " if name is not None else ""
        raise UnitError(f"{prefix}unknown unit {unit!r} ({_known_list(quantity)})")
    if quantity is not None and info.quantity != quantity:
        raise UnitError(
            f"{_who(name)} expects {_a(quantity)} unit, got {unit!r} "
            f"({_a(info.quantity)} unit; {_known_list(quantity)})"
        )
    return info


def is_known_unit(unit: str) -> bool:
    """Whether `unit` is in the unit table.

    Parameters
    ----------
    unit : str
        Unit as written.

    Returns
    -------
    bool
    """
    return isinstance(unit, str) and unit.strip() in _UNITS


def quantity_of_unit(unit: str) -> str:
    """Quantity measured by `unit` (e.g. ``"mm"`` -> ``"length"``).

    Parameters
    ----------
    unit : str
        Unit as written.

    Returns
    -------
    str
        One of :data:`QUANTITIES`.

    Raises
    ------
    UnitError
        If the unit is unknown.
    """
    return unit_info(unit).quantity


def known_units(quantity: str | None = None) -> list[str]:
    """Units in the table, for one quantity or for all.

    Parameters
    ----------
    quantity : str, optional
        One of :data:`QUANTITIES`; ``None`` lists every unit.

    Returns
    -------
    list of str
        The SI unit comes first for each quantity.
    """
    _check_quantity(quantity)
    if quantity is None:
        return list(_UNITS)
    return [u for u, _ in _TABLE[quantity]]


def si_unit(quantity: str) -> str:
    """SI unit string of a quantity (``"length"`` -> ``"m"``).

    Parameters
    ----------
    quantity : str
        One of :data:`QUANTITIES`.

    Returns
    -------
    str
    """
    _check_quantity(quantity)
    return SI_UNITS[quantity]


def is_si_unit(unit: str) -> bool:
    """Whether `unit` is exactly the SI unit string of its quantity.

    Aliases with factor 1 (``"Nm"``, ``"m/s2"``, ``"-"``) are not: a Recording
    stores the canonical string of :data:`SI_UNITS`.

    Parameters
    ----------
    unit : str
        Unit as written.

    Returns
    -------
    bool
    """
    return isinstance(unit, str) and unit in SI_UNITS.values()


def quantity_of_channel(name: str) -> str | None:
    """Quantity a canonical channel name expects.

    Parameters
    ----------
    name : str
        Channel name, e.g. ``"x_table_position"``, ``"force_y"``, ``"spindle_speed"``.

    Returns
    -------
    str or None
        One of :data:`QUANTITIES`, or ``None`` for a name outside the data model
        (such a channel may use any known unit).

    Examples
    --------
    >>> quantity_of_channel("y_current_ref"), quantity_of_channel("force_z")
    ('current', 'force')
    >>> quantity_of_channel("temperature") is None
    True
    """
    if not isinstance(name, str):
        return None
    if name in _FIXED_CHANNELS:
        return _FIXED_CHANNELS[name]
    if _FORCE_RE.match(name):
        return FORCE
    m = _AXIS_RE.match(name)
    if m:
        return _AXIS_CHANNELS.get(m.group(2))
    return None


def _as_float(values: ArrayLike, name: str | None) -> np.ndarray:
    try:
        arr = np.array(values, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"{_who(name)}: values are not numeric ({exc})") from None
    return arr


def to_si(
    values: ArrayLike,
    unit: str,
    *,
    quantity: str | None = None,
    name: str | None = None,
) -> tuple[np.ndarray, str]:
    """Convert values in `unit` to SI.

    Parameters
    ----------
    values : array_like
        Values [`unit`] (any shape).
    unit : str
        Unit of `values`, e.g. ``"mm"``, ``"deg"``, ``"rpm"``.
    quantity : str, optional
        Expected quantity (one of :data:`QUANTITIES`), e.g. from
        :func:`quantity_of_channel`; ``None`` accepts any known unit.
    name : str, optional
        Channel name, used in error messages.

    Returns
    -------
    values_si : numpy.ndarray
        New float64 array in SI (an exact copy when the factor is 1).
    si_unit : str
        The SI unit string (e.g. ``"m"``).

    Raises
    ------
    UnitError
        Unknown unit, or a unit of another quantity than `quantity`.
    InvalidSignalError
        Values that are not numeric.

    Examples
    --------
    >>> to_si(90.0, "deg")
    (array(1.57079633), 'rad')
    """
    info = unit_info(unit, quantity=quantity, name=name)
    arr = _as_float(values, name)
    if info.factor != 1.0:
        arr *= info.factor
    if info.offset != 0.0:
        arr += info.offset
    return arr, SI_UNITS[info.quantity]


def from_si(
    values: ArrayLike,
    unit: str,
    *,
    quantity: str | None = None,
    name: str | None = None,
) -> np.ndarray:
    """Convert SI values to `unit` (the inverse of :func:`to_si`).

    Parameters
    ----------
    values : array_like
        Values [SI unit of the quantity of `unit`].
    unit : str
        Target unit, e.g. ``"mm"``.
    quantity : str, optional
        Expected quantity; ``None`` accepts any known unit.
    name : str, optional
        Channel name, used in error messages.

    Returns
    -------
    numpy.ndarray
        New float64 array in `unit` (an exact copy when the factor is 1).

    Raises
    ------
    UnitError
        Unknown unit, or a unit of another quantity than `quantity`.
    InvalidSignalError
        Values that are not numeric.
    """
    info = unit_info(unit, quantity=quantity, name=name)
    arr = _as_float(values, name)
    if info.offset != 0.0:
        arr -= info.offset
    if info.factor != 1.0:
        arr /= info.factor
    return arr


def convert(
    values: ArrayLike, from_unit: str, to_unit: str, *, name: str | None = None
) -> np.ndarray:
    """Convert values between two units of the same quantity.

    Parameters
    ----------
    values : array_like
        Values [`from_unit`].
    from_unit, to_unit : str
        Units of one quantity, e.g. ``"mm/min"`` and ``"m/s"``.
    name : str, optional
        Channel name, used in error messages.

    Returns
    -------
    numpy.ndarray
        New float64 array in `to_unit`.

    Raises
    ------
    UnitError
        Unknown unit, or units of different quantities.
    """
    si, _ = to_si(values, from_unit, name=name)
    return from_si(si, to_unit, quantity=quantity_of_unit(from_unit), name=name)
