"""End-milling scenarios of the first paper, simulated with the full stage physics.

Ten cutting conditions (Figs. 15 and 21): radial depth 1.5 or 6.0 mm with a
6 mm two-flute end mill, spindle 1000 / 4000 / 10 000 min^-1, feed 1 mm/s,
a small axial depth so the force stays below the stage's kinetic friction.

* ``feed``: the X stage feeds, the X force is the feed-direction component;
  three idling runs over the same trajectory calibrate the friction.
* ``cross``: the Y stage feeds while X stands under position control; the X
  force is the cross-feed component; a tare before the cut calibrates.

Each simulated trace holds the drive signals and the true process force on
the table (``force_x`` ...), with its scoring window in the metadata.

The ideal-physics switch is :meth:`ScenarioSettings.as_ideal` (``ideal=True``
on every ``simulate_*`` function routes to it): data from exactly the
estimators' own model -- the linear dual-inertia plant without friction,
cogging, lead error, torque-constant droop or second current-loop pole,
perfect encoders, no noise, coupling or run-to-run variation.  The
linear-motor simulator has the same switch
(:meth:`drivesense.sim.machining.ProcessSettings.as_ideal`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from functools import partial

import numpy as np

from drivesense.machine.friction import Ripple, ripple_values
from drivesense.machine.milling import CuttingCoefficients, EndMill, MillingCut, feed_per_tooth, milling_forces
from drivesense.machine.presets import table1_stage
from drivesense.machine.stage import StagePhysics
from drivesense.nc_context import ACTIVE, program_code
from drivesense.recording import Recording
from drivesense.sim.encoders import LinearScale, RotaryEncoder
from drivesense.sim.servo import ServoConfig, run_servo
from drivesense.sim.toolpath import constant_feed, standstill

__all__ = ["CutCondition", "ScenarioSettings", "paper_conditions", "simulate_cut", "simulate_idle", "run_scenario",
           "simulate_frf_excitation", "scenario_names", "condition_by_name"]


@dataclass(frozen=True)
class CutCondition:
    """One end-milling test.

    Parameters
    ----------
    name : str
        Identifier, e.g. ``"feed_r1.5_S1000"``.
    direction : {"feed", "cross"}
        Whether the monitored X axis feeds or stands.
    radial_depth : float
        Radial depth of cut [m].
    spindle_rpm : float
        Spindle speed [min^-1].
    feed_speed : float
        Feed speed [m/s].
    axial_depth : float
        Axial depth of cut [m].
    mode : {"down", "up"}
        Milling mode for partial immersion.
    """

    name: str
    direction: str
    radial_depth: float
    spindle_rpm: float
    feed_speed: float = 1.0e-3
    axial_depth: float = 0.5e-3
    mode: str = "down"


@dataclass(frozen=True)
class ScenarioSettings:
    """Everything about a simulated test that is not the cutting condition.

    Parameters
    ----------
    stage : StagePhysics
        Plant physics (default: Table 1 with the full physics).
    servo : ServoConfig
        Controller and signal chain.
    tool : EndMill
        6 mm, 2 flutes, 30 deg helix, 2 um runout.
    coefficients : CuttingCoefficients
        Aluminium.
    duration : float
        Trace length [s].
    t_contact : float
        Time the tool first reaches the workpiece edge [s].
    settle : float
        Time after the end of the acceleration ramp excluded from scoring [s].
    coupling_gain : float
        Share of the Y drive's friction ripple felt by the X table [-].
    run_spread : float
        Run-to-run friction variation, 1 sigma [-].
    ideal : bool
        Set by :meth:`as_ideal`: the simulation draws no run-to-run
        variation and uses perfect encoders (the rest of the ideal physics is
        in the stage and servo that :meth:`as_ideal` strips).
    """

    stage: StagePhysics = field(default_factory=table1_stage)
    servo: ServoConfig = field(default_factory=ServoConfig)
    tool: EndMill = field(default_factory=lambda: EndMill(6e-3, 2, 30.0, runout=2e-6, runout_phase=0.4))
    coefficients: CuttingCoefficients = field(default_factory=CuttingCoefficients.aluminium)
    duration: float = 8.0
    t_contact: float = 1.5
    settle: float = 0.3
    coupling_gain: float = 0.02
    run_spread: float = 0.02
    ideal: bool = False

    def as_ideal(self) -> "ScenarioSettings":
        """Settings that reproduce the estimators' own model exactly (the ideal-physics switch).

        The stage reduced to the linear model (:meth:`StagePhysics.ideal
        <drivesense.machine.stage.StagePhysics.ideal>`), no current noise
        (:meth:`ServoConfig.as_ideal <drivesense.sim.servo.ServoConfig.as_ideal>`),
        no coupling or run-to-run variation, perfect encoders (``ideal``).

        Returns
        -------
        ScenarioSettings
        """
        return replace(self, stage=self.stage.ideal(), servo=self.servo.as_ideal(), coupling_gain=0.0,
                       run_spread=0.0, ideal=True)


def _settings(settings: ScenarioSettings | None, ideal: bool) -> ScenarioSettings:
    """The settings a ``simulate_*`` call uses: the default, and :meth:`ScenarioSettings.as_ideal` if asked."""
    settings = settings or ScenarioSettings()
    return settings.as_ideal() if ideal else settings


def paper_conditions(axial_depth: float = 0.5e-3) -> list[CutCondition]:
    """The ten conditions of Figs. 15 (feed) and 21 (cross-feed).

    Parameters
    ----------
    axial_depth : float, optional
        Axial depth of cut of every condition [m] (default 0.5 mm).

    Returns
    -------
    list of CutCondition
        The five feed-direction conditions, then the five cross-feed ones.
    """
    feed = [(1.5, 1000), (1.5, 4000), (6.0, 1000), (1.5, 10000), (6.0, 10000)]
    cross = [(1.5, 1000), (1.5, 4000), (6.0, 4000), (1.5, 10000), (6.0, 10000)]
    out = []
    for direction, grid in (("feed", feed), ("cross", cross)):
        for r, s in grid:
            out.append(CutCondition(f"{direction}_r{r:g}_S{s}", direction, r * 1e-3, float(s),
                                    axial_depth=axial_depth))
    return out


def scenario_names() -> list[str]:
    """Names accepted by ``drivesense simulate``: the cuts, their idle runs and the FRF excitations."""
    from drivesense.sim.excitation import EXCITATIONS

    return [c.name for c in paper_conditions()] + [f"idle_{c.name}" for c in paper_conditions()
                                                   if c.direction == "feed"] + [f"frf_{k}" for k in EXCITATIONS]


def condition_by_name(name: str) -> tuple[CutCondition, bool]:
    """Look up a scenario name; returns ``(condition, is_idle)``.

    Parameters
    ----------
    name : str
        A condition name (``"feed_r6_S1000"``), optionally prefixed ``"idle_"``.

    Returns
    -------
    condition : CutCondition
    is_idle : bool

    Raises
    ------
    KeyError
        Listing the known names.
    """
    idle = name.startswith("idle_")
    base = name[5:] if idle else name
    for c in paper_conditions():
        if c.name == base:
            return c, idle
    raise KeyError(f"unknown scenario {name!r}; known: {', '.join(scenario_names())}")


#: Friction ripple of the (unsimulated) Y drive [N] over its position [m].
_Y_RIPPLE = (Ripple(5e-3, 3.0, 0.5), Ripple(1.25e-3, 1.0, 1.7))


def _y_ripple(y: np.ndarray) -> np.ndarray:
    """Friction ripple of the (unsimulated) Y drive [N] versus its position [m]."""
    return ripple_values(_Y_RIPPLE, y)


def _process_forces(cond: CutCondition, settings: ScenarioSettings, times: np.ndarray, feed_axis, omega: float,
                    phase0: float, t_grid: np.ndarray):
    """Process force on the table along machine X, Y, Z [N] at ``times`` [s]."""
    tool = settings.tool
    feed_pos = np.interp(times, t_grid, feed_axis.position)
    progress = feed_pos - np.interp(settings.t_contact, t_grid, feed_axis.position) - tool.diameter / 2
    c = feed_per_tooth(cond.feed_speed, omega, tool.flutes)
    mf = milling_forces(tool, settings.coefficients,
                        MillingCut(cond.radial_depth, cond.axial_depth, cond.mode, axial_slices=8),
                        omega * times + phase0, c, feed_progress=progress)
    # tool frame: x along the tool's motion relative to the workpiece (opposite the table's),
    # y = z x x.  The table (workpiece) feels minus the force on the tool.
    if cond.direction == "feed":
        return mf.feed, mf.normal, -mf.axial
    return -mf.normal, mf.feed, -mf.axial


def run_scenario(cond: CutCondition, settings: ScenarioSettings, seed: int, cutting: bool, label: str, *,
                 overrides=(), forces=None, extra_meta=None, part_length: float | None = None) -> Recording:
    """One simulated run of the stage (what :func:`simulate_cut` and :func:`simulate_idle` run).

    The trace carries the NC's context (:mod:`drivesense.nc_context`) as the
    controller would report it: tool 1, the program (a code of the
    condition's name), block 10 while the axis stands and 20 for the feed
    move, the feed override stepping at each override change (the axis
    follows over the ramp), spindle override 1, execution ``ACTIVE``, and
    ``in_cut`` from the first contact until the tool has left the part (a
    cutting run; ``part_length``), as a CAM program that knows the stock
    marks it.

    Parameters
    ----------
    cond : CutCondition
        The cutting condition.
    settings : ScenarioSettings
        Physics and signal chain.
    seed : int
        Seed of every random element.
    cutting : bool
        Whether the tool cuts (False: an idle run, zero force).
    label : str
        The trace's name.
    overrides : sequence of (float, float)
        Feed-rate override changes ``(time [s], factor [-])``.
    forces : callable, optional
        ``forces(t_fine, feed_axis, omega, phase0, t) -> (F_x, F_y, F_z)`` [N] on the plant's sub-step
        grid, replacing the milling force model (e.g. with tool vibration and events).
    extra_meta : dict, optional
        Metadata added to the trace's.
    part_length : float, optional
        Length of the part along the feed [m] from the first contact (None: the part outlasts the run).

    Returns
    -------
    Recording
    """
    rng = np.random.default_rng(seed)
    cfg = settings.servo
    fs = cfg.fs
    stage = settings.stage if settings.ideal else settings.stage.varied(rng, settings.run_spread)
    feed_axis = constant_feed(settings.duration, fs, cond.feed_speed, overrides=overrides)
    n = feed_axis.position.size
    t = np.arange(n) / fs
    if cond.direction == "feed":
        x_traj = feed_axis
        y_pos = np.zeros(n)
    elif cond.direction == "cross":
        x_traj = standstill(settings.duration, fs)
        y_pos = feed_axis.position
    else:
        raise ValueError(f"condition {cond.name!r}: direction must be 'feed' or 'cross'")
    tool = settings.tool
    omega = cond.spindle_rpm * 2 * math.pi / 60.0
    phase0 = rng.uniform(0, 2 * math.pi)
    # the process force at every plant sub-step; the recorded truth is its value at the control instants
    t_fine = np.arange(n * cfg.substeps) / (fs * cfg.substeps)
    if cutting:
        fine_x, fine_y, fine_z = (forces or partial(_process_forces, cond, settings))(t_fine, feed_axis, omega,
                                                                                      phase0, t)
    else:
        fine_x = fine_y = fine_z = np.zeros(t_fine.size)
    forces_x, forces_y, forces_z = (np.ascontiguousarray(f[::cfg.substeps]) for f in (fine_x, fine_y, fine_z))
    table_force = fine_x.copy()
    if cond.direction == "cross" and settings.coupling_gain:
        table_force += settings.coupling_gain * _y_ripple(np.interp(t_fine, t, y_pos))
    normal_load = -forces_z
    enc = RotaryEncoder().ideal() if settings.ideal else RotaryEncoder()
    scl = LinearScale().ideal() if settings.ideal else LinearScale()
    res = run_servo(stage, cfg, x_traj.position, x_traj.velocity, x_traj.acceleration, table_force,
                    normal_load, encoder=enc, scale=scl, seed=int(rng.integers(2**31)))
    cruise_start = feed_axis.cruise[0]
    score = [cruise_start + settings.settle, settings.duration - 0.01]
    meta = {
        "name": label,
        "scenario": cond.name,
        "kind": "cut" if cutting else "idle",
        "condition": asdict(cond),
        "direction": cond.direction,
        "physics": "ideal (the estimators' own model)" if settings.ideal else
                   "full (LuGre friction with ripple/drift/load, cogging, lead error, Kt droop, "
                   "2nd-order current loop, encoder interpolation error, noise, quantisation, coupling)",
        "seed": int(seed),
        "tool": {"diameter_m": tool.diameter, "flutes": tool.flutes, "helix_deg": tool.helix_deg,
                 "runout_m": tool.runout},
        "t_contact": settings.t_contact,
        "score_window": score,
        "tare_window": [cruise_start + settings.settle, settings.t_contact - 0.05],
        "true_signal": {"T_a": cfg.T_a, "T_b": cfg.T_b, "omega_cc": cfg.omega_cc},
        "provenance": [f"drivesense.sim {cond.name} ({'cut' if cutting else 'idle'}), seed {seed}"],
        **(extra_meta or {}),
    }
    channels = {
        "x_current_ref": res.current_ref,
        "x_current": res.current,
        "x_motor_angle": res.motor_angle,
        "x_table_position": res.table_position,
        "y_table_position": y_pos,
        "spindle_speed": np.full(n, omega),
        "force_x": forces_x,
        "force_y": forces_y,
        "force_z": forces_z,
        **_nc_context(cond, settings, feed_axis, t, overrides, cutting, part_length),
    }
    return Recording.from_arrays(channels, fs=fs, meta=meta)


#: Blocks of the stage's program: the axis stands (N10), the feed move (N20).
STAND_BLOCK, FEED_BLOCK = 10.0, 20.0


def _nc_context(cond: CutCondition, settings: ScenarioSettings, feed_axis, t: np.ndarray, overrides, cutting: bool,
                part_length: float | None) -> dict[str, np.ndarray]:
    """The controller's context channels of one run (see :func:`run_scenario`)."""
    n = t.size
    feed_override = np.ones(n)
    for t_change, factor in overrides:
        feed_override[t >= t_change] = factor
    moving = np.abs(feed_axis.velocity) > 0.0
    first_move = int(np.argmax(moving)) if moving.any() else n
    block = np.full(n, STAND_BLOCK)
    block[first_move:] = FEED_BLOCK
    in_cut = np.zeros(n)
    if cutting:
        travel = np.abs(feed_axis.position - np.interp(settings.t_contact, t, feed_axis.position))
        inside = t >= settings.t_contact
        if part_length is not None:
            inside &= travel <= part_length + settings.tool.diameter     # the tool's far edge has left the part
        in_cut[inside] = 1.0
    return {"tool_number": np.ones(n), "program_number": np.full(n, program_code(cond.name)),
            "block_number": block, "feed_override": feed_override, "spindle_override": np.ones(n),
            "execution": np.full(n, ACTIVE), "in_cut": in_cut}


def simulate_cut(cond: CutCondition, settings: ScenarioSettings | None = None, *, seed: int = 0,
                 ideal: bool = False) -> Recording:
    """Simulate one cutting test.

    Parameters
    ----------
    cond : CutCondition
        The cutting condition.
    settings : ScenarioSettings, optional
        Physics and signal chain (default: full physics of the Table 1 stage).
    seed : int
        Seed of every random element (noise, run variation, spindle phase).
    ideal : bool
        Use ``settings.as_ideal()`` (:meth:`ScenarioSettings.as_ideal`): data
        from exactly the estimators' model.

    Returns
    -------
    Recording
        ``x_current_ref`` [A], ``x_current`` [A], ``x_motor_angle`` [rad],
        ``x_table_position`` [m], ``y_table_position`` [m],
        ``spindle_speed`` [rad/s] and the true forces on the table
        ``force_x``, ``force_y``, ``force_z`` [N]; metadata include
        ``score_window`` and ``tare_window`` [s].
    """
    return run_scenario(cond, _settings(settings, ideal), seed, True, cond.name)


def simulate_idle(cond: CutCondition, settings: ScenarioSettings | None = None, *, repeats: int = 3,
                  seed: int = 1000, ideal: bool = False) -> list[Recording]:
    """Idling runs: the cut's trajectory without cutting, ``repeats`` times (Sec. 4).

    Parameters
    ----------
    cond : CutCondition
        The cutting condition whose trajectory is repeated.
    settings : ScenarioSettings, optional
        Physics and signal chain (default: full physics of the Table 1 stage).
    repeats : int
        Number of runs.
    seed : int
        Seed of the first run (run ``k`` uses ``seed + k``).
    ideal : bool
        Use ``settings.as_ideal()`` (:meth:`ScenarioSettings.as_ideal`).

    Returns
    -------
    list of Recording
        Channels as :func:`simulate_cut`, forces zero; run ``k`` is named
        ``idle_{condition}_{k + 1}_seed{seed + k}``.
    """
    settings = _settings(settings, ideal)
    # the name holds the run index and its seed: runs of one call, and of calls with other seeds, differ
    return [run_scenario(cond, settings, seed + k, False, f"idle_{cond.name}_{k + 1}_seed{seed + k}")
            for k in range(repeats)]


def simulate_frf_excitation(kind: str = "multisine", settings: ScenarioSettings | None = None, *,
                            amplitude: float = 0.3, duration: float = 8.0, feed_speed: float = 10e-3,
                            f0: float = 5.0, f1: float = 2000.0, seed: int = 0, ideal: bool = False) -> Recording:
    """Excite the X axis through its current reference while it moves at constant speed.

    The axis moves at ``feed_speed`` (sliding friction, no stick-slip) under
    closed-loop control; from the end of the acceleration ramp on, the
    excitation is added to the controller's current reference.

    Parameters
    ----------
    kind : {"multisine", "chirp", "prbs"}
        Excitation signal.
    settings : ScenarioSettings, optional
        Physics and signal chain (default: full physics).
    amplitude : float
        Peak excitation [A].
    duration : float
        Trace length [s].
    feed_speed : float
        Axis speed during the measurement [m/s].
    f0, f1 : float
        Excitation band [Hz].
    seed : int
        Seed.
    ideal : bool
        Use ``settings.as_ideal()`` (:meth:`ScenarioSettings.as_ideal`).

    Returns
    -------
    Recording
        ``x_current_ref`` (controller output plus excitation) [A],
        ``x_current_excitation`` [A], ``x_current`` [A], ``x_motor_angle`` [rad],
        ``x_table_position`` [m]; ``meta["excitation_window"]`` [s] and the
        true parameters in ``meta["true_axis"]`` / ``meta["true_signal"]``.
    """
    from drivesense.sim.excitation import make_excitation

    settings = _settings(settings, ideal)
    rng = np.random.default_rng(seed)
    cfg = settings.servo
    fs = cfg.fs
    stage = settings.stage if settings.ideal else settings.stage.varied(rng, settings.run_spread)
    traj = constant_feed(duration, fs, feed_speed)
    n = traj.position.size
    t_on = round(traj.cruise[0] + settings.settle, 3)
    i_on = int(round(t_on * fs))
    excitation = np.zeros(n)
    excitation[i_on:] = make_excitation(kind, (n - i_on) / fs, fs, amplitude, f0=f0, f1=f1,
                                        limit=stage.max_current, seed=seed)
    enc = RotaryEncoder().ideal() if settings.ideal else RotaryEncoder()
    scl = LinearScale().ideal() if settings.ideal else LinearScale()
    z = np.zeros(n)
    res = run_servo(stage, cfg, traj.position, traj.velocity, traj.acceleration, z, z, encoder=enc, scale=scl,
                    seed=int(rng.integers(2**31)), current_excitation=excitation)
    meta = {
        "name": f"frf_{kind}",
        "scenario": f"frf_{kind}",
        "kind": "frf",
        "excitation": {"kind": kind, "amplitude_a": amplitude, "band_hz": [f0, f1], "feed_speed_m_s": feed_speed,
                       "period_s": 1.0 if kind == "multisine" else None},
        "excitation_window": [t_on, duration],
        "physics": "ideal" if settings.ideal else "full",
        "seed": int(seed),
        "true_axis": stage.axis.to_dict(),
        "true_signal": {"T_a": cfg.T_a, "T_b": cfg.T_b, "omega_cc": cfg.omega_cc},
        "provenance": [f"drivesense.sim frf_{kind}, seed {seed}"],
    }
    return Recording.from_arrays({"x_current_ref": res.current_ref, "x_current_excitation": excitation,
                                  "x_current": res.current, "x_motor_angle": res.motor_angle,
                                  "x_table_position": res.table_position}, fs=fs, meta=meta,
                                 units={"x_current_excitation": "A"})
