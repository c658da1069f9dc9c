"""The ball-screw vertical machining centre running part programs, traced by its controller at 50-500 Hz.

The machine is :func:`drivesense.machine.vmc.vmc_physics` under the
compiled closed-loop control of :func:`drivesense.sim.linear_machine.run_linear_machine`
(4 kHz: P position loop, PI velocity loop with velocity and acceleration
feedforward, current loops); the programs and their forces are
:mod:`drivesense.sim.nc_programs`.

The trace, as an edge device records it (:func:`controller_trace`):

* the drive's own 500 Hz values are block means of the control-rate values
  over 2 ms (8 control periods);
* a trace at ``rate`` (500 Hz divided by a whole number, e.g. 50 Hz) is the
  500 Hz signal averaged over its interval and decimated;
* each value is stamped at the end of its interval, so the drive channels lag
  the instant they are stamped with by half the interval less half a control
  period (``meta["trace_delay_s"]``; 9.875 ms at 50 Hz, 0.875 ms at 500 Hz;
  the velocity and acceleration, backward differences at the control rate,
  another half and one control period).  The trace does not declare it
  (no ``nc_delay_s``): a real edge device does not;
* the controller logs the currents of X and Y with the opposite sign of
  their motor force, Z's as is (:attr:`VMCSettings.current_signs`), so the
  force constants *as logged* are ``-K_m``, ``-K_m``, ``+K_m``.

Cuts also carry the dynamometer reference ``force_{x,y,z}``: the true force
on the workpiece low-passed zero-phase (4th-order Butterworth at 0.4 times
the trace rate) and sampled at the trace instants, plus 1.5 N of noise.

Run-to-run structure: ``machine_seed`` draws one machine of the series
(:func:`~drivesense.machine.vmc.machine_variant`: friction, ripple, weight
and mass spread), the same for the air cut and every cut of a session;
``seed`` draws the run's noise, its 2 % friction variation and the spindle
phase.  ``ideal=True`` (:meth:`VMCSettings.as_ideal`): the nominal preset as
exactly the model (static Stribeck friction, the ripple table, no droop,
current-loop lag, coupling or variation), no noise or quantisation, block
means of the plant's true state, and the block means of the true force over
the same intervals as the reference (so ``trace_delay_s`` is 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal as sps

from drivesense.errors import ConfigError
from drivesense.machine.linear_motor import AXES, LinearMachinePhysics
from drivesense.machine.milling import CuttingCoefficients, EndMill
from drivesense.machine.vmc import machine_variant, vmc_physics
from drivesense.recording import Recording
from drivesense.sim.linear_machine import LinearMachineResult, LinearServoConfig, run_linear_machine
from drivesense.sim.machining import c45_coefficients
from drivesense.sim.nc_programs import DEFAULT_CUT, CutParameters, build_nc_program, nc_programs, program_forces

__all__ = ["VMCSettings", "vmc_servo", "block_means", "controller_trace", "true_model", "simulate_nc_program"]


def vmc_servo() -> LinearServoConfig:
    """The machining centre's controller: 4 kHz, ball-screw gains, motor-encoder and current-sensor noise.

    Position gain 30 1/s, velocity bandwidth 40 Hz, integral time 12 ms, 95 %
    acceleration feedforward; current disturbance 0.02 A and sensor noise
    0.02 A (1 mA resolution); encoder noise 5 nm with a 15 nm resolution
    (2^20 counts per 16 mm lead).

    Returns
    -------
    LinearServoConfig
        With ``nc_rate`` 500 Hz and neither logger filter nor reference filter
        (:func:`controller_trace` records the trace).
    """
    return LinearServoConfig(fs=4000.0, substeps=4, position_gain=30.0, velocity_bandwidth_hz=40.0,
                             velocity_integral_time=0.012, feedforward_mass_ratio=0.95, current_noise=0.02,
                             current_sensor_noise=0.02, current_resolution=1e-3, scale_noise=5e-9,
                             scale_resolution=15e-9, nc_rate=500.0, logger_delay=0.0, reference_order=0)


@dataclass(frozen=True)
class VMCSettings:
    """Machine, controller, trace, tool and spindle of the machining-centre simulation.

    Parameters
    ----------
    physics : LinearMachinePhysics
        Nominal machine (default :func:`~drivesense.machine.vmc.vmc_physics`).
    servo : LinearServoConfig
        Controller and sensors (default :func:`vmc_servo`).
    drive_rate : float
        Rate of the drive's own block means [Hz] (a whole fraction of the control rate).
    current_signs : tuple of float
        Sign the controller logs each axis's current with, relative to its
        motor force (x, y, z) [-].
    tool : EndMill
        12 mm, 4 flutes, 35 deg helix, 5 um runout.
    coefficients : CuttingCoefficients
        C45 steel (:func:`~drivesense.sim.machining.c45_coefficients`).
    spindle_kt : float
        Spindle motor torque constant [N*m/A].
    spindle_idle_current : float
        Spindle current at no load [A].
    spindle_droop : float
        Relative speed drop per newton metre of load [1/(N*m)].
    spindle_speed_noise : float
        Relative noise of the spindle speed [-].
    spindle_current_noise : float
        Noise of the spindle current [A].
    force_noise : float
        Noise of the dynamometer reference [N].
    reference_order : int
        Order of the zero-phase Butterworth of the reference (0: block means
        of the true force, as the ideal switch sets).
    reference_cutoff_ratio : float
        Its cut-off as a share of the trace rate [-] (below Nyquist: < 0.5).
    glitches_per_minute : float
        The edge logger's glitches seen on real traces [1/min] (0: none, the
        default): the spindle speed read across a wrap of its logged angle
        (hundreds of thousands of rpm backwards) and isolated current spikes on
        the axes, about a third each of speed and current.  Their truth is in
        ``meta["glitches"]``; ``--bad-samples repair`` mends them.
    ideal : bool
        Set by :meth:`as_ideal`.
    """

    physics: LinearMachinePhysics = field(default_factory=vmc_physics)
    servo: LinearServoConfig = field(default_factory=vmc_servo)
    drive_rate: float = 500.0
    current_signs: tuple[float, float, float] = (-1.0, -1.0, 1.0)
    tool: EndMill = field(default_factory=lambda: EndMill(12e-3, 4, 35.0, runout=5e-6, runout_phase=0.4))
    coefficients: CuttingCoefficients = field(default_factory=c45_coefficients)
    spindle_kt: float = 0.75
    spindle_idle_current: float = 6.0
    spindle_droop: float = 2.5e-4
    spindle_speed_noise: float = 1e-3
    spindle_current_noise: float = 0.05
    force_noise: float = 1.5
    reference_order: int = 4
    reference_cutoff_ratio: float = 0.4
    glitches_per_minute: float = 0.0
    ideal: bool = False

    def as_ideal(self) -> "VMCSettings":
        """The exact model, no noise, true-state block means, block-mean reference (the ideal switch).

        Returns
        -------
        VMCSettings
        """
        return replace(self, physics=self.physics.ideal(), servo=self.servo.as_ideal(), spindle_speed_noise=0.0,
                       spindle_current_noise=0.0, force_noise=0.0, reference_order=0, glitches_per_minute=0.0,
                       ideal=True)


def _logger_glitches(channels: dict, per_minute: float, rate: float, rng) -> list[dict]:
    """Write the logger's glitches into the trace (in place); their truth as ``{channel, sample, value}``."""
    n = channels["spindle_speed"].size
    count = int(rng.poisson(per_minute * n / rate / 60.0)) if per_minute > 0 else 0
    out = []
    for _ in range(count):
        i = int(rng.integers(2, n - 2))
        if rng.random() < 0.35:     # the angle wraps between two logged samples: the speed reads a huge step back
            ch, value = "spindle_speed", float(-rng.uniform(2e5, 4e5))
        else:
            ch = f"{AXES[int(rng.integers(3))]}_current"
            spread = max(float(np.ptp(channels[ch])), 1.0)
            value = float(channels[ch][i] + rng.choice([-1.0, 1.0]) * rng.uniform(8.0, 15.0) * spread)
        channels[ch][i] = value
        out.append({"channel": ch, "sample": i, "value": value})
    return out


def block_means(x: np.ndarray, q: int) -> np.ndarray:
    """Means of consecutive blocks of ``q`` samples along the last axis (an incomplete last block dropped).

    Parameters
    ----------
    x : ndarray
        Samples along the last axis [any unit].
    q : int
        Block length.

    Returns
    -------
    ndarray
        One mean per block (unit of ``x``).
    """
    nb = x.shape[-1] // q
    return x[..., :nb * q].reshape(*x.shape[:-1], nb, q).mean(axis=-1)


def _ratio(a: float, b: float, what: str) -> int:
    r = a / b
    if not (math.isfinite(r) and r >= 1 and abs(r - round(r)) < 1e-9):
        raise ConfigError(f"{what}: {a:g} Hz / {b:g} Hz = {r:g} must be a whole number >= 1")
    return int(round(r))


def controller_trace(result: LinearMachineResult, rate: float, settings: VMCSettings,
                     extra: dict[str, np.ndarray] | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The drive's 500 Hz block means, averaged again and decimated to ``rate``.

    Parameters
    ----------
    result : LinearMachineResult
        Control-rate values of :func:`~drivesense.sim.linear_machine.run_linear_machine`
        (the plant's true state with ``settings.servo.true_state``).
    rate : float
        Trace rate [Hz]; the drive rate divided by a whole number.
    settings : VMCSettings
        Control and drive rates, logged current signs.
    extra : dict of str to ndarray, optional
        More control-rate signals to trace the same way [their own units] (e.g. the spindle's).

    Returns
    -------
    channels : dict of str to ndarray
        ``{ax}_position`` [m], ``{ax}_velocity`` [m/s], ``{ax}_acceleration``
        [m/s^2], ``{ax}_current`` [A] (as logged) and ``extra``, at ``rate``.
    index : ndarray of int
        Control-rate index of the last sample in each trace interval (the
        instant each value is stamped with).
    """
    fs = settings.servo.fs
    q1 = _ratio(fs, settings.drive_rate, "control rate / drive rate")
    q2 = _ratio(settings.drive_rate, rate, "drive rate / trace rate")
    src = (result.true_position, result.true_velocity, result.true_acceleration, result.true_current) \
        if settings.servo.true_state else (result.position, result.velocity, result.acceleration, result.current)
    signs = np.asarray(settings.current_signs, dtype=float)[:, None]
    out: dict[str, np.ndarray] = {}
    for name, arr in zip(("position", "velocity", "acceleration", "current"), src):
        arr = arr * signs if name == "current" else arr
        drive = block_means(arr, q1)
        trace = block_means(drive, q2) if q2 > 1 else drive
        for i, ax in enumerate(AXES):
            out[f"{ax}_{name}"] = np.ascontiguousarray(trace[i])
    for name, arr in (extra or {}).items():
        drive = block_means(np.asarray(arr, dtype=float), q1)
        out[name] = block_means(drive, q2) if q2 > 1 else drive
    nb = out["x_position"].size
    return out, (np.arange(nb) + 1) * q1 * q2 - 1


def true_model(physics: LinearMachinePhysics, current_signs=(-1.0, -1.0, 1.0)) -> dict:
    """The true controller-level parameters of a machine, per axis, with the force constant as logged.

    Parameters
    ----------
    physics : LinearMachinePhysics
        The machine as simulated (after its variation).
    current_signs : sequence of float
        Sign each axis's current is logged with (x, y, z) [-].

    Returns
    -------
    dict
        ``{ax: {K_m [N/A] as logged, K_m_motor [N/A], mass [kg] moved,
        own_mass [kg], reflected_mass [kg], weight [N] along +axis,
        holding_current [A] as logged (= -weight / K_m), F_C, F_br [N], v_s
        [m/s], sigma [N s/m], ripple_period [m], ripple [[amplitude N, phase
        rad], ...], load_coefficient [-]}}`` and ``carries``.
    """
    masses = physics.moved_masses()
    out: dict = {"carries": {a: list(physics.carries[a]) for a in AXES}}
    for sign, ax in zip(current_signs, AXES):
        a = physics.axis(ax)
        md = a.model
        km_logged = float(sign) * md.K_m
        out[ax] = {"K_m": km_logged, "K_m_motor": md.K_m, "mass": masses[ax], "own_mass": md.m,
                   "reflected_mass": a.reflected_mass, "weight": a.weight,
                   "holding_current": -a.weight / km_logged, "F_C": md.F_C, "F_br": md.F_br, "v_s": md.v_s,
                   "sigma": md.sigma, "ripple_period": md.pole_pitch,
                   "ripple": [[float(amp), float(ph)] for amp, ph in a.cogging_harmonics],
                   "load_coefficient": 0.0 if physics.exact or a.friction is None else a.friction.load_coefficient}
    return out


def _check(value, name: str, unit: str, upper: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or not 0 < value <= upper:
        raise ConfigError(f"NC program parameter '{name}' must be in (0, {upper:g}] {unit}, got {value!r}")
    return float(value)


def simulate_nc_program(program: str, *, rate: float = 50.0, air: bool = False, seed: int = 0, machine_seed: int = 0,
                        ideal: bool = False, a_p: float = DEFAULT_CUT.a_p, a_e: float = DEFAULT_CUT.a_e,
                        v_f: float = DEFAULT_CUT.v_f, n: float = DEFAULT_CUT.n,
                        settings: VMCSettings | None = None) -> Recording:
    """Run a part program on the machining centre and record the controller's trace.

    Parameters
    ----------
    program : str
        One of :func:`~drivesense.sim.nc_programs.nc_programs`.
    rate : float
        Trace rate [Hz]: 500 Hz divided by a whole number (50, 100, 250, 500).
    air : bool
        A dry run: the same moves, spindle on, no cutting force (the air cut
        recorded before the cuts); the trace has no force channels.
    seed : int
        Seed of the run: noise, 2 % friction variation, spindle phase.
    machine_seed : int
        Seed of the machine of the series (the same for a session's air cut and cuts).
    ideal : bool
        The exact model without noise (:meth:`VMCSettings.as_ideal`).
    a_p : float
        Axial depth of cut per level [m].
    a_e : float
        Radial depth of cut (stepover) [m].
    v_f : float
        Feed speed [m/s].
    n : float
        Spindle speed [min^-1].
    settings : VMCSettings, optional
        Machine, controller, tool (default :class:`VMCSettings`).

    Returns
    -------
    Recording
        At ``rate``: ``{x,y,z}_position`` [m], ``{x,y,z}_velocity`` [m/s],
        ``{x,y,z}_acceleration`` [m/s^2], ``{x,y,z}_current`` [A] (as
        logged), ``spindle_speed`` [rad/s], ``spindle_current`` [A]; cuts
        also ``force_{x,y,z}`` [N] on the workpiece.  Metadata: the program
        and its parameters, ``true_model`` (:func:`true_model`),
        ``trace_delay_s``, ``averaging_window_s``, ``current_signs``, the
        rates; no ``nc_delay_s``.
    """
    settings = settings or VMCSettings()
    if ideal:
        settings = settings.as_ideal()
    if not isinstance(program, str) or program not in nc_programs():
        raise ConfigError(f"unknown NC program {program!r}; known: {', '.join(nc_programs())}")
    rate = _check(rate, "rate", "Hz", settings.drive_rate)
    cut = CutParameters(_check(a_p, "a_p", "m", 0.01), _check(a_e, "a_e", "m", settings.tool.diameter),
                        _check(v_f, "v_f", "m/s", 0.1), _check(n, "n", "min^-1", 30000.0))
    cfg = settings.servo
    fs = cfg.fs
    prog = build_nc_program(program, cut, settings.tool, fs)
    t, pos, vel, acc = prog.path.build(0.0)
    rng = np.random.default_rng(seed)
    omega = cut.n * 2 * math.pi / 60.0
    angle = omega * t + rng.uniform(0, 2 * math.pi)
    if air:
        force, torque = np.zeros((3, t.size)), np.zeros(t.size)
    else:
        force, torque = program_forces(prog, t, pos, vel, angle, settings.tool, settings.coefficients, fs)
    if settings.ideal:
        physics = settings.physics
    else:
        physics = machine_variant(settings.physics, np.random.default_rng(machine_seed)).varied(rng)
    f_abs = np.abs(force)       # nut load: the axis's own force; guides: a tenth of the other two
    load = f_abs + 0.1 * (f_abs.sum(axis=0) - f_abs)
    res = run_linear_machine(physics, cfg, pos, vel, acc, force, load, seed=int(rng.integers(2 ** 31)))
    spindle_speed = omega * (1.0 - settings.spindle_droop * torque)
    spindle_current = settings.spindle_idle_current + torque / settings.spindle_kt
    if settings.spindle_speed_noise > 0:
        spindle_speed = spindle_speed * (1.0 + settings.spindle_speed_noise * rng.standard_normal(t.size))
    if settings.spindle_current_noise > 0:
        spindle_current = spindle_current + settings.spindle_current_noise * rng.standard_normal(t.size)
    channels, index = controller_trace(res, rate, settings, {"spindle_speed": spindle_speed,
                                                             "spindle_current": spindle_current})
    window = (index[0] + 1) / fs
    if settings.reference_order > 0:
        sos = sps.butter(settings.reference_order, settings.reference_cutoff_ratio * rate, fs=fs, output="sos")
        reference = f"zero-phase {settings.reference_order}th-order Butterworth " \
                    f"{settings.reference_cutoff_ratio * rate:g} Hz, sampled at the trace instants, " \
                    f"+ {settings.force_noise:g} N noise"
        delay = (index[0] / 2.0) / fs
    else:
        sos = None
        reference = "block means of the true force over the trace intervals"
        delay = 0.0
    if not air:
        for i, ax in enumerate(AXES):
            if sos is None:
                f = block_means(force[i], index[0] + 1)
            else:
                f = sps.sosfiltfilt(sos, force[i])[index] + settings.force_noise * rng.standard_normal(index.size)
            channels[f"force_{ax}"] = f
    glitches = _logger_glitches(channels, settings.glitches_per_minute, rate, rng)
    moving = [a for i, a in enumerate(AXES) if np.ptp(pos[i]) > 1e-4]
    meta = {"name": f"vmc_{'air_' if air else ''}{program}_ap{cut.a_p * 1e3:g}_ae{cut.a_e * 1e3:g}"
                    f"_vf{cut.v_f * 60e3:g}_n{cut.n:g}_{rate:g}Hz",
            "machine": "vmc", "program": program, "kind": "air" if air else "cut", "a_p_m": cut.a_p,
            "a_e_m": cut.a_e, "v_f_m_s": cut.v_f, "n_rpm": cut.n, "seed": int(seed), "machine_seed": int(machine_seed),
            "rate_hz": rate, "control_rate_hz": fs, "drive_rate_hz": settings.drive_rate,
            "averaging_window_s": window, "trace_delay_s": delay,
            "current_signs": {a: float(s) for a, s in zip(AXES, settings.current_signs)},
            "true_model": true_model(physics, settings.current_signs), "moving_axes": moving,
            "tool": {"diameter_m": settings.tool.diameter, "flutes": settings.tool.flutes},
            "physics": "ideal (the exact model: static Stribeck friction, ripple table, no droop, lag, coupling, "
                       "variation or noise; block means of the true state)" if settings.ideal else
                       "full (LuGre friction with presliding/stiction, ripple, drift and nut load, ripple harmonics "
                       "varying along the travel, K_m droop, current-loop lag, yaw coupling, noise, quantisation, "
                       "machine spread and run-to-run variation)",
            "reference_filter": None if air else reference, "glitches": glitches,
            "provenance": [f"drivesense.sim.vmc {program} seed {seed} machine_seed {machine_seed}"]}
    return Recording.from_arrays(channels, fs=rate, t0=float(t[index[0]]), meta=meta)
