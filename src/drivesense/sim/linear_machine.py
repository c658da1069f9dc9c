"""Closed-loop control of the three linear-motor axes (compiled) and the NC trace it records.

Control runs at ``fs`` (4 kHz by default) for each axis: a P position loop
on the linear scale with velocity feedforward, a PI velocity loop on the
scale's differentiated position with acceleration feedforward, and a current
reference to the current loop (first order, plus a second pole in the full
physics).  The plant (motor force with droop, cogging, restoring force,
LuGre friction, process force, yaw coupling, a constant weight; each motor
moving the masses of :meth:`LinearMachinePhysics.moved_masses
<drivesense.machine.linear_motor.LinearMachinePhysics.moved_masses>`) is
integrated with ``substeps`` semi-implicit Euler steps per control period.

The controller's own values -- scale position, velocity and acceleration from
differences of the scale at the control rate, measured motor current -- are
what an NC trace can log.  :func:`nc_trace` turns them into the 250 Hz trace
of the third paper: the logger low-passes every drive channel with a causal
linear-phase FIR filter at the control rate (anti-aliasing; its magnitude is
that of the reference filter below, its delay -- half its length -- is
returned as the trace's delay) and keeps every ``fs / nc_rate``-th sample.
The true process force is low-passed with a zero-phase Butterworth filter
(120 Hz, like the paper's dynamometer chain) before the same decimation, so
the reference is not aliased.  With ``LinearServoConfig.as_ideal()`` (part of the
ideal-physics switch :meth:`drivesense.sim.machining.ProcessSettings.as_ideal`) the trace
holds point samples of the plant's true state and the unfiltered true force instead.

Friction and quantisation are the shared implementations
(:func:`~drivesense.machine.friction.coulomb_level`,
:func:`~drivesense.machine.friction.lugre_step`,
:func:`~drivesense.sim.encoders.quantise`) that the ball-screw simulator uses
too; the compiled loop reads named tuples (:class:`AxisParams`,
:class:`MachineParams`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy import signal as sps

from drivesense.errors import ConfigError
from drivesense.machine import friction, linear_motor
from drivesense.machine.friction import LuGreParams, coulomb_level, lugre_step, ripple_params
from drivesense.machine.linear_motor import AXES, LinearAxisPhysics, LinearMachinePhysics, cogging_table_force
from drivesense.sim import encoders
from drivesense.sim.encoders import quantise
from drivesense.sim.kernel_cache import source_digest

__all__ = ["LinearServoConfig", "LinearMachineResult", "AxisParams", "MachineParams", "axis_params",
           "run_linear_machine", "nc_trace"]

_G = 9.81


@dataclass(frozen=True)
class LinearServoConfig:
    """Controller, sensors and trace settings of the 3-axis machine.

    Parameters
    ----------
    fs : float
        Control rate [Hz].
    substeps : int
        Plant integration steps per control period.
    position_gain : float
        Position-loop gain [1/s].
    velocity_bandwidth_hz : float
        Velocity-loop bandwidth [Hz]; the P gain is the nominal moved mass
        times ``2 pi`` this [N/(m/s)].
    velocity_integral_time : float
        Integral time of the velocity PI [s].
    feedforward_mass_ratio : float
        Acceleration feedforward with this share of the nominal moved mass [-].
    current_noise : float
        White disturbance on the real motor current, 1 sigma [A].
    current_sensor_noise : float
        Noise on the measured current, 1 sigma [A].
    current_resolution : float
        Quantisation of the measured current [A] (0: none).
    scale_noise : float
        Noise of the linear scale, 1 sigma [m].
    scale_resolution : float
        Quantisation of the linear scale [m] (0: none).
    nc_rate : float
        Sample rate of the NC trace [Hz]; ``fs / nc_rate`` must be an integer.
    logger_delay : float
        Half-length (= delay) of the trace logger's linear-phase FIR
        anti-alias filter [s] (0: no filter, point samples).
    reference_cutoff_hz : float
        Cut-off of the zero-phase Butterworth low-pass of the true force [Hz].
    reference_order : int
        Order of that filter (0: unfiltered true force).
    true_state : bool
        Record point samples of the plant's true position, velocity,
        acceleration and current instead of the controller's measurements.
    """

    fs: float = 4000.0
    substeps: int = 4
    position_gain: float = 40.0
    velocity_bandwidth_hz: float = 60.0
    velocity_integral_time: float = 8.0e-3
    feedforward_mass_ratio: float = 0.95
    current_noise: float = 0.01
    current_sensor_noise: float = 0.02
    current_resolution: float = 2.0e-3
    scale_noise: float = 10.0e-9
    scale_resolution: float = 5.0e-9
    nc_rate: float = 250.0
    logger_delay: float = 0.02
    reference_cutoff_hz: float = 120.0
    reference_order: int = 4
    true_state: bool = False

    def __post_init__(self) -> None:
        ratio = self.fs / self.nc_rate
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise ConfigError(f"LinearServoConfig: fs / nc_rate = {ratio:g} must be a whole number >= 1")

    @property
    def decimation(self) -> int:
        """Control samples per NC-trace sample."""
        return int(round(self.fs / self.nc_rate))

    def as_ideal(self) -> "LinearServoConfig":
        """No noise, no quantisation, point samples of the true state and the unfiltered true force.

        The servo part of :meth:`ProcessSettings.as_ideal <drivesense.sim.machining.ProcessSettings.as_ideal>`.

        Returns
        -------
        LinearServoConfig
        """
        return replace(self, current_noise=0.0, current_sensor_noise=0.0, current_resolution=0.0,
                       scale_noise=0.0, scale_resolution=0.0, logger_delay=0.0, reference_order=0,
                       true_state=True)

    def logger_taps(self) -> np.ndarray:
        """Taps of the logger's FIR filter at ``fs`` (empty without one).

        The zero-phase impulse response of the reference filter (Butterworth,
        ``reference_order``, ``reference_cutoff_hz``; 4th order at 120 Hz when
        the reference is unfiltered), truncated to ``+-logger_delay`` with a
        Hann taper and normalised to unit DC gain.
        """
        half = int(round(self.logger_delay * self.fs))
        if half <= 0:
            return np.zeros(0)
        order = self.reference_order if self.reference_order > 0 else 4
        sos = sps.butter(order, self.reference_cutoff_hz, fs=self.fs, output="sos")
        imp = np.zeros(4 * half + 1)
        imp[2 * half] = 1.0
        h = sps.sosfiltfilt(sos, imp)[half:3 * half + 1] * np.hanning(2 * half + 3)[1:-1]
        return h / h.sum()


@dataclass(frozen=True)
class LinearMachineResult:
    """Arrays of :func:`run_linear_machine`, shape ``(3, n)`` (rows x, y, z) at the control rate.

    Attributes
    ----------
    position, velocity, acceleration, current : ndarray
        The controller's measured values [m], [m/s], [m/s^2], [A].
    true_position, true_velocity, true_acceleration, true_current : ndarray
        Plant state at the control instants [m], [m/s], [m/s^2], [A].
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    current: np.ndarray
    true_position: np.ndarray
    true_velocity: np.ndarray
    true_acceleration: np.ndarray
    true_current: np.ndarray


class AxisParams(NamedTuple):
    """One axis as the compiled loop reads it (see :func:`axis_params`).

    Attributes
    ----------
    K_m : float
        Motor constant [N/A].
    k : float
        Restoring constant [N/m].
    s_r : float
        Rest point of the restoring force [m].
    pole_pitch : float
        Pole pitch [m].
    mass : float
        Mass the motor moves [kg].
    velocity_gain : float
        Velocity-loop P gain [N/(m/s)].
    weight : float
        Constant gravity force along +axis [N] (net of a counterbalance).
    lugre : bool
        LuGre friction (full physics); False: the model's static Stribeck curve.
    friction : LuGreParams
        Friction: levels, Stribeck velocity and viscous coefficient of the
        model; stiffness, damping, ripple, drift and load coefficient of the
        LuGre friction (the drift taken about the travel centre).
    delta : float
        Stribeck shape factor of the model [-].
    km_droop : float
        Relative fall of ``K_m`` at the rated current [-].
    rated_current, max_current : float
        Rated current and current limit [A].
    current_bandwidth : float
        Current-loop bandwidth [rad/s].
    current_extra_pole : float
        Second current-loop pole [rad/s] (0: none).
    cogging_variation : float
        Relative change of the cogging amplitude along the travel [-].
    travel_length : float
        Length of the travel [m] (period of that change).
    cogging_amplitude, cogging_phase : ndarray
        Cogging harmonics 1, 2, ... of the pole pitch [N], [rad].
    cogging_table : ndarray
        The model's cogging table over one pole pitch [N].
    """

    K_m: float
    k: float
    s_r: float
    pole_pitch: float
    mass: float
    velocity_gain: float
    weight: float
    lugre: bool
    friction: LuGreParams
    delta: float
    km_droop: float
    rated_current: float
    max_current: float
    current_bandwidth: float
    current_extra_pole: float
    cogging_variation: float
    travel_length: float
    cogging_amplitude: np.ndarray
    cogging_phase: np.ndarray
    cogging_table: np.ndarray


class MachineParams(NamedTuple):
    """Controller, sensors and cross-axis effects as the compiled loop reads them.

    Attributes
    ----------
    fs : float
        Control rate [Hz].
    substeps : int
        Plant steps per control period.
    position_gain : float
        Position-loop gain [1/s].
    integral_time : float
        Velocity PI integral time [s].
    feedforward_mass_ratio : float
        Share of the moved mass in the acceleration feedforward [-].
    current_noise, current_sensor_noise : float
        Current disturbance and measurement noise, 1 sigma [A].
    current_resolution : float
        Quantisation of the measured current [A] (0: none).
    scale_noise : float
        Scale noise, 1 sigma [m].
    scale_resolution : float
        Scale quantisation [m] (0: none).
    yaw_coupling : float
        Share of X's inertial force on the Y drive [-].
    weight_shift_force : float
        Extra Y-guide load per metre of X away from its centre [N/m].
    x_mid : float
        Centre of the X travel [m].
    exact : bool
        The estimators' own model (:attr:`LinearMachinePhysics.exact
        <drivesense.machine.linear_motor.LinearMachinePhysics.exact>`).
    """

    fs: float
    substeps: int
    position_gain: float
    integral_time: float
    feedforward_mass_ratio: float
    current_noise: float
    current_sensor_noise: float
    current_resolution: float
    scale_noise: float
    scale_resolution: float
    yaw_coupling: float
    weight_shift_force: float
    x_mid: float
    exact: bool


def axis_params(axis: LinearAxisPhysics, exact: bool, mass: float, velocity_gain: float) -> AxisParams:
    """The compiled loop's view of one axis.

    Parameters
    ----------
    axis : LinearAxisPhysics
        The axis.
    exact : bool
        The estimators' own model: no drift, ripple, load dependence, droop,
        extra pole or cogging variation (and the model's friction and cogging table).
    mass : float
        Mass the motor moves [kg].
    velocity_gain : float
        Velocity-loop P gain [N/(m/s)].

    Returns
    -------
    AxisParams
    """
    md = axis.model
    fr = axis.friction
    full = not exact and fr is not None
    mid = 0.5 * (axis.travel[0] + axis.travel[1])
    drift = fr.drift_per_m if full else 0.0
    lugre_params = LuGreParams(
        F_c=md.F_C - drift * mid, F_s=md.F_br - drift * mid, v_s=md.v_s,
        sigma0=fr.sigma0 if fr is not None else 0.0, sigma1=fr.sigma1 if fr is not None else 0.0,
        sigma2=md.sigma, drift_per_m=drift, load_coefficient=fr.load_coefficient if full else 0.0,
        ripple=ripple_params(fr.ripples if full else ()))
    harm = np.array(axis.cogging_harmonics, dtype=np.float64).reshape(-1, 2)
    return AxisParams(
        K_m=md.K_m, k=md.k, s_r=md.s_r, pole_pitch=md.pole_pitch, mass=float(mass),
        velocity_gain=float(velocity_gain), weight=float(axis.weight), lugre=full, friction=lugre_params, delta=md.delta,
        km_droop=0.0 if exact else float(axis.km_droop), rated_current=float(axis.rated_current),
        max_current=float(axis.max_current), current_bandwidth=float(axis.current_bandwidth),
        current_extra_pole=0.0 if exact else float(axis.current_extra_pole),
        cogging_variation=0.0 if exact else float(axis.cogging_variation),
        travel_length=float(axis.travel[1] - axis.travel[0]),
        cogging_amplitude=np.ascontiguousarray(harm[:, 0]), cogging_phase=np.ascontiguousarray(harm[:, 1]),
        cogging_table=np.array(md.cogging, dtype=np.float64))


def run_linear_machine(physics: LinearMachinePhysics, config: LinearServoConfig, position_ref, velocity_ref,
                       acceleration_ref, work_force, normal_load, *, seed: int = 0) -> LinearMachineResult:
    """Simulate the three axes under closed-loop control.

    Parameters
    ----------
    physics : LinearMachinePhysics
        Plant physics (``exact`` selects the estimators' own model).
    config : LinearServoConfig
        Controller and sensor settings.
    position_ref, velocity_ref, acceleration_ref : array_like, shape (3, n)
        Reference position [m], velocity [m/s] and acceleration [m/s^2] of
        x, y, z at the control instants.
    work_force : array_like, shape (3, n)
        Process force on the workpiece [N] (the axes, which carry the tool,
        feel minus it), at the control instants.
    normal_load : array_like, shape (3, n)
        Extra load on each axis's guides or screw nut [N] (raises its
        friction by the LuGre ``load_coefficient``).
    seed : int
        Seed of the noise generators.

    Returns
    -------
    LinearMachineResult
    """
    arrays = [np.ascontiguousarray(a, dtype=np.float64)
              for a in (position_ref, velocity_ref, acceleration_ref, work_force, normal_load)]
    if any(a.ndim != 2 or a.shape[0] != 3 or a.shape != arrays[0].shape for a in arrays):
        raise ConfigError("run_linear_machine: references, forces and loads must all have shape (3, n)")
    model = physics.model()
    masses = physics.moved_masses()
    axes = tuple(axis_params(physics.axis(a), physics.exact, masses[a],
                             masses[a] * 2.0 * math.pi * config.velocity_bandwidth_hz) for a in AXES)
    x_travel = physics.x.travel
    mp = MachineParams(
        fs=float(config.fs), substeps=int(config.substeps), position_gain=float(config.position_gain),
        integral_time=float(config.velocity_integral_time), feedforward_mass_ratio=float(config.feedforward_mass_ratio),
        current_noise=float(config.current_noise), current_sensor_noise=float(config.current_sensor_noise),
        current_resolution=float(config.current_resolution), scale_noise=float(config.scale_noise),
        scale_resolution=float(config.scale_resolution), yaw_coupling=float(physics.yaw_coupling),
        weight_shift_force=float(physics.weight_shift * (model.x.m + model.z.m) * _G),
        x_mid=float(0.5 * (x_travel[0] + x_travel[1])), exact=bool(physics.exact))
    out = _machine_loop(axes, mp, *arrays, np.int64(seed))
    return LinearMachineResult(*out)


@njit(cache=True)
def _cogging(p: AxisParams, exact: bool, s: float) -> float:
    """Cogging force [N] at ``s`` [m]: the model's table (exact) or harmonics varying along the travel."""
    if exact:
        return cogging_table_force(p.cogging_table, p.pole_pitch, s)
    pitch = p.pole_pitch
    scale = 1.0 + p.cogging_variation * math.sin(2.0 * math.pi * s / p.travel_length)
    f = 0.0
    for h in range(p.cogging_amplitude.size):
        f += p.cogging_amplitude[h] * math.sin(2.0 * math.pi * (h + 1) * s / pitch + p.cogging_phase[h])
    return scale * f


@njit(cache=True)
def _model_friction(p: AxisParams, v: float) -> float:
    """The estimators' static friction (Eq. 4) [N] at velocity ``v`` [m/s]."""
    f = p.friction
    sgn = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return sgn * (f.F_c + (f.F_s - f.F_c) * math.exp(-abs(v / f.v_s) ** p.delta)) + f.sigma2 * v


def _make_machine_loop(physics_source: str):
    """Compile the loop with its on-disk cache tied to ``physics_source`` (:mod:`drivesense.sim.kernel_cache`)."""

    @njit(cache=True)
    def _machine_loop(axes, mp, x_ref, v_ref, a_ref, f_work, n_load, seed):
        physics_source  # noqa: B018 -- part of numba's cache key (see drivesense.sim.kernel_cache)
        np.random.seed(seed)
        fs = mp.fs
        nsub = mp.substeps
        kp, ti, ff_ratio = mp.position_gain, mp.integral_time, mp.feedforward_mass_ratio
        i_noise, i_sens, i_res = mp.current_noise, mp.current_sensor_noise, mp.current_resolution
        x_noise, x_res = mp.scale_noise, mp.scale_resolution
        yaw, w_shift, x_mid = mp.yaw_coupling, mp.weight_shift_force, mp.x_mid
        exact = mp.exact
        T = 1.0 / fs
        dt = T / nsub
        n = x_ref.shape[1]
        o_x = np.zeros((3, n))
        o_v = np.zeros((3, n))
        o_a = np.zeros((3, n))
        o_i = np.zeros((3, n))
        t_x = np.zeros((3, n))
        t_v = np.zeros((3, n))
        t_a = np.zeros((3, n))
        t_i = np.zeros((3, n))
        x = np.empty(3)
        v = np.zeros(3)
        acc = np.zeros(3)
        zb = np.zeros(3)          # LuGre bristle deflection [m]
        i1 = np.zeros(3)
        i2 = np.zeros(3)
        integ = np.zeros(3)
        x_prev = np.empty(3)
        v_prev = np.zeros(3)
        i_ref = np.zeros(3)
        i_dist = np.zeros(3)
        fc = np.zeros(3)
        for a in range(3):
            x[a] = x_ref[a, 0]
            # start at rest in force balance with the restoring force, cogging and weight (integrator preloaded)
            p = axes[a]
            f0 = p.k * (x[a] - p.s_r) + _cogging(p, exact, x[a]) - p.weight
            integ[a] = f0
            i1[a] = f0 / p.K_m
            i2[a] = i1[a]
        for k in range(n):
            for a in range(3):
                p = axes[a]
                xm = quantise(x[a] + x_noise * np.random.standard_normal(), x_res)
                if k == 0:
                    x_prev[a] = xm
                vm = (xm - x_prev[a]) * fs
                am = (vm - v_prev[a]) * fs if k > 1 else 0.0
                x_prev[a] = xm
                v_prev[a] = vm
                i_now = i2[a] if (p.current_extra_pole > 0.0 and not exact) else i1[a]
                o_x[a, k] = xm
                o_v[a, k] = vm
                o_a[a, k] = am
                o_i[a, k] = quantise(i_now + i_sens * np.random.standard_normal(), i_res)
                # control: P position, PI velocity, velocity + acceleration feedforward
                v_cmd = v_ref[a, k] + kp * (x_ref[a, k] - xm)
                e = v_cmd - vm
                integ[a] += p.velocity_gain / ti * e * T
                f_cmd = p.velocity_gain * e + integ[a] + ff_ratio * p.mass * a_ref[a, k]
                ir = f_cmd / p.K_m
                if ir > p.max_current:
                    ir = p.max_current
                elif ir < -p.max_current:
                    ir = -p.max_current
                i_ref[a] = ir
                i_dist[a] = i_noise * np.random.standard_normal()
                load = n_load[a, k]
                if a == 1:
                    load += w_shift * abs(x[0] - x_mid)
                fc[a] = coulomb_level(p.friction, x[a], load) if p.lugre else p.friction.F_c
            f_now = np.empty(3)
            for a in range(3):
                f_now[a] = f_work[a, k]
            for j in range(nsub):
                frac = j / nsub
                for a in range(3):
                    p = axes[a]
                    f_next = f_work[a, k + 1] if k + 1 < n else f_now[a]
                    fw = f_now[a] + frac * (f_next - f_now[a])
                    # current loop: exact first order (+ second pole) over the sub-step, force from its start
                    w_cc = p.current_bandwidth
                    if exact:
                        i_act = i_ref[a]
                        i1[a] = i_ref[a]
                        i2[a] = i_ref[a]
                    else:
                        i_act = (i2[a] if p.current_extra_pole > 0.0 else i1[a]) + i_dist[a]
                        i1[a] = i_ref[a] + (i1[a] - i_ref[a]) * math.exp(-w_cc * dt)
                        if p.current_extra_pole > 0.0:
                            i2[a] = i1[a] + (i2[a] - i1[a]) * math.exp(-p.current_extra_pole * dt)
                    km = p.K_m * (1.0 - p.km_droop * (i_act / p.rated_current) ** 2)
                    f_cog = _cogging(p, exact, x[a])
                    f_rest = p.k * (x[a] - p.s_r)
                    if p.lugre:
                        zb[a], f_fr = lugre_step(p.friction, zb[a], v[a], fc[a], dt)
                    else:
                        f_fr = _model_friction(p, v[a])
                    f_net = km * i_act - f_cog - f_rest - f_fr - fw + p.weight
                    if a == 1 and not exact:
                        f_net += yaw * axes[0].mass * acc[0]
                    acc[a] = f_net / p.mass
                    if j == 0:
                        t_x[a, k] = x[a]
                        t_v[a, k] = v[a]
                        t_a[a, k] = acc[a]
                        t_i[a, k] = i_act
                for a in range(3):
                    v[a] += acc[a] * dt
                    x[a] += v[a] * dt
        return o_x, o_v, o_a, o_i, t_x, t_v, t_a, t_i

    return _machine_loop


_machine_loop = _make_machine_loop(source_digest(friction, encoders, linear_motor))


def nc_trace(result: LinearMachineResult, work_force, config: LinearServoConfig) -> tuple[dict, np.ndarray, float]:
    """Decimate the controller's values to the NC trace and the true force to the reference.

    Parameters
    ----------
    result : LinearMachineResult
        Output of :func:`run_linear_machine`.
    work_force : array_like, shape (3, n)
        True process force on the workpiece at the control rate [N].
    config : LinearServoConfig
        Trace settings (rate, logger filter, reference filter, true state).

    Returns
    -------
    channels : dict of str to ndarray
        ``{ax}_position`` [m], ``{ax}_velocity`` [m/s], ``{ax}_acceleration``
        [m/s^2], ``{ax}_current`` [A] and ``force_{ax}`` [N] at ``nc_rate``.
    index : ndarray
        Control-rate indices of the kept samples.
    delay : float
        Delay of the drive channels against the reference [s] (the logger's
        FIR delay).
    """
    q = config.decimation
    src = (result.true_position, result.true_velocity, result.true_acceleration, result.true_current) \
        if config.true_state else (result.position, result.velocity, result.acceleration, result.current)
    n = src[0].shape[1]
    index = np.arange(q - 1, n, q)
    out: dict[str, np.ndarray] = {}
    taps = config.logger_taps()
    for name, arr in zip(("position", "velocity", "acceleration", "current"), src):
        for i, ax in enumerate(AXES):
            sig = arr[i]
            if taps.size:   # causal FIR from rest at the first value, evaluated at the kept samples only
                padded = np.concatenate((np.full(taps.size - 1, sig[0]), sig))
                win = np.lib.stride_tricks.sliding_window_view(padded, taps.size)
                out[f"{ax}_{name}"] = win[index] @ taps[::-1]
            else:
                out[f"{ax}_{name}"] = np.ascontiguousarray(sig[index])
    fw = np.asarray(work_force, dtype=np.float64)
    ref_sos = sps.butter(config.reference_order, config.reference_cutoff_hz, fs=config.fs, output="sos") \
        if config.reference_order > 0 else None
    for i, ax in enumerate(AXES):
        f = fw[i]
        if ref_sos is not None:
            f = sps.sosfiltfilt(ref_sos, f)
        out[f"force_{ax}"] = np.ascontiguousarray(f[index])
    return out, index, (taps.size // 2) / config.fs if taps.size else 0.0
