"""Dual-inertia model of a ball-screw-driven stage (first paper, Eq. 1-4).

The motor side (motor, coupling, screw) and the table are two inertias joined
by the axial stiffness ``K_r`` and damping ``C_k`` of the screw/nut/bearing
chain.  Rotational quantities are written as translational ones through the
screw radius ``R = lead / (2 pi)`` [m/rad]: ``x_m = R theta_m``,
``M_r = J_r / R^2``, ``C_r = D_r / R^2``.

With proportional damping (``C_r / M_r == C_t / M_t``) the modal transform
``[phi] = [[1, 1], [1, -1/alpha]]`` (``alpha = M_t / M_r``) decouples the model
into a rigid-body mode and a vibration mode (Eq. 3-4).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from drivesense.errors import ConfigError
from drivesense.machine.validation import dataclass_from_dict

__all__ = ["BallScrewAxis", "ModalMatrices"]


@dataclass(frozen=True)
class ModalMatrices:
    """Mass, damping and stiffness matrices of Eq. 2 or Eq. 4.

    Attributes
    ----------
    M : ndarray, shape (2, 2)
        Mass matrix [kg].
    C : ndarray, shape (2, 2)
        Damping matrix [N*s/m].
    K : ndarray, shape (2, 2)
        Stiffness matrix [N/m].
    """

    M: np.ndarray
    C: np.ndarray
    K: np.ndarray


@dataclass(frozen=True)
class BallScrewAxis:
    """Parameters of a ball-screw axis (the first paper's Table 1 notation).

    Parameters
    ----------
    J_r : float
        Total inertia of motor, coupling and screw [kg*m^2].
    M_t : float
        Total moving mass of the table [kg].
    C_t : float
        Viscous coefficient of the translational element [N*s/m].
    C_k : float
        Damping coefficient of the screw mechanism [N*s/m].
    D_r : float
        Viscous coefficient of the rotational element [N*m*s/rad].
    K_r : float
        Total axial rigidity of the feed-screw system [N/m].
    lead : float
        Screw lead [m/rev].
    K_t : float
        Motor torque constant [N*m/A].
    """

    J_r: float
    M_t: float
    C_t: float
    C_k: float
    D_r: float
    K_r: float
    lead: float
    K_t: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool):
                raise ConfigError(f"axis parameter '{f.name}' must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ConfigError(f"axis parameter '{f.name}' must be finite, got {value!r}")
            if f.name in ("C_t", "C_k", "D_r"):
                if value < 0:
                    raise ConfigError(f"axis parameter '{f.name}' must be >= 0, got {value!r}")
            elif value <= 0:
                raise ConfigError(f"axis parameter '{f.name}' must be > 0, got {value!r}")

    # ------------------------------------------------------------------ derived
    @property
    def R(self) -> float:
        """Screw radius: table travel per motor radian [m/rad]."""
        return self.lead / (2.0 * math.pi)

    @property
    def M_r(self) -> float:
        """Motor-side inertia written as a mass, ``J_r / R^2`` [kg]."""
        return self.J_r / self.R**2

    @property
    def C_r(self) -> float:
        """Motor-side viscous coefficient as a translational one, ``D_r / R^2`` [N*s/m]."""
        return self.D_r / self.R**2

    @property
    def alpha(self) -> float:
        """Inertia ratio ``M_t / M_r`` [-]."""
        return self.M_t / self.M_r

    @property
    def alpha_c(self) -> float:
        """Mass-proportional damping factor ``C_r / M_r`` [1/s] (Eq. 2, proportional damping)."""
        return self.C_r / self.M_r

    @property
    def beta_c(self) -> float:
        """Stiffness-proportional damping factor ``C_k / K_r`` [s]."""
        return self.C_k / self.K_r

    @property
    def force_per_amp(self) -> float:
        """Motor thrust per ampere of current, ``K_t / R`` [N/A]."""
        return self.K_t / self.R

    @property
    def proportional_damping_mismatch(self) -> float:
        """Relative mismatch of ``C_r/M_r`` and ``C_t/M_t`` [-]; 0 means exactly proportional."""
        return abs(self.C_r / self.M_r - self.C_t / self.M_t) / (self.C_r / self.M_r)

    # ----------------------------------------------------------------- matrices
    def matrices(self) -> ModalMatrices:
        """Physical matrices of Eq. 2 in the coordinates ``(x_m, x_t)``."""
        M = np.diag([self.M_r, self.M_t])
        C = np.array([[self.C_r + self.C_k, -self.C_k], [-self.C_k, self.C_t + self.C_k]])
        K = self.K_r * np.array([[1.0, -1.0], [-1.0, 1.0]])
        return ModalMatrices(M, C, K)

    def modal_transform(self) -> np.ndarray:
        """The modal matrix ``[phi]`` of Eq. 3: ``{x} = [phi] {x_modal}``."""
        return np.array([[1.0, 1.0], [1.0, -1.0 / self.alpha]])

    def to_modal(self, x_m, x_t):
        """Modal coordinates ``(x_rigid, x_vib)`` of Eq. 3 from motor-side and table positions.

        Parameters
        ----------
        x_m, x_t : array_like
            Motor-side position ``R theta_m`` and table position [m] (or velocities,
            accelerations: the transform is linear).

        Returns
        -------
        x_rigid, x_vib : ndarray
            Rigid-body and vibration-mode coordinates [m].
        """
        a = self.alpha
        x_m = np.asarray(x_m, dtype=float)
        x_t = np.asarray(x_t, dtype=float)
        return (x_m + a * x_t) / (1.0 + a), a * (x_m - x_t) / (1.0 + a)

    def modal_matrices(self) -> ModalMatrices:
        """Modal matrices ``[phi]^T [M|C|K] [phi]`` of Eq. 4.

        Diagonal when damping is proportional; ``K[0, 0] == 0`` always (the
        rigid-body mode has no stiffness).
        """
        phi = self.modal_transform()
        m = self.matrices()
        return ModalMatrices(phi.T @ m.M @ phi, phi.T @ m.C @ phi, phi.T @ m.K @ phi)

    @property
    def M_rigid(self) -> float:
        """Rigid-body modal mass ``M_r + M_t`` [kg]."""
        return self.M_r + self.M_t

    @property
    def C_rigid(self) -> float:
        """Rigid-body modal damping ``C_r + C_t`` [N*s/m] (equals alpha_c M_rigid when proportional)."""
        return self.C_r + self.C_t

    @property
    def M_vib(self) -> float:
        """Vibration-mode modal mass ``(1 + 1/alpha) M_r`` [kg]."""
        return (1.0 + 1.0 / self.alpha) * self.M_r

    @property
    def C_vib(self) -> float:
        """Vibration-mode modal damping ``C_r + C_t/alpha^2 + C_k (1 + 1/alpha)^2`` [N*s/m]."""
        a = self.alpha
        return self.C_r + self.C_t / a**2 + self.C_k * (1.0 + 1.0 / a) ** 2

    @property
    def K_vib(self) -> float:
        """Vibration-mode modal stiffness ``(1 + 1/alpha)^2 K_r`` [N/m]."""
        return (1.0 + 1.0 / self.alpha) ** 2 * self.K_r

    @property
    def natural_frequency_hz(self) -> float:
        """Undamped natural frequency of the vibration mode [Hz]."""
        return math.sqrt(self.K_vib / self.M_vib) / (2.0 * math.pi)

    # --------------------------------------------------------------- responses
    def frf(self, freq_hz) -> dict[str, np.ndarray]:
        """Analytic frequency responses to motor thrust and to a table force.

        Parameters
        ----------
        freq_hz : array_like
            Frequencies [Hz].

        Returns
        -------
        dict of ndarray (complex)
            ``"xm_per_thrust"``, ``"xt_per_thrust"`` [m/N]: displacement per
            motor thrust ``K_t I / R``; ``"xm_per_force"``, ``"xt_per_force"``
            [m/N]: displacement per force acting on the table in +x.
        """
        w = 2.0 * math.pi * np.asarray(freq_hz, dtype=float)
        m = self.matrices()
        out = {k: np.empty(w.shape, complex) for k in ("xm_per_thrust", "xt_per_thrust", "xm_per_force", "xt_per_force")}
        for i, wi in enumerate(w.ravel()):
            Z = -wi**2 * m.M + 1j * wi * m.C + m.K
            G = np.linalg.inv(Z)
            idx = np.unravel_index(i, w.shape)
            out["xm_per_thrust"][idx] = G[0, 0]
            out["xt_per_thrust"][idx] = G[1, 0]
            out["xm_per_force"][idx] = G[0, 1]
            out["xt_per_force"][idx] = G[1, 1]
        return out

    # ------------------------------------------------------------- persistence
    def to_dict(self) -> dict[str, float]:
        """Parameters as a plain dict (SI), keys as in the paper."""
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict, *, source: str = "axis parameters") -> "BallScrewAxis":
        """Build from a mapping with exactly the keys of the paper.

        Parameters
        ----------
        values : dict
            Parameter name -> value [SI unit of the parameter].
        source : str, optional
            Where the values come from (a file name), to start error messages.

        Returns
        -------
        BallScrewAxis

        Raises
        ------
        ConfigError
            Naming missing or unknown keys and bad values.
        """
        return dataclass_from_dict(cls, values, source)
