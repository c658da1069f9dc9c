"""Vibration-mode estimator (first paper, Eq. 6)."""

from __future__ import annotations

from drivesense.estimate.ballscrew import BallScrewEstimator
from drivesense.estimate.design import ForceCombination

__all__ = ["VibrationMode"]


class VibrationMode(BallScrewEstimator):
    """Force from the vibration modal equation, Eq. 6.

    ``F_cut = -alpha [K_t I/R - T_fric/R + F_fric/alpha - (M_vib a_vib + C_vib v_vib + K_vib x_vib)]``
    with ``x_vib = alpha (x_m - x_t)/(1 + alpha)``.  In (x_m, x_t) terms the
    force rests on the relative motion of motor and table: ``alpha M_vib a_vib =
    M_t (a_m - a_t)`` and ``alpha K_vib x_vib = (1 + alpha) K_r (x_m - x_t)``;
    the motor thrust enters with weight ``alpha`` only (0.08 for Table 1),
    which is why friction on the motor side barely disturbs it.
    Parameters as :class:`~drivesense.estimate.ballscrew.BallScrewEstimator`.
    """

    name = "vibration"
    models_vibration_mode = True

    def combination(self) -> ForceCombination:
        """Eq. 6 in (x_m, x_t) coordinates, ``force_x = -F_cut``."""
        ax = self.axis
        a = ax.alpha
        c_v = a * a * ax.modal_matrices().C[1, 1] / (1.0 + a)
        k_v = (1.0 + a) * ax.K_r
        return ForceCombination(c_I=-a, m_m=-ax.M_t, m_t=ax.M_t, c_m=-c_v, c_t=c_v, k_m=-k_v, k_t=k_v)
