"""Closed-loop, full-closed cascade control of one ball-screw axis (compiled).

Control runs at ``fs`` (10 kHz by default): a P position loop on the linear
scale with velocity and acceleration feedforward, a PI velocity loop on the
motor encoder, and a current reference sent through the driver's dead time
``T_a`` to the current loop (first order ``omega_cc``, optionally a second
pole).  The recorded encoder signals are delayed by ``T_b``.  The plant is
integrated with ``substeps`` semi-implicit Euler steps per control period;
LuGre bristles are integrated exactly over each sub-step.

The friction, ripple and quantisation physics are the shared implementations
of :mod:`drivesense.machine.friction` and :func:`drivesense.sim.encoders.quantise`
(the linear-motor simulator uses the same ones).  The compiled loop reads its
parameters from named tuples (:class:`StageParams`, :class:`ControlParams`,
:class:`~drivesense.sim.encoders.EncoderParams`, :class:`~drivesense.sim.encoders.ScaleParams`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numba import njit

from drivesense.machine import friction
from drivesense.machine.friction import LuGreFriction, LuGreParams, RippleParams, coulomb_level, lugre_step, \
    ripple_params, ripple_sum
from drivesense.machine.stage import StagePhysics
from drivesense.sim import encoders
from drivesense.sim.encoders import LinearScale, RotaryEncoder, quantise
from drivesense.sim.kernel_cache import source_digest

__all__ = ["ServoConfig", "ServoResult", "StageParams", "ControlParams", "run_servo"]


@dataclass(frozen=True)
class ServoConfig:
    """Controller, driver and sampling settings.

    Parameters
    ----------
    fs : float
        Control and recording rate [Hz].
    substeps : int
        Plant integration steps per control period.
    position_gain : float
        Position-loop gain ``K_p`` [1/s].
    velocity_gain : float
        Velocity-loop proportional gain [N/(m/s)] (motor-side translational).
    velocity_integral : float
        Velocity-loop integral gain [N/m].
    accel_feedforward_mass : float
        Mass used for acceleration feedforward [kg] (0: none).
    T_a : float
        Driver dead time [s].
    T_b : float
        Encoder-side dead time (transmission, differentiation) [s].
    omega_cc : float
        Current-loop bandwidth [rad/s].
    current_noise : float
        White noise on the real motor current, 1 sigma [A].
    current_sensor_noise : float
        Extra noise on the recorded current response, 1 sigma [A].
    """

    fs: float = 10_000.0
    substeps: int = 3
    position_gain: float = 150.0
    velocity_gain: float = 5.5e4
    velocity_integral: float = 5.0e6
    accel_feedforward_mass: float = 88.0
    T_a: float = 0.2e-3
    T_b: float = 0.2e-3
    omega_cc: float = 5000.0
    current_noise: float = 2.0e-3
    current_sensor_noise: float = 5.0e-3

    def as_ideal(self) -> "ServoConfig":
        """The same controller without current noise (part of :meth:`ScenarioSettings.as_ideal
        <drivesense.sim.scenarios.ScenarioSettings.as_ideal>`).

        Returns
        -------
        ServoConfig
        """
        return replace(self, current_noise=0.0, current_sensor_noise=0.0)

    def params(self, enabled: bool = True) -> "ControlParams":
        """The settings as the named tuple the compiled loop reads.

        Parameters
        ----------
        enabled : bool
            Closed loop (False: only the current excitation drives the motor).

        Returns
        -------
        ControlParams
        """
        return ControlParams(float(self.fs), int(self.substeps), float(self.position_gain),
                             float(self.velocity_gain), float(self.velocity_integral),
                             float(self.accel_feedforward_mass), float(self.T_a), float(self.T_b),
                             float(self.omega_cc), float(self.current_noise), float(self.current_sensor_noise),
                             bool(enabled))


class ControlParams(NamedTuple):
    """Controller and sampling settings for the compiled loop (see :meth:`ServoConfig.params`).

    Attributes
    ----------
    fs : float
        Control rate [Hz].
    substeps : int
        Plant steps per control period.
    position_gain : float
        Position-loop gain [1/s].
    velocity_gain : float
        Velocity-loop P gain [N/(m/s)].
    velocity_integral : float
        Velocity-loop integral gain [N/m].
    accel_feedforward_mass : float
        Acceleration feedforward mass [kg].
    T_a, T_b : float
        Driver and encoder dead times [s].
    omega_cc : float
        Current-loop bandwidth [rad/s].
    current_noise, current_sensor_noise : float
        Current disturbance and measurement noise, 1 sigma [A].
    closed : bool
        Closed loop.
    """

    fs: float
    substeps: int
    position_gain: float
    velocity_gain: float
    velocity_integral: float
    accel_feedforward_mass: float
    T_a: float
    T_b: float
    omega_cc: float
    current_noise: float
    current_sensor_noise: float
    closed: bool


class StageParams(NamedTuple):
    """What the compiled loop reads of :class:`~drivesense.machine.stage.StagePhysics`.

    The linear mechanics enter through the exact discretisation instead.

    Attributes
    ----------
    K_r : float
        Screw-nut stiffness [N/m] (turns the lead error into a force).
    R : float
        Table travel per motor radian ``lead / (2 pi)`` [m/rad].
    K_t : float
        Torque constant [N*m/A].
    kt_droop : float
        Relative fall of ``K_t`` at the rated current [-].
    rated_current, max_current : float
        Rated current and current limit [A].
    extra_pole : float
        Second current-loop pole [rad/s] (0: none).
    has_motor_friction, has_guide_friction : bool
        Whether each friction is present.
    motor_friction, guide_friction : LuGreParams
        Motor-side (coordinate ``x_m``) and guideway (``x_t``) friction.
    cogging : RippleParams
        Cogging force [N] over ``x_m`` [m].
    lead_error : RippleParams
        Screw lead error [m] over ``x_m`` [m].
    """

    K_r: float
    R: float
    K_t: float
    kt_droop: float
    rated_current: float
    max_current: float
    extra_pole: float
    has_motor_friction: bool
    motor_friction: LuGreParams
    has_guide_friction: bool
    guide_friction: LuGreParams
    cogging: RippleParams
    lead_error: RippleParams

    @classmethod
    def of(cls, stage: StagePhysics) -> "StageParams":
        """Build from the stage physics (absent friction gets inert placeholder values).

        Parameters
        ----------
        stage : StagePhysics

        Returns
        -------
        StageParams
        """
        ax = stage.axis

        def fric(f: LuGreFriction | None) -> LuGreParams:
            return f.params() if f is not None else LuGreFriction(0.0, 0.0, 1.0, 1.0, 0.0).params()

        return cls(float(ax.K_r), float(ax.R), float(ax.K_t), float(stage.kt_droop), float(stage.rated_current),
                   float(stage.max_current), float(stage.current_loop_extra_pole),
                   stage.motor_friction is not None, fric(stage.motor_friction),
                   stage.guide_friction is not None, fric(stage.guide_friction),
                   ripple_params(stage.cogging), ripple_params(stage.lead_error))


@dataclass(frozen=True)
class ServoResult:
    """Arrays produced by :func:`run_servo` (length ``n`` each, SI).

    Attributes
    ----------
    current_ref, current : ndarray
        Current reference and measured current response [A].
    motor_angle, table_position : ndarray
        Recorded (delayed, noisy, quantised) encoder signals [rad], [m].
    true_motor_position, true_table_position, true_table_velocity : ndarray
        Plant state at the control instants [m], [m], [m/s].
    """

    current_ref: np.ndarray
    current: np.ndarray
    motor_angle: np.ndarray
    table_position: np.ndarray
    true_motor_position: np.ndarray
    true_table_position: np.ndarray
    true_table_velocity: np.ndarray


def run_servo(stage: StagePhysics, config: ServoConfig, position_ref, velocity_ff, accel_ff,
              table_force, normal_load, *, encoder: RotaryEncoder | None = None,
              scale: LinearScale | None = None, seed: int = 0, enabled: bool = True,
              current_excitation=None) -> ServoResult:
    """Simulate the axis under closed-loop control.

    Parameters
    ----------
    stage : StagePhysics
        Plant physics.
    config : ServoConfig
        Controller and sampling settings.
    position_ref, velocity_ff, accel_ff : array_like
        Table position reference [m], velocity [m/s] and acceleration [m/s^2]
        feedforward at the control instants.
    table_force : array_like
        External (process) force on the table along +x [N]: either at the
        control instants (length ``n``; linearly interpolated) or at every
        sub-step start ``(k + j / substeps) / fs`` (length ``n * substeps``);
        each sub-step applies the mean of its start and end values.
    normal_load : array_like
        Extra normal load on the guides [N] (raises guide friction).
    encoder, scale : RotaryEncoder, LinearScale, optional
        Measurement models (defaults: the first paper's encoders).
    seed : int
        Seed of the noise generators.
    enabled : bool
        ``False`` opens the loop (only the excitation drives the motor): for free-response tests.
    current_excitation : array_like, optional
        Signal added to the controller's current reference [A] before the
        current limit (FRF excitation); part of the recorded ``current_ref``.

    Returns
    -------
    ServoResult
    """
    encoder = encoder or RotaryEncoder()
    scale = scale or LinearScale()
    n = np.size(position_ref)
    excitation = np.zeros(n) if current_excitation is None else current_excitation
    fine_force = np.ascontiguousarray(table_force, dtype=np.float64)
    if fine_force.size not in (n, n * config.substeps):
        raise ValueError(f"run_servo: all input arrays must have the same length ({n}); table_force may "
                         f"also have one sample per sub-step ({n * config.substeps}), got {fine_force.size}")
    coarse_force = fine_force if fine_force.size == n else np.zeros(n)
    arrays = [np.ascontiguousarray(a, dtype=np.float64)
              for a in (position_ref, velocity_ff, accel_ff, coarse_force, normal_load, excitation)]
    if any(a.size != n for a in arrays):
        raise ValueError("run_servo: all input arrays must have the same length")
    fine = fine_force if fine_force.size != n else np.zeros(0)
    phi, gamma = _exact_step(stage.axis, 1.0 / (config.fs * config.substeps))
    out = _servo_loop(StageParams.of(stage), config.params(enabled), phi, gamma, encoder.params(), scale.params(),
                      *arrays, fine, np.int64(seed))
    return ServoResult(*out)


def _exact_step(axis, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation over ``dt`` of the linear mechanics for inputs held constant.

    State ``[x_m, x_t, v_m, v_t]``, inputs ``[force on motor side, force on table]``
    (everything the linear model leaves out: thrust, friction, cogging, lead
    error, process force).
    """
    from scipy.linalg import expm

    m = axis.matrices()
    minv = np.linalg.inv(m.M)
    aug = np.zeros((6, 6))
    aug[0:2, 2:4] = np.eye(2)
    aug[2:4, 0:2] = -minv @ m.K
    aug[2:4, 2:4] = -minv @ m.C
    aug[2:4, 4:6] = minv
    e = expm(aug * dt)
    return np.ascontiguousarray(e[0:4, 0:4]), np.ascontiguousarray(e[0:4, 4:6])


@njit(cache=True)
def _interp_hist(hist: np.ndarray, pos: float) -> float:
    if pos <= 0.0:
        return hist[0]
    i = int(math.floor(pos))
    frac = pos - i
    if frac == 0.0:
        return hist[i]
    return hist[i] + frac * (hist[i + 1] - hist[i])


def _make_servo_loop(physics_source: str):
    """Compile the loop with its on-disk cache tied to ``physics_source`` (:mod:`drivesense.sim.kernel_cache`)."""

    @njit(cache=True)
    def _servo_loop(sp, cp, phi, gamma, enc, scl, x_ref, v_ff, a_ff, f_ext, n_load, i_exc, f_fine, seed):
        physics_source  # noqa: B018 -- part of numba's cache key (see drivesense.sim.kernel_cache)
        np.random.seed(seed)
        K_r, R, K_t = sp.K_r, sp.R, sp.K_t  # the linear mechanics are in phi/gamma
        droop, i_rated, i_max, pole2 = sp.kt_droop, sp.rated_current, sp.max_current, sp.extra_pole
        fric_m, fric_g, cog, lead_err = sp.motor_friction, sp.guide_friction, sp.cogging, sp.lead_error
        fs = cp.fs
        nsub = cp.substeps
        Kp, Kvp, Kvi, m_ff = cp.position_gain, cp.velocity_gain, cp.velocity_integral, cp.accel_feedforward_mass
        T_a, T_b, w_cc = cp.T_a, cp.T_b, cp.omega_cc
        i_noise, i_sens_noise = cp.current_noise, cp.current_sensor_noise
        closed = cp.closed
        T = 1.0 / fs
        dt = T / nsub
        n = x_ref.size
        has_fm = sp.has_motor_friction
        has_fg = sp.has_guide_friction

        out_iref = np.zeros(n)
        out_ires = np.zeros(n)
        out_theta = np.zeros(n)
        out_xt = np.zeros(n)
        true_xm = np.zeros(n)
        true_xt = np.zeros(n)
        true_vt = np.zeros(n)

        # encoder model
        enc_res, enc_periods, enc_noise = enc.resolution, enc.signal_periods, enc.noise
        n_harm = enc.interpolation_error.size
        scl_res, scl_noise = scl.resolution, scl.noise

        # plant state: start at rest at the reference, spring unloaded
        x_t = x_ref[0]
        x_m = x_t - ripple_sum(lead_err, x_t)
        v_m = 0.0
        v_t = 0.0
        z_m = 0.0
        z_g = 0.0
        i1 = 0.0
        i2 = 0.0
        integ = 0.0
        theta_prev = 0.0
        a1 = math.exp(-w_cc * dt) if w_cc > 0.0 else 0.0
        m1 = (1.0 - a1) / (w_cc * dt) if w_cc > 0.0 else 0.0  # mean of a first-order step response over dt
        a2 = math.exp(-pole2 * dt) if pole2 > 0.0 else 0.0
        tb_samples = T_b * fs
        ta_samples = T_a * fs

        for k in range(n):
            true_xm[k] = x_m
            true_xt[k] = x_t
            true_vt[k] = v_t
            # ---- measurement (delayed by T_b)
            pos = k - tb_samples
            xm_d = _interp_hist(true_xm, pos)
            xt_d = _interp_hist(true_xt, pos)
            theta = xm_d / R
            err = 0.0
            for h in range(n_harm):
                err += enc.interpolation_error[h] * math.sin((h + 1) * enc_periods * theta)
            theta_meas = quantise(theta + err + enc_noise * np.random.standard_normal(), enc_res)
            xt_meas = quantise(xt_d + scl_noise * np.random.standard_normal(), scl_res)
            if k == 0:
                theta_prev = theta_meas
            # ---- control
            v_cmd = v_ff[k] + Kp * (x_ref[k] - xt_meas)
            v_meas = (theta_meas - theta_prev) * R * fs
            theta_prev = theta_meas
            e = v_cmd - v_meas
            integ += Kvi * e * T
            f_cmd = Kvp * e + integ + m_ff * a_ff[k]
            i_ref = f_cmd * R / K_t + i_exc[k]
            if i_ref > i_max:
                i_ref = i_max
            elif i_ref < -i_max:
                i_ref = -i_max
            if not closed:
                i_ref = i_exc[k]
                integ = 0.0
            out_iref[k] = i_ref
            out_theta[k] = theta_meas
            out_xt[k] = xt_meas
            out_ires[k] = (i2 if pole2 > 0.0 else i1) + i_sens_noise * np.random.standard_normal()

            # ---- position-dependent terms, once per control period
            cog_f = ripple_sum(cog, x_m)
            lead = ripple_sum(lead_err, x_m)
            i_dist = i_noise * np.random.standard_normal()
            f0 = f_ext[k]
            f1 = f_ext[k + 1] if k + 1 < n else f0
            load = n_load[k]
            fc_m = coulomb_level(fric_m, x_m, 0.0) if has_fm else 0.0
            fc_g = coulomb_level(fric_g, x_t, load) if has_fg else 0.0
            # ---- plant sub-steps
            for j in range(nsub):
                t_rel = k + j / nsub - ta_samples  # driver input index (zero-order hold)
                idx = int(math.floor(t_rel + 1e-9))
                i_in = out_iref[idx] if idx >= 0 else 0.0
                # the linear mechanics are stepped exactly (phi, gamma); everything else is held over the
                # sub-step at its mean (current) or start value (friction, cogging, lead error)
                if pole2 > 0.0:
                    i_start = i2
                    i1 = i_in + (i1 - i_in) * a1
                    i2 = i1 + (i2 - i1) * a2
                    i_act = 0.5 * (i_start + i2)
                else:
                    i_act = i_in + (i1 - i_in) * m1
                    i1 = i_in + (i1 - i_in) * a1
                i_act += i_dist
                kt = K_t * (1.0 - droop * (i_act / i_rated) ** 2)
                f_motor = kt * i_act / R + cog_f
                if has_fm:
                    z_m, ff_m = lugre_step(fric_m, z_m, v_m, fc_m, dt)
                else:
                    ff_m = 0.0
                if has_fg:
                    z_g, ff_g = lugre_step(fric_g, z_g, v_t, fc_g, dt)
                else:
                    ff_g = 0.0
                if f_fine.size > 0:
                    i_f = k * nsub + j
                    f_cut = 0.5 * (f_fine[i_f] + f_fine[i_f + 1]) if i_f + 1 < f_fine.size else f_fine[i_f]
                else:  # Catmull-Rom through the neighbouring samples, at the sub-step midpoint
                    u = (j + 0.5) / nsub
                    fm1 = f_ext[k - 1] if k > 0 else f0
                    f2 = f_ext[k + 2] if k + 2 < n else f1
                    f_cut = 0.5 * (2.0 * f0 + (f1 - fm1) * u + (2.0 * fm1 - 5.0 * f0 + 4.0 * f1 - f2) * u * u
                                   + (3.0 * f0 - fm1 - 3.0 * f1 + f2) * u * u * u)
                u_m = f_motor - ff_m - K_r * lead
                u_t = f_cut - ff_g + K_r * lead
                x_m, x_t, v_m, v_t = (
                    phi[0, 0] * x_m + phi[0, 1] * x_t + phi[0, 2] * v_m + phi[0, 3] * v_t + gamma[0, 0] * u_m + gamma[0, 1] * u_t,
                    phi[1, 0] * x_m + phi[1, 1] * x_t + phi[1, 2] * v_m + phi[1, 3] * v_t + gamma[1, 0] * u_m + gamma[1, 1] * u_t,
                    phi[2, 0] * x_m + phi[2, 1] * x_t + phi[2, 2] * v_m + phi[2, 3] * v_t + gamma[2, 0] * u_m + gamma[2, 1] * u_t,
                    phi[3, 0] * x_m + phi[3, 1] * x_t + phi[3, 2] * v_m + phi[3, 3] * v_t + gamma[3, 0] * u_m + gamma[3, 1] * u_t,
                )
        return out_iref, out_ires, out_theta, out_xt, true_xm, true_xt, true_vt

    return _servo_loop


_servo_loop = _make_servo_loop(source_digest(friction, encoders))
