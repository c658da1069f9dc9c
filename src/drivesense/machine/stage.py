"""Full physics of a ball-screw stage: the dual-inertia model plus what it leaves out.

:class:`StagePhysics` is what the simulator integrates.  It extends the
estimators' linear model (:class:`~drivesense.machine.ballscrew.BallScrewAxis`)
with LuGre friction on both sides, friction ripple and drift along the travel,
load-dependent guide friction, motor cogging, screw lead error, a torque
constant that falls at high current and a current loop with an extra lag.
:meth:`StagePhysics.ideal` strips all of that, leaving exactly the
estimators' model (used by tests to show exact recovery).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.friction import LuGreFriction, Ripple

__all__ = ["StagePhysics"]


@dataclass(frozen=True)
class StagePhysics:
    """Simulation physics of one ball-screw axis.

    Parameters
    ----------
    axis : BallScrewAxis
        Linear dual-inertia parameters (the true ones).
    motor_friction : LuGreFriction or None
        Screw, nut and bearing friction written as a force on the motor side
        [N]; its ripple/drift coordinate is ``x_m = R theta_m`` [m].
    guide_friction : LuGreFriction or None
        Guideway friction on the table [N]; coordinate ``x_t`` [m]; its load
        coefficient acts on the process's normal (z) force.
    cogging : tuple of Ripple
        Motor cogging force [N] versus ``x_m`` [m].
    lead_error : tuple of Ripple
        Kinematic screw error: the nut sits at ``x_m + e(x_m)`` [m].
    kt_droop : float
        Relative fall of the torque constant at ``rated_current`` (quadratic) [-].
    rated_current : float
        Motor rated current [A].
    max_current : float
        Driver current limit [A].
    current_loop_extra_pole : float
        Second pole of the real current loop [rad/s] (0: none); the estimators
        model the loop as first order.
    """

    axis: BallScrewAxis
    motor_friction: LuGreFriction | None = None
    guide_friction: LuGreFriction | None = None
    cogging: tuple[Ripple, ...] = field(default_factory=tuple)
    lead_error: tuple[Ripple, ...] = field(default_factory=tuple)
    kt_droop: float = 0.0
    rated_current: float = 2.8
    max_current: float = 8.4
    current_loop_extra_pole: float = 0.0

    def ideal(self) -> "StagePhysics":
        """The estimators' own model: linear plant, no friction, cogging, lead error, droop or second pole.

        The physics part of :meth:`drivesense.sim.scenarios.ScenarioSettings.as_ideal`.

        Returns
        -------
        StagePhysics
        """
        return replace(self, motor_friction=None, guide_friction=None, cogging=(), lead_error=(),
                       kt_droop=0.0, current_loop_extra_pole=0.0)

    def varied(self, rng: np.random.Generator, spread: float = 0.02) -> "StagePhysics":
        """A copy with run-to-run variation of the friction levels.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the variation (one normal draw per friction present).
        spread : float
            Relative variation, 1 sigma [-].

        Returns
        -------
        StagePhysics
        """
        mf = self.motor_friction.scaled(1.0 + spread * rng.standard_normal()) if self.motor_friction else None
        gf = self.guide_friction.scaled(1.0 + spread * rng.standard_normal()) if self.guide_friction else None
        return replace(self, motor_friction=mf, guide_friction=gf)
