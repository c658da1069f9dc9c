"""The cases of ``drivesense bench events``: simulated cuts with known events, and event-free programs.

Every case is a cut of the first paper's ball-screw stage (X feeding) with a
tool drawn over 1-4 teeth, 1000-12 000 min^-1, three radial depths, up and
down milling, 0-5 um runout; the force is estimated by the ``vibration``
method (friction map from idle runs of the same feed) and handed to the
detectors (:mod:`drivesense.events.pipeline`).  A case returns what the
detectors raised next to the truth; :mod:`drivesense.bench.events` scores them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
from scipy.ndimage import maximum_filter1d

from drivesense.estimate import make
from drivesense.machine.milling import CuttingCoefficients, EndMill, engagement_angles
from drivesense.machine.presets import table1_axis, table1_signal
from drivesense.machine.stability import critical_depth
from drivesense.machine.tool_dynamics import ToolDynamics
from drivesense.events.pipeline import default_detectors, detector_inputs, estimate_limits, run_detectors
from drivesense.events.teach import TeachInDetector, teach
from drivesense.nc_context import CONTEXT_CHANNELS
from drivesense.sim.process_events import ProcessEvent, simulate_event_cut
from drivesense.sim.scenarios import CutCondition, ScenarioSettings, simulate_idle

__all__ = ["Case", "plan_event_cases", "plan_programs", "run_case", "run_program", "bench_estimator", "DIAMETER",
           "CONTEXT_VARIANTS"]

#: The scenario tool's diameter [m].
DIAMETER = 6e-3
_T_CONTACT = 1.5
_CHIP = 25e-6


@dataclass(frozen=True)
class Case:
    """One simulated cut (or program of runs) of the bench.

    Parameters
    ----------
    kind : str
        ``breakage``, ``chipping``, ``collision``, ``overload``, ``missing_tool``, ``chatter``, ``stable``
        or ``event_free`` (a program).
    teeth : int
        Flutes of the 6 mm end mill.
    rpm : float
        Spindle speed [min^-1].
    radial_depth : float
        Radial depth of cut [m].
    mode : str
        ``up`` or ``down`` milling.
    axial_depth : float
        Axial depth of cut [m].
    runout : float
        Runout of the tool [m].
    seed : int
        Seed of the simulation.
    duration : float
        Trace length [s].
    events : tuple of ProcessEvent
        Injected events.
    dynamics : ToolDynamics or None
        Tool modes (chatter cases).
    exit_length : float or None
        Length of the part [m] (the tool leaves it).
    lobe_depth : float or None
        The stability lobes' critical depth at this speed [m].
    overrides : tuple
        Per monitored run of a program, its feed-override changes ``(time [s], factor)``.
    """

    kind: str
    teeth: int
    rpm: float
    radial_depth: float
    mode: str
    axial_depth: float
    runout: float
    seed: int
    duration: float
    events: tuple = ()
    dynamics: ToolDynamics | None = None
    exit_length: float | None = None
    lobe_depth: float | None = None
    overrides: tuple = field(default=())

    @property
    def feed_speed(self) -> float:
        """Feed [m/s]: 25 um per tooth, at least 1 mm/s."""
        return max(_CHIP * self.teeth * self.rpm / 60.0, 1e-3)

    @property
    def full_engagement_s(self) -> float:
        """When the tool is fully in the part [s]."""
        return _T_CONTACT + 0.5 * DIAMETER / self.feed_speed

    def condition(self) -> CutCondition:
        """The cutting condition."""
        name = f"{self.kind}_z{self.teeth}_n{self.rpm:.0f}_ae{self.radial_depth * 1e3:g}_{self.mode}"
        return CutCondition(name, "feed", self.radial_depth, self.rpm, feed_speed=self.feed_speed,
                            axial_depth=self.axial_depth, mode=self.mode)

    def tool(self) -> EndMill:
        """The end mill."""
        return EndMill(DIAMETER, self.teeth, 30.0, runout=self.runout, runout_phase=0.4)

    def settings(self) -> ScenarioSettings:
        """Trace length and the rest of the scenario."""
        return replace(ScenarioSettings(), tool=self.tool(), duration=self.duration, t_contact=_T_CONTACT)

    def describe(self) -> dict:
        """The case as the bench's rows list it."""
        return {"kind": self.kind, "teeth": self.teeth, "spindle_rpm": round(self.rpm, 1),
                "radial_depth_mm": self.radial_depth * 1e3, "mode": self.mode,
                "axial_depth_mm": round(self.axial_depth * 1e3, 4), "runout_um": round(self.runout * 1e6, 2),
                "seed": self.seed, "duration_s": self.duration}


def _draw_condition(rng: np.random.Generator, teeth=None) -> dict:
    return {"teeth": int(teeth or rng.integers(1, 5)),
            "rpm": float(np.exp(rng.uniform(math.log(1000.0), math.log(12000.0)))),
            "radial_depth": float(rng.choice([1.5e-3, 3e-3, 6e-3])),
            "mode": str(rng.choice(["down", "up"])), "runout": float(rng.uniform(0.0, 5e-6))}


def _event_time(case: Case, rng: np.random.Generator) -> float:
    return case.full_engagement_s + float(rng.uniform(0.3, 1.5))


def plan_event_cases(seed: int = 0, *, counts: dict | None = None) -> list[Case]:
    """Cuts with one event each (and stable cuts near the stability limit).

    Parameters
    ----------
    seed : int
        Seed of the draw.
    counts : dict, optional
        Cases per kind (default: breakage 60, chipping 60, collision 25, overload 25, missing_tool 20,
        chatter 40, stable 40).
    """
    counts = counts or {"breakage": 60, "chipping": 60, "collision": 25, "overload": 25, "missing_tool": 20,
                        "chatter": 40, "stable": 40}
    rng = np.random.default_rng(seed)
    cases: list[Case] = []
    k = 0
    for kind, count in counts.items():
        made = 0
        while made < count:
            k += 1
            cond = _draw_condition(rng, teeth=None if kind != "chipping" else int(rng.integers(2, 5)))
            base = Case(kind, axial_depth=float(rng.uniform(0.5e-3, 2e-3)), seed=1000 + k, duration=0.0, **cond)
            t_full = base.full_engagement_s
            if kind in ("chatter", "stable"):
                dyn = ToolDynamics.symmetric(float(rng.choice([350.0, 500.0, 650.0])), float(rng.uniform(0.02, 0.04)),
                                             float(rng.uniform(2e6, 8e6)))
                st, ex = engagement_angles(DIAMETER, base.radial_depth, base.mode)
                lim = critical_depth(dyn, CuttingCoefficients.aluminium(), base.teeth, st, ex, base.rpm)
                ratio = rng.uniform(1.5, 3.0) if kind == "chatter" else (
                    rng.uniform(0.8, 0.95) if made < 0.6 * count else rng.uniform(0.5, 0.8))
                depth = lim * ratio
                if not (0.2e-3 <= depth <= 6e-3):
                    continue
                case = replace(base, axial_depth=float(depth), dynamics=dyn, lobe_depth=float(lim),
                               duration=t_full + 2.0)
            else:
                case = replace(base, duration=0.0)
                t_ev = _event_time(case, rng)
                ev = {"breakage": lambda: ProcessEvent("breakage", t_ev, flute=int(rng.integers(0, case.teeth))),
                      "chipping": lambda: ProcessEvent("chipping", t_ev, flute=int(rng.integers(0, case.teeth)),
                                                       edge_loss=float(rng.uniform(0.3, 0.8))),
                      "collision": lambda: ProcessEvent("collision", t_ev, force_n=float(rng.uniform(400, 1500)),
                                                        rise_s=float(rng.uniform(1e-4, 1e-3))),
                      "overload": lambda: ProcessEvent("overload", t_ev, force_n=float(rng.uniform(300, 800)),
                                                       rise_s=float(rng.uniform(0.05, 0.5))),
                      "missing_tool": lambda: ProcessEvent("missing_tool", _T_CONTACT)}[kind]()
                case = replace(case, events=(ev,), duration=max(t_ev, t_full) + 1.0)
            cases.append(case)
            made += 1
    return cases


def plan_programs(seed: int = 0, *, hours: float = 10.0, runs_per_program: int = 8,
                  run_s: float = 20.0) -> list[Case]:
    """Event-free programs: each taught from its first 3 runs, the rest with feed-rate overrides.

    Parameters
    ----------
    seed : int
        Seed of the draw.
    hours : float
        Total simulated time [h].
    runs_per_program : int
        Runs per program (3 teach + the rest monitored).
    run_s : float
        Length of a run [s].
    """
    rng = np.random.default_rng(10_000 + seed)
    programs = []
    total = 0.0
    k = 0
    while total < hours * 3600.0:
        k += 1
        cond = _draw_condition(rng)
        case = Case("event_free", axial_depth=float(rng.uniform(0.5e-3, 2e-3)), seed=100_000 + 100 * k,
                    duration=run_s, **cond)
        # the part ends before the run does on some programs: an exit, then air
        travel = case.feed_speed * (run_s - _T_CONTACT)
        exit_length = float(rng.uniform(0.4, 0.8) * travel) if rng.random() < 0.5 else None
        overrides = []
        for _ in range(runs_per_program - 3):
            times = np.sort(rng.uniform(case.full_engagement_s + 0.5, run_s - 1.0, size=int(rng.integers(1, 4))))
            overrides.append(tuple((float(t), float(rng.uniform(0.5, 1.5))) for t in times))
        programs.append(replace(case, exit_length=exit_length, overrides=tuple(overrides)))
        total += runs_per_program * run_s
    return programs


@lru_cache(maxsize=16)
def bench_estimator(feed_speed: float, duration: float):
    """The vibration estimator with a friction map from 3 idle runs of this feed (covering overrides).

    Parameters
    ----------
    feed_speed : float
        Feed [m/s].
    duration : float
        Length of the runs it serves [s] (the idle runs are 1.6 times longer).
    """
    cond = CutCondition("idle", "feed", 1.5e-3, 4000.0, feed_speed=feed_speed)
    settings = replace(ScenarioSettings(), duration=1.6 * duration)
    est = make("vibration", axis=table1_axis(), signal=table1_signal())
    est.fit(simulate_idle(cond, settings, seed=5000))
    return est


def _detect(case: Case, rec, limit_n: float, limits=None):
    est = bench_estimator(round(case.feed_speed, 9), case.duration)
    forces = est.estimate(rec)
    inputs = detector_inputs(rec, forces)
    detectors = default_detectors("x", teeth=case.teeth, force_limit_n=limit_n, **estimate_limits(est))
    if limits is not None:
        detectors.append(TeachInDetector(limits))
    report = run_detectors(inputs, detectors, check=False)
    return inputs, report


def _events_json(report) -> list[dict]:
    return [{"kind": e.kind, "time_s": e.time_s, "detector": e.detector, "confidence": e.confidence,
             "latency_s": e.latency_s, **{k: v for k, v in e.evidence.items() if isinstance(v, (int, float, str))}}
            for e in report.events]


def run_case(case: Case) -> dict:
    """Simulate one event case, detect, and return the truth and the detections.

    Parameters
    ----------
    case : Case
        From :func:`plan_event_cases`.
    """
    settings = case.settings()
    rec = simulate_event_cut(case.condition(), events=case.events, settings=settings, dynamics=case.dynamics,
                             seed=case.seed)
    truth = rec.meta["truth"]
    limit = 3.0 * truth["stable_peak_n"] + 20.0
    limits = None
    if case.kind == "missing_tool":
        good = [simulate_event_cut(case.condition(), settings=settings, seed=case.seed + 1 + j) for j in range(3)]
        est = bench_estimator(round(case.feed_speed, 9), case.duration)
        limits = teach([detector_inputs(g, est.estimate(g)) for g in good], ["force_x"])
    inputs, report = _detect(case, rec, limit, limits)
    out = {**case.describe(), "truth": {k: truth[k] for k in ("events", "chatter_onset_s", "stable_peak_n")},
           "limit_n": limit, "detected": _events_json(report), "estimator_latency_s": inputs.meta["latency_s"],
           "fs": rec.fs}
    if case.lobe_depth is not None:
        out["lobe_depth_mm"] = case.lobe_depth * 1e3
        out["lobe_label"] = "chatter" if case.axial_depth > case.lobe_depth else "stable"
    force = rec["force_x"]
    if case.kind in ("collision", "overload"):
        over = np.flatnonzero(np.abs(force) > limit)
        out["true_crossing_s"] = float(rec.t0 + over[0] / rec.fs) if over.size else None
    if case.kind == "chatter" and truth["chatter_onset_s"] is not None:
        rev = int(round(60.0 / case.rpm * rec.fs))
        peaks = np.maximum.accumulate(np.abs(force))       # the largest force so far, for the 2x check
        out["true_peak_by_time"] = {"rev_samples": rev, "t": [], "peak_n": []}
        for e in out["detected"]:
            if e["kind"] == "chatter":
                i = int(round((e["time_s"] - rec.t0) * rec.fs))
                out["true_peak_by_time"]["t"].append(e["time_s"])
                out["true_peak_by_time"]["peak_n"].append(float(np.max(np.abs(force[max(0, i - rev):i + 1])))
                                                           if i < force.size else float(peaks[-1]))
    return out


#: What the event-free runs are monitored with: no NC context (the drive signals alone), the controller's
#: context without an in-cut flag (tool, program, block, overrides, execution state), and with it.
CONTEXT_VARIANTS = {"none": (), "nc": tuple(c for c in CONTEXT_CHANNELS if c != "in_cut"),
                    "nc_in_cut": CONTEXT_CHANNELS}


def _with_context(inputs, variant: str):
    """The detector inputs with only the context channels of ``variant`` (see :data:`CONTEXT_VARIANTS`)."""
    keep = CONTEXT_VARIANTS[variant]
    return inputs.select(*[c for c in inputs.channels if c not in CONTEXT_CHANNELS or c in keep])


def run_program(program: Case) -> list[dict]:
    """The event-free runs of one program: teach from 3 runs, monitor the others (with overrides), once per
    context variant (:data:`CONTEXT_VARIANTS`).

    Parameters
    ----------
    program : Case
        From :func:`plan_programs`.
    """
    settings = program.settings()
    est = bench_estimator(round(program.feed_speed, 9), program.duration)
    rows = []
    taught = []
    runs = [()] * 3 + list(program.overrides)
    limits: dict = {}
    for j, overrides in enumerate(runs):
        events = tuple(ProcessEvent("feed_override", t, factor=f) for t, f in overrides)
        rec = simulate_event_cut(program.condition(), events=events, settings=settings,
                                 exit_length=program.exit_length, seed=program.seed + j)
        if j == 3:                  # taught as each variant sees the runs (per block with the NC's context)
            limits = {v: teach([_with_context(t, v) for t in taught], ["force_x"]) for v in CONTEXT_VARIANTS}
        limit = 3.0 * rec.meta["truth"]["stable_peak_n"] + 20.0
        forces = est.estimate(rec)
        inputs = detector_inputs(rec, forces)
        if j < 3:
            taught.append(inputs)
        detected = {}
        for variant in CONTEXT_VARIANTS:
            detectors = default_detectors("x", teeth=program.teeth, force_limit_n=limit, **estimate_limits(est))
            if limits:
                detectors.append(TeachInDetector(limits[variant]))
            detected[variant] = _events_json(run_detectors(_with_context(inputs, variant), detectors, check=False))
        rev = max(1, int(round(60.0 / program.rpm * rec.fs)))
        engaged = maximum_filter1d(np.abs(rec["force_x"]), rev) > 0.05 * max(rec.meta["truth"]["stable_peak_n"], 1e-9)
        cutting = float(np.count_nonzero(engaged) / rec.fs)
        rows.append({**program.describe(), "run": j, "overrides": [list(o) for o in overrides],
                     "exit_length_mm": None if program.exit_length is None else program.exit_length * 1e3,
                     "teach_in": bool(limits), "detected": detected["none"], "detected_by_context": detected,
                     "cutting_s": cutting})
    return rows
