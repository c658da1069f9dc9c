"""Closed-loop control of the three linear-motor axes (compiled) and the NC trace it records.

Control runs at ``fs`` (4 kHz by default) for each axis: a P position loop
on the linear scale with velocity feedforward, a PI velocity loop on the
scale's differentiated position with acceleration feedforward, and a current
reference to the current loop (first order, plus a second pole in the full
physics).  The plant (motor force with droop, cogging, restoring force,
LuGre friction, process force, yaw coupling; masses stacked as in Eq. 2) is
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
the reference is not aliased.  With ``LinearServoConfig.as_ideal()`` the trace holds point samples
of the plant's true state and the unfiltered true force instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit
from scipy import signal as sps

from drivesense.errors import ConfigError
from drivesense.machine.linear_motor import AXES, LinearMachinePhysics, cogging_table_force

__all__ = ["LinearServoConfig", "LinearMachineResult", "run_linear_machine", "nc_trace"]

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
        Velocity-loop bandwidth [Hz]; the P gain is the nominal stacked mass
        times ``2 pi`` this [N/(m/s)].
    velocity_integral_time : float
        Integral time of the velocity PI [s].
    feedforward_mass_ratio : float
        Acceleration feedforward with this share of the nominal stacked mass [-].
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
        """No noise, no quantisation, point samples of the true state and the unfiltered true force."""
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


def _pack_axes(physics: LinearMachinePhysics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rows = [physics.axis(a).pack(physics.exact) for a in AXES]
    width = max(r.size for r in rows)
    packed = np.zeros((3, width))
    for i, r in enumerate(rows):
        packed[i, :r.size] = r
    tables = [physics.axis(a).model.cogging for a in AXES]
    tab = np.zeros((3, max(t.size for t in tables)))
    sizes = np.zeros(3, dtype=np.int64)
    for i, t in enumerate(tables):
        tab[i, :t.size] = t
        sizes[i] = t.size
    return packed, tab, sizes


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
        Extra normal load on each axis's guides [N] (raises its friction).
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
    packed, tables, sizes = _pack_axes(physics)
    model = physics.model()
    masses = model.stacked_masses()
    mass = np.array([masses[a] for a in AXES])
    kvp = mass * 2.0 * math.pi * config.velocity_bandwidth_hz
    x_travel = physics.x.travel
    ctrl = np.array([config.fs, float(config.substeps), config.position_gain, config.velocity_integral_time,
                     config.feedforward_mass_ratio, config.current_noise, config.current_sensor_noise,
                     config.current_resolution, config.scale_noise, config.scale_resolution,
                     physics.yaw_coupling, physics.weight_shift * (model.x.m + model.z.m) * _G,
                     0.5 * (x_travel[0] + x_travel[1]), 1.0 if physics.exact else 0.0], dtype=np.float64)
    out = _machine_loop(packed, tables, sizes, mass, kvp, ctrl, *arrays, np.int64(seed))
    return LinearMachineResult(*out)


@njit(cache=True)
def _quantise(value: float, step: float) -> float:
    if step > 0.0:
        return math.floor(value / step + 0.5) * step
    return value


@njit(cache=True)
def _cogging(p: np.ndarray, table: np.ndarray, exact: bool, s: float) -> float:
    if exact:
        return cogging_table_force(table, p[3], s)
    pitch = p[3]
    nh = int(p[19])
    scale = 1.0 + p[17] * math.sin(2.0 * math.pi * s / p[18])
    f = 0.0
    for h in range(nh):
        f += p[22 + 2 * h] * math.sin(2.0 * math.pi * (h + 1) * s / pitch + p[23 + 2 * h])
    return scale * f


@njit(cache=True)
def _coulomb(p: np.ndarray, s: float, load: float) -> float:
    """Coulomb level [N] with drift, ripple and load (full physics)."""
    level = p[4] + p[10] * s + p[11] * load
    nh = int(p[19])
    base = 22 + 2 * nh
    for r in range(int(p[20])):
        level += p[base + 3 * r + 1] * math.sin(2.0 * math.pi * s / p[base + 3 * r] + p[base + 3 * r + 2])
    return level if level > 0.0 else 0.0


@njit(cache=True)
def _machine_loop(packed, tables, sizes, mass, kvp, ctrl, x_ref, v_ref, a_ref, f_work, n_load, seed):
    np.random.seed(seed)
    fs = ctrl[0]
    nsub = int(ctrl[1])
    kp, ti, ff_ratio = ctrl[2], ctrl[3], ctrl[4]
    i_noise, i_sens, i_res, x_noise, x_res = ctrl[5], ctrl[6], ctrl[7], ctrl[8], ctrl[9]
    yaw, w_shift, x_mid = ctrl[10], ctrl[11], ctrl[12]
    exact = ctrl[13] > 0.5
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
        # start at rest in force balance with the restoring force and cogging (integrator preloaded)
        p = packed[a]
        f0 = p[1] * (x[a] - p[2]) + _cogging(p, tables[a, :sizes[a]], exact, x[a])
        integ[a] = f0
        i1[a] = f0 / p[0]
        i2[a] = i1[a]
    for k in range(n):
        for a in range(3):
            p = packed[a]
            xm = _quantise(x[a] + x_noise * np.random.standard_normal(), x_res)
            if k == 0:
                x_prev[a] = xm
            vm = (xm - x_prev[a]) * fs
            am = (vm - v_prev[a]) * fs if k > 1 else 0.0
            x_prev[a] = xm
            v_prev[a] = vm
            i_now = i2[a] if (p[16] > 0.0 and not exact) else i1[a]
            o_x[a, k] = xm
            o_v[a, k] = vm
            o_a[a, k] = am
            o_i[a, k] = _quantise(i_now + i_sens * np.random.standard_normal(), i_res)
            # control: P position, PI velocity, velocity + acceleration feedforward
            v_cmd = v_ref[a, k] + kp * (x_ref[a, k] - xm)
            e = v_cmd - vm
            integ[a] += kvp[a] / ti * e * T
            f_cmd = kvp[a] * e + integ[a] + ff_ratio * mass[a] * a_ref[a, k]
            ir = f_cmd / p[0]
            if ir > p[14]:
                ir = p[14]
            elif ir < -p[14]:
                ir = -p[14]
            i_ref[a] = ir
            i_dist[a] = i_noise * np.random.standard_normal()
            load = n_load[a, k]
            if a == 1:
                load += w_shift * abs(x[0] - x_mid)
            fc[a] = _coulomb(p, x[a], load) if not exact else p[4]
        f_now = np.empty(3)
        for a in range(3):
            f_now[a] = f_work[a, k]
        for j in range(nsub):
            frac = j / nsub
            for a in range(3):
                p = packed[a]
                f_next = f_work[a, k + 1] if k + 1 < n else f_now[a]
                fw = f_now[a] + frac * (f_next - f_now[a])
                # current loop: exact first order (+ second pole) over the sub-step, force from its start
                w_cc = p[15]
                if exact:
                    i_act = i_ref[a]
                    i1[a] = i_ref[a]
                    i2[a] = i_ref[a]
                else:
                    i_act = (i2[a] if p[16] > 0.0 else i1[a]) + i_dist[a]
                    i1[a] = i_ref[a] + (i1[a] - i_ref[a]) * math.exp(-w_cc * dt)
                    if p[16] > 0.0:
                        i2[a] = i1[a] + (i2[a] - i1[a]) * math.exp(-p[16] * dt)
                km = p[0] * (1.0 - p[12] * (i_act / p[13]) ** 2)
                f_cog = _cogging(p, tables[a, :sizes[a]], exact, x[a])
                f_rest = p[1] * (x[a] - p[2])
                va = v[a]
                if exact:
                    sgn = 1.0 if va > 0.0 else (-1.0 if va < 0.0 else 0.0)
                    f_fr = sgn * (p[4] + (p[5] - p[4]) * math.exp(-abs(va / p[6]) ** p[21])) + p[7] * va
                else:
                    g = fc[a] + (p[5] - p[4]) * math.exp(-(va / p[6]) ** 2)
                    if g < 1e-9:
                        g = 1e-9
                    z_old = zb[a]
                    if va != 0.0:
                        z_ss = g / p[8] * (1.0 if va > 0.0 else -1.0)
                        zb[a] = z_ss + (z_old - z_ss) * math.exp(-p[8] * abs(va) * dt / g)
                    f_fr = p[8] * zb[a] + p[9] * (zb[a] - z_old) / dt + p[7] * va
                f_net = km * i_act - f_cog - f_rest - f_fr - fw
                if a == 1 and not exact:
                    f_net += yaw * mass[0] * acc[0]
                acc[a] = f_net / mass[a]
                if j == 0:
                    t_x[a, k] = x[a]
                    t_v[a, k] = v[a]
                    t_a[a, k] = acc[a]
                    t_i[a, k] = i_act
            for a in range(3):
                v[a] += acc[a] * dt
                x[a] += v[a] * dt
    return o_x, o_v, o_a, o_i, t_x, t_v, t_a, t_i


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
