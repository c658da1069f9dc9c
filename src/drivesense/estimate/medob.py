"""Multi-encoder disturbance observer (MEDOB), the first paper's Appendix form."""

from __future__ import annotations

from drivesense.errors import ConfigError
from drivesense.estimate.ballscrew import BallScrewEstimator
from drivesense.estimate.design import ForceCombination

__all__ = ["MEDOB"]


class MEDOB(BallScrewEstimator):
    """Disturbance observer on motor angle and table position.

    ``F_cut = (K_t I - J_r alpha_m - D_r omega_m - T_fric)/R - M_t a_t - C_t v_t - F_fric``
    (Appendix; Eq. 6 of the authors' earlier MEDOB paper), realised in
    observer form: the low-pass ``Q(s)`` and the derivatives ``s Q(s)``,
    ``s^2 Q(s)`` are discretised together by the bilinear transform
    (pseudo-differentiation), as a disturbance observer is built, rather than
    by explicit numerical differentiation.  Under proportional damping it
    equals :class:`~drivesense.estimate.rigid.RigidBody` (Appendix), which the
    tests check.  Parameters as
    :class:`~drivesense.estimate.ballscrew.BallScrewEstimator`.
    """

    name = "medob"
    models_vibration_mode = True
    discretisation = "bilinear"

    def combination(self) -> ForceCombination:
        """Rotational terms ``J_r/R^2 = M_r``, ``D_r/R^2 = C_r`` on the motor side, M_t, C_t on the table.

        Raises
        ------
        ConfigError
            For a low-pass of order < 2 (the observer needs ``s^2 Q(s)`` to be proper).
        """
        if self.signal.lpf_order < 2:
            raise ConfigError("signal parameter 'lpf_order' must be >= 2 for MEDOB "
                              "(the observer needs s^2 Q(s) to be proper)")
        ax = self.axis
        return ForceCombination(c_I=1.0, m_m=ax.M_r, c_m=ax.C_r, m_t=ax.M_t, c_t=ax.C_t)
