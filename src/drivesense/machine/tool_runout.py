"""Measured tool runout in the power calibration of K_tc and K_te (beyond the second paper's Eq. 2).

Eq. 2, ``P = K_tc Q + K_te A_c``, assumes every flute cuts its share. With radial runout (the tool
axis offset by ``e`` from the spindle axis) the flutes sit on different radii, ``r_i = r + e cos(phase
- 2 pi i / N)``; where the chip is thin -- low feeds, small immersions -- a flute can lose contact
and its edge stops rubbing. The material removed is unchanged (the next flute takes it) but the
edge contact, and so the ``K_te`` term, shrinks: a plain Eq. 2 fit reads this as a lower ``K_te``
(about -5 % at 5 um on a 4-flute tool at 0.04 mm/tooth).

When the runout is measured (a dial indicator on each flute, a tool presetter), the mechanistic
force model of :mod:`drivesense.machine.milling` gives, per cut, the mean power per unit ``K_tc``
(``B_c``) and per unit ``K_te`` (``B_e``). ``P = K_tc B_c + K_te B_e`` is then the same straight
line as Eq. 5 with ``h = B_c / B_e`` and ``F_t / a = P / B_e``; without runout ``B_c = Q`` and
``B_e = A_c`` and it is Eq. 5 exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivesense.errors import ConfigError

__all__ = ["ToolRunout", "power_bases"]


@dataclass(frozen=True)
class ToolRunout:
    """Measured radial runout of an end mill.

    Parameters
    ----------
    offset : float
        Offset e of the tool axis from the spindle axis [m] (half the indicator's total reading
        over the flutes of a pure offset), >= 0.
    phase : float
        Direction of the offset from flute 1 [rad].
    helix_deg : float
        Helix angle of the tool [deg] (catalogue value).
    """

    offset: float
    phase: float = 0.0
    helix_deg: float = 30.0

    def __post_init__(self) -> None:
        for name, low, high in (("offset", 0.0, 1e-3), ("phase", -1e3, 1e3), ("helix_deg", 0.0, 60.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not low <= v <= high:
                raise ConfigError(f"tool runout '{name}' must be a number in [{low:g}, {high:g}], got {v!r}")


def power_bases(cuts, runout: ToolRunout, *, samples: int = 720, axial_slices: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Mean cutting power per unit K_tc and per unit K_te of each cut, with the tool's runout.

    Parameters
    ----------
    cuts : sequence of CutConditions
        The calibration cuts.
    runout : ToolRunout
        The measured runout and helix.
    samples : int
        Spindle angles per revolution of the force model.
    axial_slices : int
        Axial slices of the helix.

    Returns
    -------
    b_c : ndarray
        Power per unit K_tc [W / (N/m^2)] = [m^3/s] (the removal rate Q without runout).
    b_e : ndarray
        Power per unit K_te [W / (N/m)] = [m^2/s] (the contact-area rate A_c without runout).
    """
    from drivesense.machine.milling import CuttingCoefficients, milling_forces

    if not isinstance(runout, ToolRunout):
        raise ConfigError(f"'runout' must be a ToolRunout, got {type(runout).__name__}")
    angle = np.linspace(0.0, 2.0 * math.pi, int(samples), endpoint=False)
    unit_c, unit_e = CuttingCoefficients(1.0, 0.0, 0.0, 0.0, 0.0, 0.0), CuttingCoefficients(0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
    b_c, b_e = [], []
    for cut in cuts:
        tool = cut.end_mill(runout.helix_deg, runout.offset, runout.phase)
        geometry = cut.milling_cut(axial_slices)
        for unit, out in ((unit_c, b_c), (unit_e, b_e)):
            f = milling_forces(tool, unit, geometry, angle, cut.feed_per_tooth)
            out.append(float(np.mean(f.torque)) * cut.spindle_speed)
    return np.array(b_c), np.array(b_e)
