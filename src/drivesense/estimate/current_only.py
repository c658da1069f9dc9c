"""Conventional current-based estimate: motor thrust minus friction (the baseline)."""

from __future__ import annotations

from drivesense.estimate.ballscrew import BallScrewEstimator
from drivesense.estimate.design import ForceCombination

__all__ = ["CurrentOnly"]


class CurrentOnly(BallScrewEstimator):
    """``F_cut = K_t I_ref / R - friction``: no inertia, no encoders but for the friction map.

    The classical sensorless monitor (Altintas; Lee et al.), limited by the
    current loop and by everything the motor thrust must also overcome.
    Parameters as :class:`~drivesense.estimate.ballscrew.BallScrewEstimator`.
    """

    name = "current"

    def combination(self) -> ForceCombination:
        """Thrust only."""
        return ForceCombination(c_I=1.0)
