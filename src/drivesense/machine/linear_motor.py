"""Linear-motor feed axes of a 3-axis machine (third paper, Sec. 2.2, Eq. 1-4).

The estimators' model of one axis (Eq. 1) balances the motor force against
cogging, a linear restoring force (cable drag, covers), friction, inertia and
the process::

    K_m I = F_co(s) + k (s - s_r) + F_fr(v) + M a + F_ext

with the Stribeck curve of Eq. 4 (shape factor ``delta = 2``)::

    F_fr(v) = sgn(v) (F_C + (F_br - F_C) exp(-|v / v_s|^delta)) + sigma v

Beyond the paper, ``sgn(v)`` may be replaced by a presliding (Dahl) state
``d`` in [-1, 1] that follows the position: over a travel ``ds`` it relaxes
towards ``sgn(ds)`` as ``exp(-|ds| / x_pre)`` (:mod:`drivesense.machine.presliding`,
:func:`~drivesense.machine.presliding.presliding_direction`, re-exported here).
Sliding, ``d = sgn(v)`` and Eq. 4 is unchanged; at standstill and through
reversals the friction becomes a stiff, hysteretic spring of stiffness about
``F_br / x_pre`` instead of a sign that flips with the velocity noise.
``x_pre = 0`` keeps the paper's model.

and the cogging force a lookup table over one pole pitch.  On the machine of
the paper Y carries X, and X carries Z (Eq. 2), so the masses the motors move
are ``m_x + m_z`` (X), ``m_x + m_y + m_z`` (Y) and ``m_z`` (Z).

``F_ext`` is the process force on the workpiece (what a table-mounted
dynamometer reads) along +axis: the axes carry the tool, which feels minus it.

:class:`LinearAxisPhysics` / :class:`LinearMachinePhysics` hold what the
simulator integrates: the model plus what it leaves out (LuGre friction with
presliding and stiction, friction ripple, drift and load dependence, cogging
harmonics whose amplitude varies along the travel, motor-constant droop,
current-loop lag, cross-axis coupling).  ``ideal()`` strips that and leaves
exactly the model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from drivesense.errors import ConfigError
from drivesense.machine.friction import LuGreFriction, Ripple
from drivesense.machine.presliding import carried_presliding_direction, presliding_direction
from drivesense.machine.validation import dataclass_from_dict, signal_array

__all__ = ["LinearMotorAxis", "ThreeAxisModel", "LinearAxisPhysics", "LinearMachinePhysics", "AXES",
           "cogging_table_force", "harmonic_cogging_table", "linear_machine_physics", "linear_machine_model",
           "presliding_direction", "carried_presliding_direction", "axis_name"]

#: Axis letters of the 3-axis machine, in order.
AXES = ("x", "y", "z")
_SCALARS = ("K_m", "k", "s_r", "m", "F_C", "F_br", "v_s", "sigma", "delta", "pole_pitch", "x_pre")
_OPTIONAL = ("pole_pitch", "delta", "x_pre", "undetermined")
_NONNEG = ("k", "F_C", "F_br", "sigma", "x_pre")
_POSITIVE = ("K_m", "m", "v_s", "delta", "pole_pitch")


@njit(cache=True)
def cogging_table_force(table: np.ndarray, pole_pitch: float, s: float) -> float:
    """Cogging force [N] at position ``s`` [m] from a periodic table (linear interpolation).

    ``table[j]`` is the force at ``s = j * pole_pitch / len(table)`` (mod ``pole_pitch``).
    """
    n = table.size
    u = (s / pole_pitch - math.floor(s / pole_pitch)) * n
    i = int(math.floor(u))
    f = u - i
    i %= n
    j = i + 1 if i + 1 < n else 0
    return table[i] + f * (table[j] - table[i])


def axis_name(name) -> str:
    """``name`` if it is an axis letter of :data:`AXES`, else :class:`~drivesense.errors.ConfigError`.

    Parameters
    ----------
    name : str
        Axis letter, ``"x"``, ``"y"`` or ``"z"``.

    Returns
    -------
    str
    """
    if name not in AXES:
        raise ConfigError(f"unknown axis {name!r} (expected x, y or z)")
    return name


def harmonic_cogging_table(harmonics, n: int = 64) -> np.ndarray:
    """Sample a cogging force given as harmonics of the pole pitch on a uniform grid.

    Parameters
    ----------
    harmonics : sequence of (float, float)
        ``(amplitude [N], phase [rad])`` of harmonic 1, 2, ... : the force is
        ``sum_h A_h sin(2 pi h s / pole_pitch + phi_h)``.
    n : int
        Table size (grid points over one pole pitch).

    Returns
    -------
    ndarray, shape (n,)
        Cogging force [N] at ``s = j pole_pitch / n``.
    """
    u = np.arange(int(n)) / int(n)
    out = np.zeros(int(n))
    for h, (amp, phase) in enumerate(harmonics, start=1):
        out += amp * np.sin(2.0 * math.pi * h * u + phase)
    return out


@dataclass(frozen=True, eq=False)
class LinearMotorAxis:
    """The estimators' model of one linear-motor axis (Eq. 1, 4).

    Parameters
    ----------
    K_m : float
        Motor (force) constant [N/A].
    k : float
        Restoring constant (cable drag, covers) [N/m].
    s_r : float
        Rest point of the restoring force [m].
    m : float
        The axis's own moving mass [kg] (the masses it carries are added by
        :class:`ThreeAxisModel`).
    F_C : float
        Coulomb friction [N].
    F_br : float
        Breakaway friction [N].
    v_s : float
        Stribeck velocity [m/s].
    sigma : float
        Viscous friction coefficient [N*s/m].
    cogging : array_like
        Cogging force [N] on a uniform grid over one pole pitch (periodic:
        ``cogging[j]`` at ``s = j pole_pitch / len(cogging)``), at least 4 values.
    pole_pitch : float
        Pole pitch of the motor [m] (e.g. 0.023).
    delta : float
        Stribeck shape factor [-] (2 in the paper).
    x_pre : float
        Presliding distance [m] of the Dahl friction state (beyond the paper;
        see :func:`~drivesense.machine.presliding.presliding_direction`); 0 (default): the paper's ``sgn(v)``.
    undetermined : tuple of str
        Parameters the identification could not determine and set to a
        documented fallback (e.g. ``("F_br", "v_s")``: Coulomb + viscous
        friction with ``F_br = F_C``); empty (default) when all were identified.
    """

    K_m: float
    k: float
    s_r: float
    m: float
    F_C: float
    F_br: float
    v_s: float
    sigma: float
    cogging: np.ndarray = field(default_factory=lambda: np.zeros(64))
    pole_pitch: float = 0.023
    delta: float = 2.0
    x_pre: float = 0.0
    undetermined: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        und = self.undetermined
        if isinstance(und, str) or not all(isinstance(n, str) and n in _SCALARS + ("cogging",) for n in und):
            raise ConfigError(f"linear axis parameter 'undetermined' must list parameter names "
                              f"({', '.join(_SCALARS)}, cogging), got {und!r}")
        object.__setattr__(self, "undetermined", tuple(und))
        for name in _SCALARS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v):
                raise ConfigError(f"linear axis parameter '{name}' must be a finite number, got {v!r}")
            if name in _POSITIVE and v <= 0:
                raise ConfigError(f"linear axis parameter '{name}' must be > 0, got {v!r}")
            if name in _NONNEG and v < 0:
                raise ConfigError(f"linear axis parameter '{name}' must be >= 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        try:
            table = np.array(self.cogging, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ConfigError(f"linear axis parameter 'cogging' must be a list of numbers [N], "
                              f"got {self.cogging!r:.60}") from None
        if table.size < 4 or not np.all(np.isfinite(table)):
            raise ConfigError(f"linear axis parameter 'cogging' must hold >= 4 finite values [N], "
                              f"got {table.size} value(s)")
        table.flags.writeable = False
        object.__setattr__(self, "cogging", table)

    # ------------------------------------------------------------- force terms
    def motor_force(self, current):
        """Motor force ``K_m I`` [N] for motor current ``current`` [A].

        Parameters
        ----------
        current : float or array_like
            Motor current [A].
        """
        return self.K_m * signal_array(current, "current")

    def restoring_force(self, position):
        """Restoring force ``k (s - s_r)`` [N] at ``position`` [m].

        Parameters
        ----------
        position : float or array_like
            Axis position [m].
        """
        return self.k * (signal_array(position, "position") - self.s_r)

    def cogging_force(self, position):
        """Cogging force [N] at ``position`` [m] (periodic linear interpolation in the table).

        Parameters
        ----------
        position : float or array_like
            Axis position [m].
        """
        s = signal_array(position, "position")
        n = self.cogging.size
        u = np.mod(s, self.pole_pitch) / self.pole_pitch * n
        i = np.floor(u)
        f = u - i
        i = i.astype(np.int64) % n
        t = self.cogging
        return t[i] + f * (t[(i + 1) % n] - t[i])

    def friction_force(self, velocity, v_eps: float = 0.0, direction=None):
        """Stribeck plus viscous friction of Eq. 4 [N] at ``velocity`` [m/s].

        Parameters
        ----------
        velocity : float or array_like
            Axis velocity [m/s].
        v_eps : float
            Half-width [m/s] of a linear ramp replacing ``sgn(v)``; 0 (default)
            is the paper's sign function.
        direction : array_like, optional
            Presliding state in [-1, 1] replacing ``sgn(v)`` (e.g.
            :func:`~drivesense.machine.presliding.presliding_direction`); overrides ``v_eps``.
        """
        v = signal_array(velocity, "velocity")
        if direction is not None:
            sgn = signal_array(direction, "direction")
        else:
            sgn = np.sign(v) if v_eps <= 0 else np.clip(v / v_eps, -1.0, 1.0)
        return sgn * self.stribeck_level(v) + self.sigma * v

    def stribeck_level(self, velocity):
        """Magnitude of the Stribeck friction ``F_C + (F_br - F_C) exp(-|v / v_s|^delta)`` [N] at ``velocity`` [m/s].

        Parameters
        ----------
        velocity : float or array_like
            Axis velocity [m/s].
        """
        v = signal_array(velocity, "velocity")
        return self.F_C + (self.F_br - self.F_C) * np.exp(-np.abs(v / self.v_s) ** self.delta)

    def cogging_amplitudes(self, n_harmonics: int = 3) -> np.ndarray:
        """Amplitudes [N] of harmonics 1..``n_harmonics`` of the pole pitch in the cogging table.

        Parameters
        ----------
        n_harmonics : int, optional
            Number of harmonics (default 3).
        """
        spec = np.fft.rfft(self.cogging) / self.cogging.size * 2.0
        return np.abs(spec[1:n_harmonics + 1])

    def with_values(self, **changes) -> "LinearMotorAxis":
        """A copy with some parameters replaced (same names as the constructor)."""
        return replace(self, **changes)

    def to_dict(self) -> dict:
        """Parameters as plain JSON/TOML types (SI; ``cogging`` a list; ``undetermined`` only when not empty)."""
        d = {name: getattr(self, name) for name in _SCALARS}
        d["cogging"] = [float(v) for v in self.cogging]
        if self.undetermined:
            d["undetermined"] = list(self.undetermined)
        return d

    @classmethod
    def from_dict(cls, values, *, source: str = "linear axis") -> "LinearMotorAxis":
        """Build from a mapping with the constructor's keys; unknown/missing keys raise ConfigError.

        Parameters
        ----------
        values : mapping
            Parameter name -> value (SI).
        source : str
            Where the values come from, for messages.
        """
        return dataclass_from_dict(cls, values, source, optional=_OPTIONAL)


@dataclass(frozen=True, eq=False)
class ThreeAxisModel:
    """The three linear-motor axes of Eq. 2 (Y carries X, X carries Z).

    Parameters
    ----------
    x, y, z : LinearMotorAxis
        Model of each axis; ``m`` is each axis's own moving mass [kg].
    """

    x: LinearMotorAxis
    y: LinearMotorAxis
    z: LinearMotorAxis

    def __post_init__(self) -> None:
        for ax in AXES:
            if not isinstance(getattr(self, ax), LinearMotorAxis):
                raise ConfigError(f"axis '{ax}' must be a LinearMotorAxis, got {type(getattr(self, ax)).__name__}")

    def axis(self, name: str) -> LinearMotorAxis:
        """The model of axis ``name`` ("x", "y" or "z").

        Parameters
        ----------
        name : {"x", "y", "z"}
            Axis letter.
        """
        return getattr(self, axis_name(name))

    def stacked_masses(self) -> dict[str, float]:
        """Mass each motor moves [kg]: ``{x: m_x + m_z, y: m_x + m_y + m_z, z: m_z}`` (Eq. 2)."""
        mx, my, mz = self.x.m, self.y.m, self.z.m
        return {"x": mx + mz, "y": mx + my + mz, "z": mz}

    def process_force(self, name: str, current, position, velocity, acceleration, *, v_eps: float = 0.0,
                      direction=None):
        """Process force on the workpiece along +axis by Eq. 2 [N].

        Parameters
        ----------
        name : {"x", "y", "z"}
            The axis.
        current : array_like
            Motor current [A].
        position : array_like
            Axis position [m].
        velocity : array_like
            Axis velocity [m/s].
        acceleration : array_like
            Axis acceleration [m/s^2].
        v_eps : float
            Sign-function ramp of the friction [m/s] (see :meth:`LinearMotorAxis.friction_force`).
        direction : array_like, optional
            Presliding friction state in [-1, 1] replacing the sign (see
            :func:`~drivesense.machine.presliding.presliding_direction`).
        """
        ax = self.axis(name)
        mass = self.stacked_masses()[name]
        return (ax.motor_force(current) - ax.restoring_force(position)
                - mass * signal_array(acceleration, "acceleration")
                - ax.cogging_force(position) - ax.friction_force(velocity, v_eps, direction))

    def to_dict(self) -> dict:
        """``{x: {...}, y: {...}, z: {...}}`` of plain types (SI)."""
        return {ax: getattr(self, ax).to_dict() for ax in AXES}


# ------------------------------------------------------------------ truth
@dataclass(frozen=True, eq=False)
class LinearAxisPhysics:
    """Simulation physics of one linear-motor axis: the model plus what it leaves out.

    Parameters
    ----------
    model : LinearMotorAxis
        Nominal parameters; the simulator's steady-state friction at the
        travel centre and its mean cogging equal the model's.
    travel : tuple of float
        Usable travel ``(min, max)`` [m].
    cogging_harmonics : tuple of (float, float)
        ``(amplitude [N], phase [rad])`` of cogging harmonics 1, 2, ... of the
        pole pitch (the model's table samples them).
    cogging_variation : float
        Relative change of the cogging amplitude along the travel [-] (one
        slow sine over ``travel``).
    friction : LuGreFriction or None
        Dynamic friction around the model's Stribeck curve: the simulator
        takes its presliding stiffness ``sigma0``, damping ``sigma1``,
        ripple, drift per metre (about the travel centre) and load
        coefficient; the levels ``F_C``, ``F_br``, ``v_s`` and the viscous
        ``sigma`` come from ``model`` (so run-to-run variation applies).
        None: the model's static Stribeck curve.
    km_droop : float
        Relative fall of ``K_m`` at ``rated_current`` (quadratic) [-].
    rated_current : float
        Rated motor current [A].
    max_current : float
        Current limit of the drive [A].
    current_bandwidth : float
        Current-loop bandwidth [rad/s] (first order).
    current_extra_pole : float
        Second pole of the real current loop [rad/s] (0: none).
    run_spread : float
        Run-to-run variation of friction and restoring levels, 1 sigma [-].
    weight : float
        Constant gravity force on the axis along +axis [N], net of any
        counterbalance (negative for a vertical axis whose + direction is
        up); the motor holds ``-weight`` at rest.  0 (default): horizontal.
    reflected_mass : float
        Rotating inertia reflected to the axis [kg] (a ball screw's rotor and
        screw, ``J (2 pi / lead)^2``): moved by this axis's motor only, never
        carried by another axis.  0 (default): a linear motor.
    """

    model: LinearMotorAxis
    travel: tuple[float, float]
    cogging_harmonics: tuple[tuple[float, float], ...]
    cogging_variation: float = 0.05
    friction: LuGreFriction | None = None
    km_droop: float = 0.04
    rated_current: float = 15.0
    max_current: float = 45.0
    current_bandwidth: float = 2.0 * math.pi * 600.0
    current_extra_pole: float = 2.0e4
    run_spread: float = 0.02
    weight: float = 0.0
    reflected_mass: float = 0.0

    def varied(self, rng: np.random.Generator) -> "LinearAxisPhysics":
        """A copy with run-to-run variation of the friction and restoring levels.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the variation (``run_spread`` relative standard deviation).
        """
        if self.run_spread <= 0:
            return self
        f = 1.0 + self.run_spread * rng.standard_normal(2)
        md = self.model.with_values(F_C=self.model.F_C * f[0], F_br=self.model.F_br * f[0],
                                    sigma=self.model.sigma * f[0], k=self.model.k * f[1])
        return replace(self, model=md)


@dataclass(frozen=True, eq=False)
class LinearMachinePhysics:
    """Simulation physics of the 3-axis linear-motor machine.

    Parameters
    ----------
    x, y, z : LinearAxisPhysics
        Per-axis physics.
    yaw_coupling : float
        Share of X's inertial force that reaches the Y drive through the
        slide's yaw [-].
    weight_shift : float
        Extra Y-guide normal load per metre of X travel away from its centre,
        as a share of the X+Z weight [1/m].
    exact : bool
        True: the estimators' own model (static Stribeck friction, the
        model's cogging table, no droop, lag, coupling or variation).  Set
        by :meth:`ideal`; the simulator's ideal switch is
        :meth:`drivesense.sim.machining.ProcessSettings.as_ideal`.
    carries : mapping of str to tuple of str
        Kinematics: the axes each axis carries (all of them, not only the
        next one), e.g. ``{"x": (), "y": ("x",), "z": ()}`` for a table X on
        a saddle Y and a Z head on a fixed column.  Default: Eq. 2 of the
        linear-motor machine (X carries Z; Y carries X and Z).
    """

    x: LinearAxisPhysics
    y: LinearAxisPhysics
    z: LinearAxisPhysics
    yaw_coupling: float = 0.01
    weight_shift: float = 2.0
    exact: bool = False
    carries: Mapping[str, tuple[str, ...]] = field(default_factory=lambda: {"x": ("z",), "y": ("x", "z"), "z": ()})

    def __post_init__(self) -> None:
        c = self.carries
        if not isinstance(c, Mapping) or set(c) != set(AXES) or any(
                isinstance(c[a], str) or not all(b in AXES and b != a for b in c[a]) for a in AXES):
            raise ConfigError(f"'carries' must map each of x, y, z to the other axes it carries, got {c!r}")
        object.__setattr__(self, "carries", {a: tuple(c[a]) for a in AXES})

    def moved_masses(self) -> dict[str, float]:
        """Mass each motor moves [kg]: its own, those of the axes it carries, and its reflected inertia.

        With the default :attr:`carries` and no reflected inertia this equals
        :meth:`ThreeAxisModel.stacked_masses` (Eq. 2).

        Returns
        -------
        dict of str to float
            Axis letter -> moved mass [kg].
        """
        out = {}
        for a in AXES:
            total = 0.0
            for b in AXES:
                if b == a or b in self.carries[a]:
                    total += self.axis(b).model.m
            out[a] = total + self.axis(a).reflected_mass
        return out

    def axis(self, name: str) -> LinearAxisPhysics:
        """Physics of axis ``name``.

        Parameters
        ----------
        name : {"x", "y", "z"}
            Axis letter.
        """
        return getattr(self, axis_name(name))

    def model(self) -> ThreeAxisModel:
        """The nominal estimator model (the true values identification should find).

        Its masses stack as in Eq. 2; the masses the simulated motors move
        (other kinematics, reflected inertia) are :meth:`moved_masses`.
        """
        return ThreeAxisModel(self.x.model, self.y.model, self.z.model)

    def ideal(self) -> "LinearMachinePhysics":
        """Physics reduced to exactly :meth:`model` (``exact``, no coupling or weight shift).

        The physics part of :meth:`drivesense.sim.machining.ProcessSettings.as_ideal`.

        Returns
        -------
        LinearMachinePhysics
        """
        return replace(self, exact=True, yaw_coupling=0.0, weight_shift=0.0)

    def varied(self, rng: np.random.Generator) -> "LinearMachinePhysics":
        """A copy with run-to-run variation (none for the exact model).

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the variation of each axis.
        """
        if self.exact:
            return self
        return replace(self, x=self.x.varied(rng), y=self.y.varied(rng), z=self.z.varied(rng))


# ------------------------------------------------------------------ preset
_PRESET = {  # m, K_m, k, s_r, travel, cogging A1, F_C, F_br, v_s, sigma, rated current
    "x": (160.0, 180.0, 200.0, 0.140, (0.0, 0.32), 24.0, 38.0, 55.0, 4.0e-3, 700.0, 15.0),
    "y": (200.0, 260.0, 180.0, 0.190, (0.0, 0.35), 32.0, 52.0, 75.0, 5.0e-3, 900.0, 18.0),
    "z": (110.0, 140.0, 150.0, 0.120, (0.0, 0.30), 18.0, 30.0, 42.0, 3.5e-3, 600.0, 12.0),
}


def linear_machine_physics(pole_pitch: float = 0.023, table_size: int = 64) -> LinearMachinePhysics:
    """Full physics of a five-axis-centre-like machine with X/Y/Z linear motors (assumed values).

    The third paper gives no parameters of its HSC30 linear; every value here
    is an assumption of plausible magnitude: moving masses X 160 kg, Y 200 kg,
    Z 110 kg (so the motors move 270, 470 and 110 kg), motor constants 180,
    260 and 140 N/A, restoring constants 200, 180, 150 N/m about rest points
    140, 190, 120 mm (about 30 N at the travel ends), cogging 24, 32, 18 N at
    the 23 mm pole pitch with 30 % second and 12 % third harmonic, Coulomb
    friction 38, 52, 30 N, breakaway 55, 75, 42 N, Stribeck velocities 4, 5,
    3.5 mm/s and viscous 700, 900, 600 N s/m.  On top: LuGre presliding
    (15 um, preloaded rolling guides), friction ripple (3 % at 61 mm, 1.5 % at 7.3 mm) and drift (+-3 % over
    the travel), 1 % extra friction per newton of normal load, 5 % cogging
    amplitude change along the travel, 4 % motor-constant droop at rated
    current, a 600 Hz current loop with a 20 000 rad/s extra pole, 1 % yaw
    coupling of X's inertial force into Y, a Y-guide load that grows by twice
    the X+Z weight per metre of X away from its centre, and 2 % run-to-run
    variation.  The Z
    axis's weight is assumed fully counterbalanced.

    Parameters
    ----------
    pole_pitch : float
        Pole pitch of all three motors [m].
    table_size : int
        Points of the model's cogging table over one pole pitch.

    Returns
    -------
    LinearMachinePhysics
    """
    axes = {}
    phases = {"x": (0.4, 1.9, 0.7), "y": (2.2, 0.3, 2.9), "z": (1.1, 2.6, 0.2)}
    for ax, (m, km, k, s_r, travel, a1, fc, fbr, vs, sig, i_r) in _PRESET.items():
        harm = ((a1, phases[ax][0]), (0.30 * a1, phases[ax][1]), (0.12 * a1, phases[ax][2]))
        model = LinearMotorAxis(K_m=km, k=k, s_r=s_r, m=m, F_C=fc, F_br=fbr, v_s=vs, sigma=sig,
                                cogging=harmonic_cogging_table(harm, table_size), pole_pitch=pole_pitch)
        length = travel[1] - travel[0]
        fric = LuGreFriction(F_c=fc, F_s=fbr, v_s=vs, sigma0=fc / 15.0e-6, sigma1=2.0e4, sigma2=sig,
                             ripples=(Ripple(0.061, 0.03 * fc, 0.5), Ripple(0.0073, 0.015 * fc, 1.7)),
                             drift_per_m=0.06 * fc / length, load_coefficient=0.01)
        axes[ax] = LinearAxisPhysics(model=model, travel=travel, cogging_harmonics=harm, friction=fric,
                                     rated_current=i_r, max_current=3.0 * i_r)
    return LinearMachinePhysics(**axes)


def linear_machine_model() -> ThreeAxisModel:
    """The nominal model of :func:`linear_machine_physics` (the true values, assumed)."""
    return linear_machine_physics().model()
