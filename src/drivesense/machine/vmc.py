"""A ball-screw 3-axis vertical machining centre (VMC) seen at controller level (assumed values).

At the rates a controller trace is logged at (50-500 Hz) a ball-screw axis is
a rigid body: the screw's axial mode (100-300 Hz on a machine this size) is
above what the trace resolves, so the axis is the linear-motor machine's
model with ball-screw values (:mod:`drivesense.machine.linear_motor`):

* force constant ``K_m = K_t 2 pi / lead`` [N/A] (:func:`ball_screw_force_constant`);
* the moved mass adds the rotor, coupling and screw inertia reflected through
  the lead, ``J (2 pi / lead)^2`` (:func:`screw_reflected_mass`), which only
  the axis's own motor moves (:attr:`LinearAxisPhysics.reflected_mass
  <drivesense.machine.linear_motor.LinearAxisPhysics.reflected_mass>`);
* motor torque ripple and lead error repeat with every screw turn: the
  cogging mechanism with ``pole_pitch = lead`` (harmonics 1-3 per turn);
* no restoring spring (``k = 0``; the cable chains' pull is negligible);
* LuGre friction of nut, support bearings and guides (Coulomb levels of a few
  hundred newtons, more than on a linear motor's guides), Stribeck, viscous,
  presliding over 10 um, a friction ripple once per screw turn and along the
  guides, 3 % drift over the travel, and 5 % extra Coulomb friction per newton
  of axial load on the nut (a screw efficiency of about 0.95).

Kinematics of a typical VMC: the table X rides on the saddle Y (Y carries X),
the spindle head Z runs on the fixed column and carries only itself
(:attr:`LinearMachinePhysics.carries
<drivesense.machine.linear_motor.LinearMachinePhysics.carries>`).  Z is
vertical (+z up): the head's weight, net of a nitrogen-cylinder
counterbalance, is a constant force along -z that the motor holds
(:attr:`LinearAxisPhysics.weight
<drivesense.machine.linear_motor.LinearAxisPhysics.weight>`), and the nut
carries it, so Z's Coulomb level includes ``0.05 |weight|``.

Every value is an assumption of plausible magnitude:

======================  ===============  ===============  ===============
value                   X (table)        Y (saddle)       Z (head)
======================  ===============  ===============  ===============
travel [m]              0 ... 0.6        0 ... 0.4        0 ... 0.4
screw lead [mm]         16               16               12
screw [mm]              32 x 1100        40 x 900         32 x 800
K_t [N m/A]             1.2              1.5              1.0
K_m [N/A]               471.2            589.0            523.6
rated / max current [A] 5.8 / 17.5       7.3 / 22         8 / 24
rotor + coupling J      0.0012 + 0.0002  0.0020 + 0.0002  0.0020 + 0.0002
[kg m^2]                                                  (brake)
reflected mass [kg]     353.0            613.1            780.4
own mass [kg]           300 (table 230,  380              350
                        part/fixture 70)
moved mass [kg]         653.0            1293.1           1130.4
net weight [N]          0                0                -2060 (350 kg,
                                                          40 % balanced)
Coulomb F_C [N]         180              260              200 + 103 (weight)
breakaway F_br [N]      1.3 F_C          1.3 F_C          1.3 F_C
Stribeck v_s [mm/s]     3                3                3
viscous [N s/m]         400              500              450
ripple per turn [N]     25, 10, 3.75     30, 12, 4.5      25, 10, 3.75
(harmonics 1, 2, 3)
======================  ===============  ===============  ===============

The holding current of Z is ``-weight / K_m = +3.9 A`` (a positive current
lifts the head).  Current loops: 800 Hz bandwidth and a 20 000 rad/s extra
pole; 3 % motor-constant droop at rated current; 0.5 % of X's inertial force
reaches Y through the saddle's yaw; 2 % run-to-run variation of the friction.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from drivesense.machine.friction import LuGreFriction, Ripple
from drivesense.machine.linear_motor import (LinearAxisPhysics, LinearMachinePhysics, LinearMotorAxis,
                                             harmonic_cogging_table)
from drivesense.machine.milling import check_number

__all__ = ["ball_screw_force_constant", "screw_reflected_mass", "screw_inertia", "VMC_AXES", "vmc_physics",
           "machine_variant", "GRAVITY", "NUT_LOAD_COEFFICIENT"]

#: Standard gravity [m/s^2].
GRAVITY = 9.81
#: Extra Coulomb friction per newton of axial load on a ball-screw nut [-] (efficiency about 0.95, assumed).
NUT_LOAD_COEFFICIENT = 0.05
_STEEL_DENSITY = 7850.0

#: Per axis: lead [m], K_t [N m/A], rated current [A], rotor+coupling J [kg m^2], screw diameter and length [m],
#: own mass [kg], travel [m], Coulomb [N], viscous [N s/m], ripple harmonic 1 [N], net weight [N].
VMC_AXES = {
    "x": dict(lead=0.016, K_t=1.2, rated_current=5.8, J_motor=0.0014, screw=(0.032, 1.1), mass=300.0,
              travel=(0.0, 0.6), F_C=180.0, sigma=400.0, ripple=25.0, weight=0.0),
    "y": dict(lead=0.016, K_t=1.5, rated_current=7.3, J_motor=0.0022, screw=(0.040, 0.9), mass=380.0,
              travel=(0.0, 0.4), F_C=260.0, sigma=500.0, ripple=30.0, weight=0.0),
    "z": dict(lead=0.012, K_t=1.0, rated_current=8.0, J_motor=0.0022, screw=(0.032, 0.8), mass=350.0,
              travel=(0.0, 0.4), F_C=200.0, sigma=450.0, ripple=25.0, weight=-0.6 * 350.0 * GRAVITY),
}


def ball_screw_force_constant(K_t: float, lead: float) -> float:
    """Force constant of a ball-screw axis at controller level, ``K_t 2 pi / lead``.

    Parameters
    ----------
    K_t : float
        Motor torque constant [N*m/A].
    lead : float
        Screw lead [m/rev].

    Returns
    -------
    float
        Force constant [N/A].
    """
    return check_number(K_t, "K_t", positive=True) * 2.0 * math.pi / check_number(lead, "lead", positive=True)


def screw_reflected_mass(J: float, lead: float) -> float:
    """Rotating inertia seen as a mass on the axis, ``J (2 pi / lead)^2``.

    Parameters
    ----------
    J : float
        Inertia of rotor, coupling and screw [kg*m^2].
    lead : float
        Screw lead [m/rev].

    Returns
    -------
    float
        Reflected mass [kg].
    """
    return check_number(J, "J", nonneg=True) * (2.0 * math.pi / check_number(lead, "lead", positive=True)) ** 2


def screw_inertia(diameter: float, length: float, density: float = _STEEL_DENSITY) -> float:
    """Inertia of a solid screw shaft about its axis, ``pi rho L d^4 / 32``.

    Parameters
    ----------
    diameter : float
        Shaft diameter [m].
    length : float
        Shaft length [m].
    density : float
        Material density [kg/m^3] (steel by default).

    Returns
    -------
    float
        Inertia [kg*m^2].
    """
    return math.pi * density * length * diameter ** 4 / 32.0


def vmc_physics(table_size: int = 64) -> LinearMachinePhysics:
    """Full physics of the ball-screw vertical machining centre (module table; assumed values).

    Parameters
    ----------
    table_size : int
        Points of the model's ripple table over one screw lead.

    Returns
    -------
    LinearMachinePhysics
        Axes with ``pole_pitch = lead``, ``k = 0``, reflected masses and Z's
        net weight; kinematics ``carries = {x: (), y: (x,), z: ()}``.
    """
    axes = {}
    phases = {"x": (0.7, 2.1, 1.3), "y": (1.9, 0.4, 2.6), "z": (2.8, 1.2, 0.5)}
    for ax, v in VMC_AXES.items():
        lead = v["lead"]
        weight = float(v["weight"])
        fc = v["F_C"] + NUT_LOAD_COEFFICIENT * abs(weight)
        fbr = 1.3 * fc
        vs = 3.0e-3
        a1 = v["ripple"]
        harm = ((a1, phases[ax][0]), (0.4 * a1, phases[ax][1]), (0.15 * a1, phases[ax][2]))
        model = LinearMotorAxis(K_m=ball_screw_force_constant(v["K_t"], lead), k=0.0,
                                s_r=0.5 * sum(v["travel"]), m=v["mass"], F_C=fc, F_br=fbr, v_s=vs,
                                sigma=v["sigma"], cogging=harmonic_cogging_table(harm, table_size), pole_pitch=lead)
        length = v["travel"][1] - v["travel"][0]
        fric = LuGreFriction(F_c=fc, F_s=fbr, v_s=vs, sigma0=fc / 10.0e-6, sigma1=3.0e4, sigma2=v["sigma"],
                             ripples=(Ripple(lead, 0.04 * fc, 0.9), Ripple(0.0507, 0.02 * fc, 2.2)),
                             drift_per_m=0.06 * fc / length, load_coefficient=NUT_LOAD_COEFFICIENT)
        j_total = v["J_motor"] + screw_inertia(*v["screw"])
        axes[ax] = LinearAxisPhysics(
            model=model, travel=v["travel"], cogging_harmonics=harm, cogging_variation=0.05, friction=fric,
            km_droop=0.03, rated_current=v["rated_current"], max_current=3.0 * v["rated_current"],
            current_bandwidth=2.0 * math.pi * 800.0, current_extra_pole=2.0e4, run_spread=0.02,
            weight=weight, reflected_mass=screw_reflected_mass(j_total, lead))
    return LinearMachinePhysics(**axes, yaw_coupling=0.005, weight_shift=0.0,
                                carries={"x": (), "y": ("x",), "z": ()})


def machine_variant(physics: LinearMachinePhysics, rng: np.random.Generator, *, friction_spread: float = 0.08,
                    ripple_spread: float = 0.15, weight_spread: float = 0.05, mass_spread: float = 0.03,
                    table_size: int = 64) -> LinearMachinePhysics:
    """One machine of the series: the preset with its build spread drawn once (1 sigma, relative).

    Per axis: the friction levels (Coulomb, breakaway, viscous together),
    the ripple amplitudes, the net weight and the own moving mass (e.g. the
    fixture and part on the table) each scaled by ``1 + spread N(0, 1)``.

    Parameters
    ----------
    physics : LinearMachinePhysics
        The nominal machine (e.g. :func:`vmc_physics`).
    rng : numpy.random.Generator
        Source of the spread.
    friction_spread : float
        Spread of the friction levels [-].
    ripple_spread : float
        Spread of the ripple (cogging-mechanism) amplitudes [-].
    weight_spread : float
        Spread of the net weight [-].
    mass_spread : float
        Spread of each axis's own moving mass [-].
    table_size : int
        Points of the model's ripple table.

    Returns
    -------
    LinearMachinePhysics
    """
    axes = {}
    for ax in ("x", "y", "z"):
        a = physics.axis(ax)
        f_fr, f_rip, f_w, f_m = 1.0 + np.array([friction_spread, ripple_spread, weight_spread, mass_spread]) \
            * rng.standard_normal(4)
        harm = tuple((amp * f_rip, ph) for amp, ph in a.cogging_harmonics)
        md = a.model.with_values(F_C=a.model.F_C * f_fr, F_br=a.model.F_br * f_fr, sigma=a.model.sigma * f_fr,
                                 m=a.model.m * f_m, cogging=harmonic_cogging_table(harm, table_size))
        fric = a.friction.scaled(f_fr) if a.friction is not None else None
        axes[ax] = replace(a, model=md, cogging_harmonics=harm, friction=fric, weight=a.weight * f_w)
    return replace(physics, **axes)
