"""The machine's kinematics as bounds of the identification: which axis is vertical, which carries which.

A controller trace does not say how the machine is built; the user does
(``identify nc --vertical AXIS --carries Y=X``).  From it:

* only the vertical axis carries a weight: another axis's ``offset`` is a
  current-sensor offset, bounded to :data:`OFFSET_FRACTION` of its largest
  current (a horizontal tool axis came out with a 2,270 N "weight" on real
  traces);
* an axis that carries another is not lighter than it: its moved mass is
  bounded below by the carried axis's (identified first).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import ConfigError

__all__ = ["OFFSET_FRACTION", "offset_bound", "carried_first", "mass_floor", "merge_bounds", "check_kinematics"]


def check_kinematics(axes: Sequence[str], vertical: str | None, carries: Mapping | None) -> None:
    """ConfigError (one line, naming the option) for a vertical axis or kinematics the traces cannot have.

    Parameters
    ----------
    axes : sequence of str
        The traces' axes.
    vertical : str, optional
        ``--vertical``.
    carries : mapping of str to sequence of str, optional
        ``--carries``.
    """
    if vertical is not None and vertical not in axes:
        raise ConfigError(f"--vertical {vertical!r}: the traces have no such axis (they have {', '.join(axes)})")
    for carrier, carried in (carries or {}).items():
        bad = [b for b in (carrier, *carried) if b not in axes]
        if bad or carrier in carried:
            raise ConfigError(f"--carries {carrier}={'+'.join(carried)}: "
                              + (f"no axis {', '.join(bad)} in the traces (they have {', '.join(axes)})" if bad
                                 else "an axis cannot carry itself"))
    carried_first(axes, carries)


#: A horizontal axis's offset is a current-sensor offset: at most this fraction of its largest current.
OFFSET_FRACTION = 0.02


def offset_bound(axis: str, current: np.ndarray, vertical: str | None) -> dict:
    """Bounds of a horizontal axis's offset (no weight on it) when the vertical axis is known; none otherwise.

    Parameters
    ----------
    axis : str
        Axis letter.
    current : ndarray
        The axis's logged current over the identification's traces [A].
    vertical : str, optional
        The vertical axis.
    """
    if vertical is None or axis == vertical:
        return {}
    limit = OFFSET_FRACTION * float(np.max(np.abs(current), initial=0.0))
    return {"lower": {"offset": -limit}, "upper": {"offset": limit},
            "why": {"offset": f"axis {axis} is horizontal (vertical: {vertical}): no weight, only a current-sensor "
                              f"offset within {OFFSET_FRACTION:.0%} of its largest current"}}


def carried_first(axes: Sequence[str], carries: Mapping | None) -> list[str]:
    """Axes ordered so that an axis comes after every axis it carries.

    Parameters
    ----------
    axes : sequence of str
        Axis letters.
    carries : mapping of str to sequence of str, optional
        Which axis carries which.
    """
    order: list[str] = []

    def visit(a: str, path: tuple) -> None:
        if a in order:
            return
        if a in path:
            raise ConfigError(f"--carries: the kinematics form a loop ({' -> '.join((*path, a))})")
        for b in (carries or {}).get(a, ()):
            if b in axes:
                visit(b, (*path, a))
        order.append(a)

    for a in axes:
        visit(a, ())
    return order


def mass_floor(axis: str, models: Mapping, carries: Mapping | None, current: Mapping) -> dict | None:
    """A lower bound on the axis's mass term when it came out lighter than an axis it carries, else None.

    The bound is on ``s theta = m / |K_m|``; a refit moves ``K_m`` a little, so the floor is raised by the
    shortfall each time until the mass holds.

    Parameters
    ----------
    axis : str
        Axis letter.
    models : mapping of str to ControllerAxis
        The axes identified so far.
    carries : mapping of str to sequence of str, optional
        Which axis carries which.
    current : mapping
        The bounds of the axis's last fit (``lower``/``upper``/``why``).
    """
    carried = [b for b in (carries or {}).get(axis, ()) if b in models]
    if not carried or axis not in models:
        return None
    heaviest = max(carried, key=lambda b: models[b].value(f"inertia_{b}"))
    floor = models[heaviest].value(f"inertia_{heaviest}")
    mass = models[axis].value(f"inertia_{axis}")
    if mass >= floor * (1 - 1e-6):
        return None
    name = f"inertia_{axis}"
    before = current.get("lower", {}).get(name, 0.0)
    theta_floor = max(floor / abs(models[axis].K_m), before * floor / max(mass, 1e-300) * (1 + 1e-6))
    return {"lower": {name: theta_floor},
            "why": {name: f"axis {axis} carries {heaviest}: its moved mass is at least {heaviest}'s {floor:.4g} kg"}}


def merge_bounds(a: Mapping, b: Mapping) -> dict:
    """Two sets of bounds (``lower``, ``upper``, ``why``) in one, ``b`` over ``a``.

    Parameters
    ----------
    a, b : mapping
        Bounds.
    """
    return {k: {**a.get(k, {}), **b.get(k, {})} for k in ("lower", "upper", "why")}


