"""Every scenario ``drivesense simulate`` runs, by name, with a one-line description.

Three machines:

* the ball-screw stage of the first paper (:mod:`drivesense.sim.scenarios`,
  10 kHz): the ten end-milling cuts, the idling runs of the feed-direction
  ones and the FRF excitations;
* the 3-axis linear-motor machine of the third paper
  (:mod:`drivesense.sim.machining`, 250 Hz NC traces): the milling processes
  at one set of cutting parameters and the identification air moves;
* the ball-screw vertical machining centre (:mod:`drivesense.sim.vmc`, 50 Hz
  controller traces): the part programs ``vmc_<program>`` and their dry runs
  ``vmc_air_<program>`` (machine seed 0, the programs' default cutting
  parameters unless given).

:func:`simulate_scenario` returns a list of recordings: one for every
scenario but ``air_moves`` (nine: three per axis).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivesense.errors import ConfigError
from drivesense.recording import Recording

__all__ = ["AIR_MOVES", "VMC_PREFIX", "VMC_AIR_PREFIX", "ProcessParameters", "describe_scenarios", "is_process",
           "is_vmc_program", "simulate_scenario"]

#: Name of the linear machine's identification air moves (several recordings).
AIR_MOVES = "air_moves"

#: Prefix of the machining centre's part programs (``vmc_<program>``) and of their dry runs.
VMC_PREFIX = "vmc_"
VMC_AIR_PREFIX = "vmc_air_"

_PROCESS_KINDS = {"groove": "groove (slot) along {d}", "side": "side milling (up) along {d}"}


@dataclass(frozen=True)
class ProcessParameters:
    """Cutting parameters of a linear-machine process (defaults: the middle of the third paper's Table 1).

    Parameters
    ----------
    a_p : float
        Axial depth of cut [m] (the ramp's final depth).
    a_e : float
        Radial depth of cut [m] (grooves use the tool diameter whatever is given).
    v_f : float
        Feed speed [m/s].
    n : float
        Spindle speed [min^-1].
    """

    a_p: float = 2e-3
    a_e: float = 5e-3
    v_f: float = 500 / 60e3
    n: float = 4500.0

    def describe(self) -> str:
        """The parameters in the units of the paper's Table 1.

        Returns
        -------
        str
            e.g. ``"a_p 2 mm, a_e 5 mm, v_f 500 mm/min, n 4500 min^-1"``.
        """
        return (f"a_p {self.a_p * 1e3:g} mm, a_e {self.a_e * 1e3:g} mm, v_f {self.v_f * 60e3:g} mm/min, "
                f"n {self.n:g} min^-1")


def _process_line(name: str) -> str:
    kind, _, direction = name.partition("_")
    if kind in _PROCESS_KINDS:
        what = _PROCESS_KINDS[kind].format(d=direction)
    elif name == "pocket_ccw":
        what = "circular pocket, counter-clockwise (climb milling)"
    elif name == "pocket_cw":
        what = "circular pocket, clockwise (up milling)"
    else:
        what = "ramp along -y rising in +z"
    return f"linear machine: {what}, for estimate --method model|lstm|hybrid"


def describe_scenarios() -> dict[str, str]:
    """Every scenario name with a one-line description, ball-screw ones first.

    The ball-screw stage records at 10 kHz, the linear machine's NC trace at
    250 Hz, the machining centre's controller trace at 50 Hz; every cut and
    process carries its true force (dry runs none).  The processes'
    cutting parameters are :class:`ProcessParameters`.

    Returns
    -------
    dict of str to str
        Name -> description.
    """
    from drivesense.sim.excitation import EXCITATIONS
    from drivesense.sim.machining import process_names
    from drivesense.sim.nc_programs import describe_nc_program, nc_programs
    from drivesense.sim.scenarios import paper_conditions

    out: dict[str, str] = {}
    conditions = paper_conditions()
    for c in conditions:
        how = "X feeds" if c.direction == "feed" else "X stands (cross-feed)"
        out[c.name] = f"ball screw: end-milling cut, {how}, r = {c.radial_depth * 1e3:g} mm, {c.spindle_rpm:g} min^-1"
    for c in conditions:
        if c.direction == "feed":
            out[f"idle_{c.name}"] = f"ball screw: {c.name} without cutting, for estimate --idle"
    for kind in EXCITATIONS:
        out[f"frf_{kind}"] = f"ball screw: {kind} on X's current reference while moving, for identify frf"
    for name in process_names():
        out[name] = _process_line(name)
    out[AIR_MOVES] = "linear machine: 9 air moves (3 per axis), a folder of .nc files, for identify linear"
    for name in nc_programs():
        out[f"{VMC_PREFIX}{name}"] = f"machining centre (ball screws, 50 Hz controller trace + dynamometer force): " \
                                     f"{describe_nc_program(name)}"
    for name in nc_programs():
        out[f"{VMC_AIR_PREFIX}{name}"] = f"machining centre: dry run of {name} (same moves, spindle on, no force)"
    return out


def is_process(name: str) -> bool:
    """Whether `name` is a linear-machine process (which takes :class:`ProcessParameters`).

    Parameters
    ----------
    name : str
        Scenario name.

    Returns
    -------
    bool
    """
    from drivesense.sim.machining import process_names

    return name in process_names()


def is_vmc_program(name: str) -> bool:
    """Whether `name` is a machining-centre part program or its dry run (which take :class:`ProcessParameters`).

    Parameters
    ----------
    name : str
        Scenario name.

    Returns
    -------
    bool
    """
    from drivesense.sim.nc_programs import nc_programs

    program = name[len(VMC_AIR_PREFIX):] if name.startswith(VMC_AIR_PREFIX) else name[len(VMC_PREFIX):]
    return name.startswith(VMC_PREFIX) and program in nc_programs()


def simulate_scenario(name: str, *, seed: int = 1, ideal: bool = False,
                      params: ProcessParameters | None = None, events=()) -> list[Recording]:
    """Simulate a scenario of :func:`describe_scenarios` by name.

    Parameters
    ----------
    name : str
        Scenario name.
    seed : int, optional
        Seed of every random element.
    ideal : bool, optional
        Data from exactly the estimators' model (each simulator's ``as_ideal``).
    params : ProcessParameters, optional
        Cutting parameters of a linear-machine process (default:
        :class:`ProcessParameters`) or of a machining-centre program (default:
        the programs' own, :data:`drivesense.sim.nc_programs.DEFAULT_CUT`);
        refused for the other scenarios.
    events : sequence of ProcessEvent, optional
        Events injected into a ball-screw feed cut (:mod:`drivesense.sim.process_events`); refused for
        the other scenarios.

    Returns
    -------
    list of Recording
        One recording; nine for ``air_moves``.

    Raises
    ------
    ConfigError
        Unknown name, or `params` for a scenario that is not a process.
    """
    from drivesense.sim.machining import simulate_air_moves, simulate_process
    from drivesense.sim.scenarios import (ScenarioSettings, condition_by_name, simulate_cut, simulate_frf_excitation,
                                          simulate_idle)

    known = describe_scenarios()
    if events and name not in known:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(known)}")
    if events and (is_process(name) or is_vmc_program(name) or name == AIR_MOVES or name.startswith("frf_")):
        raise ConfigError(f"events (--event) are simulated on the ball-screw feed cuts (feed_*), not on {name!r}")
    if name not in known:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(known)}")
    if params is not None and not (is_process(name) or is_vmc_program(name)):
        raise ConfigError(f"cutting parameters apply to the linear machine's processes and the machining centre's "
                          f"programs, not to {name!r}")
    if is_vmc_program(name):
        from drivesense.sim.vmc import simulate_nc_program

        air = name.startswith(VMC_AIR_PREFIX)
        program = name[len(VMC_AIR_PREFIX if air else VMC_PREFIX):]
        cut = {} if params is None else {"a_p": params.a_p, "a_e": params.a_e, "v_f": params.v_f, "n": params.n}
        return [simulate_nc_program(program, rate=50.0, air=air, seed=seed, ideal=ideal, **cut)]
    if is_process(name):
        p = params or ProcessParameters()
        return [simulate_process(name, p.a_p, p.a_e, p.v_f, p.n, seed=seed, ideal=ideal)]
    if name == AIR_MOVES:
        return simulate_air_moves(seed=seed, ideal=ideal)
    settings = ScenarioSettings().as_ideal() if ideal else ScenarioSettings()
    if name.startswith("frf_"):
        return [simulate_frf_excitation(name[4:], settings, seed=seed)]
    cond, is_idle = condition_by_name(name)
    if events:
        if is_idle or cond.direction != "feed" or ideal:
            raise ConfigError(f"events (--event) are simulated on the ball-screw feed cuts (feed_*), with the "
                              f"full physics, not on {name!r}")
        from drivesense.sim.process_events import simulate_event_cut

        return [simulate_event_cut(cond, events=events, settings=settings, seed=seed)]
    return simulate_idle(cond, settings, repeats=1, seed=seed) if is_idle else [simulate_cut(cond, settings, seed=seed)]
