"""Rigid-body-mode estimator (first paper, Eq. 5)."""

from __future__ import annotations

from drivesense.estimate.ballscrew import BallScrewEstimator
from drivesense.estimate.design import ForceCombination

__all__ = ["RigidBody"]


class RigidBody(BallScrewEstimator):
    """Force from the rigid-body modal equation, Eq. 5.

    ``F_cut = K_t I/R - T_fric/R - F_fric - M_rigid a_rigid - C_rigid v_rigid``
    with ``x_rigid = (x_m + alpha x_t)/(1 + alpha)``, ``M_rigid = M_r + M_t``
    and ``C_rigid`` the (1, 1) element of the modal damping matrix.  No
    stiffness enters.  Derivatives by central differences.
    Parameters as :class:`~drivesense.estimate.ballscrew.BallScrewEstimator`.
    """

    name = "rigid"

    def combination(self) -> ForceCombination:
        """Eq. 5 in (x_m, x_t) coordinates: ``M_rigid a_rigid = M_r a_m + M_t a_t``."""
        ax = self.axis
        a = ax.alpha
        c_rigid = ax.modal_matrices().C[0, 0]
        return ForceCombination(c_I=1.0, m_m=ax.M_r, m_t=ax.M_t,
                                c_m=c_rigid / (1.0 + a), c_t=c_rigid * a / (1.0 + a))
