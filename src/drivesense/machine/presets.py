"""Named parameter sets.

``table1_axis`` is the ball-screw stage of the first paper's Table 1.  The
paper does not give the motor torque constant; drivesense assumes
``K_t = 0.45 N*m/A``, typical of a 400 W AC servo motor (rated about 2.8 A).

``table1_stage`` adds the physics the paper's model leaves out, with magnitudes
chosen so that the stage needs about 120 N of thrust to keep moving at 1 mm/s
(first paper, Sec. 5.2): about 102 N of screw/nut/bearing friction, 5 N of
guideway friction and 11 N of viscous force at that speed.
"""

from __future__ import annotations

from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.friction import LuGreFriction, Ripple
from drivesense.machine.signal_chain import SignalParams
from drivesense.machine.stage import StagePhysics

__all__ = ["TABLE1_KT", "table1_axis", "table1_signal", "table1_stage"]

#: Assumed torque constant of the Table 1 stage [N*m/A] (not given in the paper).
TABLE1_KT = 0.45


def table1_axis() -> BallScrewAxis:
    """The ball-screw stage of Table 1 (first paper), SI units.

    ``J_r = 5.18e-5 kg m^2``, ``M_t = 6.55 kg``, ``C_t = 821 N s/m``,
    ``C_k = 1760 N s/m``, ``D_r = 6.50e-3 N m s/rad``, ``K_r = 40.5 N/um``,
    lead 5 mm, and the assumed ``K_t = 0.45 N m/A``.  The inertia ratio is
    0.080 and the vibration mode lies near 411 Hz.
    """
    return BallScrewAxis(J_r=5.18e-5, M_t=6.55, C_t=8.21e2, C_k=1.76e3, D_r=6.50e-3,
                         K_r=40.5e6, lead=5e-3, K_t=TABLE1_KT)


def table1_signal() -> SignalParams:
    """The signal chain of the first paper's drive: its dead times, current loop and low-pass (the
    :class:`~drivesense.machine.signal_chain.SignalParams` defaults) and its motor encoder of 2^23 counts made
    of 512 signal periods per revolution."""
    return SignalParams(encoder_signal_periods=512)


def table1_stage() -> StagePhysics:
    """Table 1 stage with the full physics used by every benchmark scenario.

    Motor side (screw, nut, support bearings; coordinate ``x_m``): LuGre with
    ``F_c = 95 N``, ``F_s = 115 N``, ``v_s = 1 mm/s``, ripple at the 5 mm lead,
    1.25 mm and 83 um, a slow drift along the travel.  Guideway (``x_t``):
    LuGre with ``F_c = 5 N``, a 10 um presliding range, ripple at 25 mm and
    2.2 mm, and 0.5 % of the process's normal force added.  Cogging at 72 and
    144 cycles per motor revolution, screw lead error of 0.4 um at the lead,
    3 % torque-constant droop at rated current, and a 60 000 rad/s second pole
    in the current loop.
    """
    axis = table1_axis()
    motor = LuGreFriction(
        F_c=95.0, F_s=115.0, v_s=1.0e-3, sigma0=1.0e8, sigma1=2.0e3, sigma2=0.0,
        ripples=(Ripple(5.0e-3, 4.0, 0.3), Ripple(1.25e-3, 1.5, 1.1), Ripple(83e-6, 1.0, 2.0)),
        drift_per_m=100.0,
    )
    guide = LuGreFriction(
        F_c=5.0, F_s=6.0, v_s=1.0e-3, sigma0=5.0e5, sigma1=1.0e2, sigma2=0.0,
        ripples=(Ripple(25e-3, 0.5, 0.7), Ripple(2.2e-3, 0.3, 2.5)),
        drift_per_m=20.0, load_coefficient=0.005,
    )
    lead = axis.lead
    return StagePhysics(
        axis=axis,
        motor_friction=motor,
        guide_friction=guide,
        cogging=(Ripple(lead / 72, 1.5, 0.4), Ripple(lead / 144, 0.5, 1.3), Ripple(lead / 24, 0.8, 2.2)),
        lead_error=(Ripple(lead, 0.4e-6, 0.9), Ripple(lead / 2, 0.1e-6, 0.2)),
        kt_droop=0.03,
        rated_current=2.8,
        max_current=8.4,
        current_loop_extra_pole=6.0e4,
    )
