"""Flexible tool/spindle modes: what makes a milling cut chatter (regenerative vibration).

The tool tip is a set of uncoupled single-degree-of-freedom modes along the
machine's x (feed) and y (normal to the feed) directions of the milling force
model (:mod:`drivesense.machine.milling`).  Mode ``k`` of direction ``d`` obeys
``m_k q'' + c_k q' + k_k q = F_d`` with ``m_k = k_k / omega_k^2`` and
``c_k = 2 zeta_k sqrt(k_k m_k)``; the tip's displacement is the sum of the
modes.  The direct FRF (receptance) of a direction is
``G(omega) = sum_k 1 / (k_k (1 - r^2 + 2 i zeta_k r))``, ``r = omega / omega_k``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivesense.errors import ConfigError
from drivesense.machine.milling import check_number

__all__ = ["ToolMode", "ToolDynamics"]


@dataclass(frozen=True)
class ToolMode:
    """One vibration mode of the tool tip.

    Parameters
    ----------
    frequency_hz : float
        Natural frequency f_n [Hz], > 0.
    damping_ratio : float
        Modal damping ratio zeta [-], in (0, 1).
    stiffness : float
        Modal stiffness k [N/m], > 0.
    """

    frequency_hz: float
    damping_ratio: float
    stiffness: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "frequency_hz", check_number(self.frequency_hz, "frequency_hz", positive=True))
        zeta = check_number(self.damping_ratio, "damping_ratio", positive=True)
        if zeta >= 1.0:
            raise ConfigError(f"'damping_ratio' must be < 1, got {zeta!r}")
        object.__setattr__(self, "damping_ratio", zeta)
        object.__setattr__(self, "stiffness", check_number(self.stiffness, "stiffness", positive=True))

    @property
    def mass(self) -> float:
        """Modal mass k / omega_n^2 [kg]."""
        return self.stiffness / (2 * math.pi * self.frequency_hz) ** 2

    def receptance(self, freq) -> np.ndarray:
        """Displacement per force ``1 / (k (1 - r^2 + 2 i zeta r))`` [m/N] at ``freq`` [Hz].

        Parameters
        ----------
        freq : array_like
            Frequencies [Hz].
        """
        r = np.asarray(freq, dtype=float) / self.frequency_hz
        return 1.0 / (self.stiffness * (1.0 - r ** 2 + 2j * self.damping_ratio * r))


@dataclass(frozen=True)
class ToolDynamics:
    """The tool tip's modes along x (feed) and y (normal to the feed).

    Parameters
    ----------
    x, y : tuple of ToolMode
        Modes of each direction (empty: rigid in that direction).
    """

    x: tuple = ()
    y: tuple = ()

    def __post_init__(self) -> None:
        for name in ("x", "y"):
            modes = tuple(getattr(self, name))
            if not all(isinstance(m, ToolMode) for m in modes):
                raise ConfigError(f"ToolDynamics.{name} must hold ToolMode objects")
            object.__setattr__(self, name, modes)
        if not (self.x or self.y):
            raise ConfigError("ToolDynamics needs at least one mode (x or y)")

    @classmethod
    def symmetric(cls, frequency_hz: float = 600.0, damping_ratio: float = 0.03,
                  stiffness: float = 5.0e6) -> "ToolDynamics":
        """The same single mode in x and y (a slender end mill in a stiff spindle).

        Parameters
        ----------
        frequency_hz : float
            Natural frequency [Hz].
        damping_ratio : float
            Damping ratio [-].
        stiffness : float
            Modal stiffness [N/m].
        """
        mode = ToolMode(frequency_hz, damping_ratio, stiffness)
        return cls(x=(mode,), y=(mode,))

    def receptance(self, freq) -> tuple[np.ndarray, np.ndarray]:
        """Direct FRFs ``G_xx``, ``G_yy`` [m/N] at ``freq`` [Hz] (zero where a direction is rigid).

        Parameters
        ----------
        freq : array_like
            Frequencies [Hz].
        """
        f = np.asarray(freq, dtype=float)
        gx = sum((m.receptance(f) for m in self.x), np.zeros(f.shape, dtype=complex))
        gy = sum((m.receptance(f) for m in self.y), np.zeros(f.shape, dtype=complex))
        return gx, gy

    def modal_arrays(self) -> np.ndarray:
        """Rows ``(direction 0|1, omega_n [rad/s], zeta, stiffness [N/m])`` for the time-domain kernel."""
        rows = [(0.0, 2 * math.pi * m.frequency_hz, m.damping_ratio, m.stiffness) for m in self.x]
        rows += [(1.0, 2 * math.pi * m.frequency_hz, m.damping_ratio, m.stiffness) for m in self.y]
        return np.array(rows, dtype=float)
