"""Milling processes and air moves on the 3-axis linear-motor machine (third paper, Sec. 2.1, 3).

Processes (:func:`process_names`): grooves (slots, ``a_e = D``) and side
milling (up milling, material on the left of the feed) in +-x, +-y and the
four diagonals at constant feed; a circular pocket, counter-clockwise (climb
milling) or clockwise (up milling), each a plunge entry, then one lap at radial
engagement ``a_e`` (X and Y reverse continuously; the radius is
:attr:`ProcessSettings.pocket_radius`); a ramp
(-y with +z, ``a_p`` growing from 0 to its value).  Every move starts and
ends at rest, so each trace holds accelerations; the workpiece is fixed on
the table and the axes carry the tool.

Forces come from :func:`drivesense.machine.milling.milling_forces` in the
tool frame (x along the tool's motion relative to the workpiece, y = z x x,
z the tool axis), are rotated into machine axes along the path and applied to
the axes with opposite sign; ``force_{ax}`` in the trace is the force on the
workpiece, as a table-mounted dynamometer reads it.  A trace ends with the
tool leaving the material (superposition of an entry at the far edge).

The ideal-physics switch is :meth:`ProcessSettings.as_ideal` (``ideal=True``
on :func:`simulate_process` and :func:`simulate_air_moves` routes to it):
data from exactly the ModelBased model -- static Stribeck friction, the
model's cogging table, no droop, current-loop lag, coupling, weight shift or
run-to-run variation, no noise or quantisation, point samples of the true
state and the unfiltered true force.  The ball-screw simulator has the same
switch (:meth:`drivesense.sim.scenarios.ScenarioSettings.as_ideal`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from drivesense.errors import ConfigError
from drivesense.machine.linear_motor import AXES, LinearMachinePhysics, linear_machine_physics
from drivesense.machine.milling import CuttingCoefficients, EndMill, MillingCut, milling_forces
from drivesense.recording import Recording
from drivesense.sim.cutting import plunge_load, straight_cut_forces, workpiece_force
from drivesense.sim.linear_machine import LinearServoConfig, nc_trace, run_linear_machine
from drivesense.sim.toolpath import ToolpathProgram

__all__ = ["ProcessSettings", "process_names", "process_run_name", "POCKETS", "table1_process_grid", "simulate_process", "simulate_air_moves",
           "c45_coefficients"]

#: Circular pockets: name -> (sense of the lap, +1 counter-clockwise; milling mode with a right-hand spindle).
POCKETS = {"pocket_ccw": (1, "down"), "pocket_cw": (-1, "up")}
_DIRS = {"+x": (1, 0), "-x": (-1, 0), "+y": (0, 1), "-y": (0, -1),
         "+x+y": (1, 1), "+x-y": (1, -1), "-x+y": (-1, 1), "-x-y": (-1, -1)}


def c45_coefficients() -> CuttingCoefficients:
    """Cutting coefficients assumed for C45 steel with a carbide end mill (not from the paper).

    ``Ktc = 1800 N/mm^2``, ``Krc = 720``, ``Kac = 300``, ``Kte = 25 N/mm``,
    ``Kre = 35``, ``Kae = 8``, in SI.

    Returns
    -------
    CuttingCoefficients
    """
    return CuttingCoefficients(Ktc=1800e6, Krc=720e6, Kac=300e6, Kte=25e3, Kre=35e3, Kae=8e3)


@dataclass(frozen=True)
class ProcessSettings:
    """Everything about a simulated process that is not its name and cutting parameters.

    Parameters
    ----------
    physics : LinearMachinePhysics
        Machine physics (default: the full physics of the preset).
    servo : LinearServoConfig
        Controller, sensors and NC trace.
    tool : EndMill
        The paper's tool: 10 mm, 4 flutes, 36.5 deg (mean of 38/35), 5 um runout.
    coefficients : CuttingCoefficients
        C45 steel (assumed).
    cut_length : float
        Length of material along a straight path [m] (two pole pitches).
    pocket_radius : float
        Radius of the pocket's tool-centre path [m].
    ramp_slope : float
        Rise of the ramp's path in z per metre along -y [-].
    ramp_time : float
        Duration of each raised-cosine velocity ramp [s].
    air_time : float
        Cruise time in air before the tool touches the material [s].
    settle : float
        Time after the end of the acceleration excluded from scoring [s].
    spindle_kt : float
        Spindle motor torque constant [N*m/A].
    spindle_idle_current : float
        Spindle current at no load [A].
    ideal : bool
        Set by :meth:`as_ideal`: the simulation draws no run-to-run variation
        (the rest of the ideal physics is in the physics and servo that
        :meth:`as_ideal` reduces).
    """

    physics: LinearMachinePhysics = field(default_factory=linear_machine_physics)
    servo: LinearServoConfig = field(default_factory=LinearServoConfig)
    tool: EndMill = field(default_factory=lambda: EndMill(10e-3, 4, 36.5, runout=5e-6, runout_phase=0.8))
    coefficients: CuttingCoefficients = field(default_factory=c45_coefficients)
    cut_length: float = 0.046
    pocket_radius: float = 0.015
    ramp_slope: float = 0.05
    ramp_time: float = 0.1
    air_time: float = 0.6
    settle: float = 0.3
    spindle_kt: float = 0.6
    spindle_idle_current: float = 2.5
    ideal: bool = False

    def as_ideal(self) -> "ProcessSettings":
        """Settings that reproduce the ModelBased model exactly (the ideal-physics switch).

        The physics reduced to the model (:meth:`LinearMachinePhysics.ideal
        <drivesense.machine.linear_motor.LinearMachinePhysics.ideal>`), the
        servo without noise, quantisation or trace filters
        (:meth:`LinearServoConfig.as_ideal
        <drivesense.sim.linear_machine.LinearServoConfig.as_ideal>`), no
        run-to-run variation (``ideal``).

        Returns
        -------
        ProcessSettings
        """
        return replace(self, physics=self.physics.ideal(), servo=self.servo.as_ideal(), ideal=True)


def process_names() -> list[str]:
    """Names accepted by :func:`simulate_process`.

    Returns
    -------
    list of str
        ``groove_{dir}`` and ``side_{dir}`` for dir in +x, -x, +y, -y, +x+y,
        +x-y, -x+y, -x-y; ``pocket_ccw``, ``pocket_cw``; ``ramp_-y+z``.
    """
    return [f"groove_{d}" for d in _DIRS] + [f"side_{d}" for d in _DIRS] + list(POCKETS) + ["ramp_-y+z"]


def process_run_name(process: str, a_p: float, a_e: float, v_f: float, n: float, *, air: bool = False,
                     pocket_radius: float | None = None) -> str:
    """File-friendly name of one run, in the units of the paper's Table 1.

    Parameters
    ----------
    process, a_p, a_e, v_f, n
        As for :func:`simulate_process`: process type, depths of cut [m], feed speed [m/s] and
        spindle speed [min^-1] (named in mm, mm/min and min^-1).
    air : bool
        An air cut (``air_`` prefix).
    pocket_radius : float, optional
        A pocket's radius [m]; named (``_r{mm}``) only when it differs from the
        default :attr:`ProcessSettings.pocket_radius`.

    Returns
    -------
    str
        e.g. ``"pocket_cw_ap2_ae2_vf500_n3500_r22"``.
    """
    name = f"{'air_' if air else ''}{process}_ap{a_p * 1e3:g}_ae{a_e * 1e3:g}_vf{v_f * 60e3:g}_n{n:g}"
    if pocket_radius is not None and abs(pocket_radius - ProcessSettings.pocket_radius) > 1e-9:
        name += f"_r{pocket_radius * 1e3:g}"
    return name


def table1_process_grid() -> dict[str, list[float]]:
    """The third paper's Table 1 process grid in SI (``n`` in min^-1).

    Returns
    -------
    dict
        ``a_p`` [m], ``a_e`` [m], ``v_f`` [m/s], ``n`` [min^-1] -> list of values.
    """
    return {"a_p": [v * 1e-3 for v in (1, 2, 3, 4)], "a_e": [v * 1e-3 for v in (1, 2, 4, 5, 7, 10)],
            "v_f": [v / 60e3 for v in (300, 400, 500, 700, 800)], "n": [2600.0, 3500.0, 4500.0, 5400.0, 6000.0]}


# ------------------------------------------------------------------ paths
def _centre(physics: LinearMachinePhysics) -> np.ndarray:
    return np.array([0.5 * sum(physics.axis(a).travel) for a in AXES])


# ------------------------------------------------------------------ forces
def _process(name: str, a_p: float, a_e: float, v_f: float, settings: ProcessSettings, angle_fn, rng):
    """Reference trajectory, workpiece force (3, n), spindle torque and scoring window."""
    tool = settings.tool
    fs = settings.servo.fs
    centre = _centre(settings.physics)
    d_half = 0.5 * tool.diameter
    kind, _, direction = name.partition("_")
    if kind in ("groove", "side"):
        dx, dy = _DIRS[direction]
        norm = math.hypot(dx, dy)
        dx, dy = dx / norm, dy / norm
        approach = v_f * (settings.ramp_time / 2 + settings.air_time) + d_half
        total = approach + settings.cut_length + d_half + v_f * 0.4
        start = centre - np.array([dx, dy, 0.0]) * total / 2
        prog = ToolpathProgram(start, fs)
        prog.dwell(0.3)
        t0, t_dec, _ = prog.line(np.array([dx, dy, 0.0]) * total, v_f, settings.ramp_time)
        t, pos, vel, acc = prog.build(0.3)
        along = (pos[0] - start[0]) * dx + (pos[1] - start[1]) * dy
        speed = vel[0] * dx + vel[1] * dy
        ae = tool.diameter if kind == "groove" else a_e
        cut = MillingCut(ae, a_p, "up", axial_slices=8)
        angle = angle_fn(t)
        fe, fn, fa, tq = straight_cut_forces(tool, settings.coefficients, cut, angle, speed,
                                             along - (approach - d_half) - d_half, settings.cut_length, fs)
        force = workpiece_force(fe, fn, fa, dx, dy)
        window = (t0 + settings.ramp_time + settings.settle, t_dec)
        return t, pos, vel, acc, force, tq, window
    if name in POCKETS:
        turn, mode = POCKETS[name]
        r = settings.pocket_radius
        start = centre + np.array([r, 0.0, 0.003])
        prog = ToolpathProgram(start, fs)
        prog.dwell(0.3)
        plunge_v = v_f / 3
        t_pl, _, t_pl_end = prog.line(np.array([0.0, 0.0, -(0.003 + a_p)]), plunge_v, settings.ramp_time)
        prog.dwell(0.2)
        t_arc, t_arc_dec, _ = prog.arc(np.array([-r, 0.0, 0.0]), turn * 2 * math.pi, v_f, settings.ramp_time)
        prog.dwell(0.2)
        prog.line(np.array([0.0, 0.0, 0.003 + a_p]), 3 * v_f, settings.ramp_time)
        t, pos, vel, acc = prog.build(0.3)
        angle = angle_fn(t)
        # plunge (drilling) thrust while the tip is below the surface and feeding down
        depth = np.clip(start[2] - 0.003 - pos[2], 0.0, None)
        omega = np.gradient(angle) * fs
        c_z = 2 * math.pi * np.clip(-vel[2], 0.0, None) / (tool.flutes * np.maximum(omega, 1e-9))
        engaged = np.clip(depth / 0.3e-3, 0.0, 1.0) * (c_z > 0)
        thrust, torque_pl = plunge_load(tool, settings.coefficients, c_z, engaged)
        # milling along the circle (tangent d = turn (-sin th, cos th)); engagement from the end of the plunge;
        # the material lies outside the lap: right of the feed counter-clockwise (climb), left clockwise (up)
        in_arc = t >= t_arc
        th = np.arctan2(pos[1] - centre[1], pos[0] - centre[0])
        dx, dy = -turn * np.sin(th), turn * np.cos(th)
        speed = np.hypot(vel[0], vel[1])
        omega_s = np.maximum(omega, 1e-9)
        c = 2 * math.pi * speed / (tool.flutes * omega_s)
        mf = milling_forces(tool, settings.coefficients, MillingCut(a_e, a_p, mode, axial_slices=8), angle, c)
        on = in_arc & (t < t_arc_dec + settings.ramp_time)
        force = workpiece_force(mf.feed * on, mf.normal * on, mf.axial * on, dx, dy)
        force[2] -= thrust
        window = (t_pl + settings.settle, t_arc_dec + settings.ramp_time)
        return t, pos, vel, acc, force, mf.torque * on + torque_pl, window
    if name == "ramp_-y+z":
        slope = settings.ramp_slope
        dvec = np.array([0.0, -1.0, slope]) / math.hypot(1.0, slope)
        approach = v_f * (settings.ramp_time / 2 + settings.air_time)
        total = approach + settings.cut_length + d_half + v_f * 0.4
        start = centre - dvec * total / 2
        prog = ToolpathProgram(start, fs)
        prog.dwell(0.3)
        t0, t_dec, _ = prog.line(dvec * total, v_f, settings.ramp_time)
        t, pos, vel, acc = prog.build(0.3)
        along = (pos[1] - start[1]) * dvec[1] + (pos[2] - start[2]) * dvec[2]
        speed = vel[1] * dvec[1] + vel[2] * dvec[2]
        angle = angle_fn(t)
        cut = MillingCut(a_e, a_p, "down", axial_slices=8)
        fe, fn, fa, tq = straight_cut_forces(tool, settings.coefficients, cut, angle, speed, along - approach + d_half,
                                             settings.cut_length, fs)
        depth = np.clip((along - approach) / settings.cut_length, 0.0, 1.0)
        force = workpiece_force(fe * depth, fn * depth, fa * depth, 0.0, -1.0)
        window = (t0 + settings.ramp_time + settings.settle, t_dec)
        return t, pos, vel, acc, force, tq * depth, window
    raise ConfigError(f"unknown process {name!r}; known: {', '.join(process_names())}")


def _check_param(value, name: str, unit: str, upper: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or not 0 < value <= upper:
        raise ConfigError(f"process parameter '{name}' must be in (0, {upper:g}] {unit}, got {value!r}")
    return float(value)


def _record(settings, physics, t, pos, vel, acc, force, load, seed, meta, spindle=None) -> Recording:
    cfg = settings.servo
    res = run_linear_machine(physics, cfg, pos, vel, acc, force, load, seed=seed)
    channels, index, delay = nc_trace(res, force, cfg)
    if spindle is not None:
        rng = np.random.default_rng(seed + 1)
        omega, torque = spindle
        cur = settings.spindle_idle_current + torque / settings.spindle_kt
        if not cfg.true_state:
            omega = omega * (1.0 + 1e-3 * rng.standard_normal(omega.size))
            cur = cur + 0.05 * rng.standard_normal(cur.size)
        channels["spindle_speed"] = omega[index]
        channels["spindle_current"] = cur[index]
    model = physics.model()
    meta = {**meta, "t_control": [float(t[index[0]]), float(t[index[-1]])], "nc_delay_s": delay,
            "motor_constants_n_per_a": {a: model.axis(a).K_m for a in AXES},
            "physics": "ideal (exactly the ModelBased model; true state point samples, unfiltered force)"
            if physics.exact else "full (LuGre friction with presliding/stiction, ripple, drift and load, cogging "
            "harmonics varying along the travel, K_m droop, current-loop lag, yaw coupling, weight shift, "
            "noise, quantisation, run-to-run variation)",
            "reference_filter": "unfiltered true force" if cfg.reference_order <= 0 else
            f"zero-phase {cfg.reference_order}th-order Butterworth {cfg.reference_cutoff_hz:g} Hz at "
            f"{cfg.fs:g} Hz, then decimated to {cfg.nc_rate:g} Hz",
            "nc_signals": "point samples of the plant's true state" if cfg.true_state else
            f"controller values through the logger's causal linear-phase FIR anti-alias filter "
            f"(magnitude of the reference filter, delay {delay * 1e3:.2f} ms), decimated"}
    t0 = float(t[index[0]])
    return Recording.from_arrays(channels, fs=cfg.nc_rate, t0=t0, meta=meta)


def simulate_process(process: str, a_p: float, a_e: float, v_f: float, n: float, *, seed: int = 0,
                     ideal: bool = False, settings: ProcessSettings | None = None, air: bool = False) -> Recording:
    """Simulate one milling process on the 3-axis linear-motor machine: the NC trace at 250 Hz.

    Parameters
    ----------
    process : str
        One of :func:`process_names` (e.g. ``"groove_+x"``, ``"pocket_ccw"``).
    a_p : float
        Axial depth of cut [m] (the ramp's final depth).
    a_e : float
        Radial depth of cut [m] (grooves use the tool diameter).
    v_f : float
        Feed speed [m/s].
    n : float
        Spindle speed [min^-1] (as in the paper's Table 1).
    seed : int
        Seed of every random element (noise, run variation, spindle phase).
    ideal : bool
        Use ``settings.as_ideal()`` (:meth:`ProcessSettings.as_ideal`): data
        from exactly the ModelBased model.
    settings : ProcessSettings, optional
        Machine, controller, tool and geometry (default: the preset, full physics).
    air : bool
        An air cut: the same toolpath, spindle running, tool clear of the
        part, so the process force is zero (labelled data for free: friction,
        cogging and inertia at the process's moves and reversals).

    Returns
    -------
    Recording
        ``{x,y,z}_position`` [m], ``{x,y,z}_velocity`` [m/s],
        ``{x,y,z}_acceleration`` [m/s^2], ``{x,y,z}_current`` [A],
        ``spindle_speed`` [rad/s], ``spindle_current`` [A] and the true
        force on the workpiece ``force_x/y/z`` [N]; metadata include
        ``score_window`` [s], ``nc_delay_s`` and the process parameters.
    """
    settings = settings or ProcessSettings()
    if ideal:
        settings = settings.as_ideal()
    if not isinstance(process, str) or process not in process_names():
        raise ConfigError(f"unknown process {process!r}; known: {', '.join(process_names())}")
    a_p = _check_param(a_p, "a_p", "m", 0.02)
    a_e = _check_param(a_e, "a_e", "m", settings.tool.diameter)
    v_f = _check_param(v_f, "v_f", "m/s", 0.5)
    n = _check_param(n, "n", "min^-1", 60000.0)
    rng = np.random.default_rng(seed)
    omega = n * 2 * math.pi / 60.0
    phase = rng.uniform(0, 2 * math.pi)
    t, pos, vel, acc, force, torque, window = _process(process, a_p, a_e, v_f, settings,
                                                       lambda tt: omega * tt + phase, rng)
    if air:     # computed and dropped, so that the random draws (noise, variation) match the cut's
        force, torque = np.zeros_like(force), np.zeros_like(torque)
    physics = settings.physics if settings.ideal else settings.physics.varied(rng)
    load = np.vstack([np.abs(force[1]) + np.abs(force[2]), np.abs(force[0]) + np.abs(force[2]),
                      np.abs(force[0]) + np.abs(force[1])])
    moving = [a for i, a in enumerate(AXES) if np.ptp(pos[i]) > 1e-4]
    if process.startswith("groove_"):
        a_e = settings.tool.diameter          # a slot: full immersion whatever a_e was given
    radius = {"pocket_radius_m": settings.pocket_radius} if process in POCKETS else {}
    meta = {"name": process_run_name(process, a_p, a_e, v_f, n, air=air, pocket_radius=radius.get("pocket_radius_m")),
            "process": process, **radius, "kind": "air" if air else "cut", "a_p_m": a_p, "a_e_m": a_e, "v_f_m_s": v_f,
            "n_rpm": n, "seed": int(seed),
            "moving_axes": moving, "score_window": [float(window[0]), float(window[1])],
            "provenance": [f"drivesense.sim.machining {process} seed {seed}"]}
    return _record(settings, physics, t, pos, vel, acc, force, load, int(rng.integers(2 ** 31)), meta,
                   spindle=(np.full(t.size, omega), torque))


def simulate_air_moves(axes=AXES, *, seed: int = 100, ideal: bool = False, settings: ProcessSettings | None = None,
                       travel_speeds=(0.03, 0.06), speeds=(0.5e-3, 1e-3, 2e-3, 3e-3, 5e-3, 8e-3, 0.012, 0.03, 0.08, 0.15),
                       segment_time: float = 1.5, accel_speed: float = 0.25, accel_ramps=(0.08, 0.12, 0.16)
                       ) -> list[Recording]:
    """Identification moves without cutting (Sec. 2.2), per axis; the other axes stand at their centre.

    For each axis: back and forth over the travel at each of ``travel_speeds``
    (restoring force and cogging), short constant-velocity segments in both
    directions at each of ``speeds`` (Stribeck curve), and back-and-forth
    moves at ``accel_speed`` with short ramps (masses).  The moves form one
    session: the run-to-run variation of the physics is drawn once for all.

    Parameters
    ----------
    axes : sequence of str
        Axes to move (default x, y, z).
    seed : int
        Seed of the first recording (each gets its own).
    ideal : bool
        Use ``settings.as_ideal()`` (:meth:`ProcessSettings.as_ideal`).
    settings : ProcessSettings, optional
        Machine and controller (default: the preset, full physics).
    travel_speeds : sequence of float
        Speeds of the full-travel moves [m/s].
    speeds : sequence of float
        Speeds of the friction segments [m/s].
    segment_time : float
        Cruise time of each friction segment [s] (at most the travel).
    accel_speed : float
        Peak speed of the accelerated moves [m/s].
    accel_ramps : sequence of float
        Ramp durations of the accelerated moves [s] (peak acceleration
        ``pi accel_speed / (2 ramp)``).

    Returns
    -------
    list of Recording
        Three NC traces per axis (``air_{ax}_travel``, ``air_{ax}_speeds``,
        ``air_{ax}_accel``), channels as :func:`simulate_process` without the
        spindle; ``meta["true_model"]`` holds the session's true model
        parameters (nominal values with this session's variation; SI).
    """
    settings = settings or ProcessSettings()
    if ideal:
        settings = settings.as_ideal()
    out = []
    fs = settings.servo.fs
    # one identification session: the run-to-run variation is drawn once for all its moves
    session = settings.physics if settings.ideal else settings.physics.varied(np.random.default_rng(seed))
    for ai, ax in enumerate(axes):
        if ax not in AXES:
            raise ConfigError(f"unknown axis {ax!r} in air moves (expected x, y or z)")
        i = AXES.index(ax)
        lo, hi = settings.physics.axis(ax).travel
        lo, hi = lo + 0.005, hi - 0.005
        unit = np.eye(3)[i]
        programs = []
        prog = ToolpathProgram(np.where(unit > 0, lo, _centre(settings.physics)), fs)
        for v in travel_speeds:
            prog.dwell(0.3)
            prog.line(unit * (hi - lo), v, 0.1)
            prog.dwell(0.3)
            prog.line(-unit * (hi - lo), v, 0.1)
        programs.append(("travel", prog))
        prog = ToolpathProgram(np.where(unit > 0, lo, _centre(settings.physics)), fs)
        here = lo
        for v in speeds:      # every segment centred on the travel centre (same friction ripple for all speeds)
            length = min(v * segment_time, hi - lo)
            target = 0.5 * (lo + hi) - 0.5 * length
            if abs(target - here) > 1e-6:
                prog.dwell(0.1)
                prog.line(unit * (target - here), min(0.1, abs(target - here) / 0.2), 0.05)
            prog.dwell(0.2)
            prog.line(unit * length, v, 0.1)
            prog.dwell(0.2)
            prog.line(-unit * length, v, 0.1)
            here = target
        programs.append(("speeds", prog))
        prog = ToolpathProgram(np.where(unit > 0, lo, _centre(settings.physics)), fs)
        span = min(0.2, hi - lo)
        for ramp in accel_ramps:
            prog.dwell(0.2)
            prog.line(unit * span, accel_speed, ramp)
            prog.dwell(0.2)
            prog.line(-unit * span, accel_speed, ramp)
        programs.append(("accel", prog))
        for pi_, (label, prog) in enumerate(programs):
            rseed = seed + 10 * ai + pi_
            rng = np.random.default_rng(rseed)
            t, pos, vel, acc = prog.build(0.3)
            physics = session
            zeros = np.zeros((3, t.size))
            truth = {a: {k: v for k, v in physics.model().axis(a).to_dict().items() if k != "cogging"} for a in AXES}
            meta = {"name": f"air_{ax}_{label}", "kind": "air_move", "moving_axes": [ax], "program": label,
                    "true_model": truth,
                    "seed": int(rseed), "provenance": [f"drivesense.sim.machining air moves {ax}/{label}, seed {rseed}"]}
            out.append(_record(settings, physics, t, pos, vel, acc, zeros, zeros, int(rng.integers(2 ** 31)), meta))
    return out
