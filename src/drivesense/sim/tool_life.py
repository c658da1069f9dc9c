"""Tool-life simulation of the second paper's wear experiments (Table 1, A-H), measured by spindle power.

One simulated tool cuts 1018 steel until it reaches its life criterion; at the experiment's
calibration interval it makes a set of calibration cuts whose average spindle power is recorded
(with the air-cut power just before each cut), exactly what :mod:`drivesense.condition.wear` reads.

Physics and what is assumed (the paper gives the conditions but neither tool lives nor wear rates):

* **Flank wear VB** grows with cutting time by a three-stage wear-rate law
  ``dVB/dt = k(V, h) (1 + b exp(-VB / w_b)) (1 + (VB / VB_acc)^q)``: break-in of the sharp edge
  (b, w_b), a steady stage, and an accelerating stage once the flank land is long enough for its
  frictional heat to soften the edge (VB_acc, q). ``k`` follows an extended Taylor law,
  ``T ~ V^(-1/n) h^(-a)``, normalised so that the median tool reaches the criterion after
  ``nominal_calibrations`` (16) calibration intervals at the experiment's wear condition
  (an assumption: Table 1 gives the intervals but no lives). Tool-to-tool scatter: life
  log-normal with sigma 0.3 (Taylor scatter of 20-40 % is typical), b, VB_acc, q uniform in ranges.
* **K_te = K_te0 + tau_w VB** (rubbing on the flank land; tau_w ~ 350 N/mm^2 in steel, carbide 0.7x,
  aluminium 0.35x), **K_tc = K_tc0 (1 + c_e (VB / VB_acc)^q) (1 + alpha_c D_c)**: the same thermal
  softening that accelerates wear raises the shearing energy near the end of life, and a chipped
  edge (depth D_c) cuts with a blunter, more negative effective rake.
* **Chipping** is a Poisson process (drawn as exponential thresholds of the integrated rate, from a
  random stream of its own, so a tool chips at the same points of its cutting history whatever the
  measurement noise or the calibration cadence) whose rate grows with the chip load
  (``(h_max / h_ref)^2``), with the damage already done (``(1 + D_c / d_0)^2``, a weakened edge)
  and, for HSS, with cutting speed (thermal softening, ``(V / 60 m/min)^4``). A chip of depth s (log-normal) adds s to D_c and grinds
  away a fraction of the flank land (less rubbing: K_te falls). Carbide: about 4 chips (median depth
  40 um) per nominal life at the reference load; HSS, tougher: 0.15 (20 um) at 60 m/min, so that
  the 3666 rpm experiment H shows "some chipping along with flank wear" as the paper reports.
* **Life criterion** (ISO 8688-2 style): uniform flank wear VB >= 0.3 mm or localised (chipping)
  damage D_c >= 0.5 mm; the true mode is the criterion closer to its limit at failure.
* **Measurement**: mean spindle power from the mechanistic force model (helix, runout up to 7.5 um
  for multi-flute tools: a flute can lose contact, which Eq. 2 ignores), workpiece hardness scatter
  (2 % per cut), air-cut power depending on speed and falling as the spindle warms up, slow power
  drift (random walk), sensor lag (0.1 s) and white noise (10 W rms at 100 Hz); the average is
  taken over each window, as a user would.

Calibrations of experiments A, E and F run continuously (each sweep through all feeds and
immersions, 10 s per cut, is one calibration); B, C, D, G and H wear at one condition and calibrate
at four feeds (0.5, 0.75, 1, 1.25 x the wear feed) every interval — G and H on aluminium.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.signal import lfilter

from drivesense.errors import ConfigError
from drivesense.machine.cutting_power import CutTable
from drivesense.machine.cutting_power import CutConditions
from drivesense.machine.milling import CuttingCoefficients, milling_forces
from drivesense.sim.wear_experiments import PASS_LENGTH, WearExperiment, section4_calibration, table1_experiments

__all__ = ["PASS_LENGTH", "WearExperiment", "ToolLife", "table1_experiments", "section4_calibration", "simulate_tool_life",
           "simulate_calibration", "power_trace"]

VB_LIMIT = 0.3e-3       # m, uniform flank wear criterion
CHIP_LIMIT = 0.5e-3     # m, localised damage criterion
CUT_SECONDS = 10.0      # s of steady cutting per calibration cut
AIR_SECONDS = 2.0       # s of air cut before each calibration cut
FS_POWER = 100.0        # Hz, power sensor sampling
# material constants: new-tool K_tc [N/m^2], K_te [N/m] by (tool, workpiece); rubbing stress factor
_K0 = {("HSS", "steel"): (2100e6, 35e3), ("carbide", "steel"): (1900e6, 30e3),
       ("HSS", "aluminium"): (750e6, 18e3), ("carbide", "aluminium"): (700e6, 15e3)}
_TAU_W = 350e6            # N/m^2: K_te rise per m of flank land, HSS in steel
_TOOL = {"HSS": {"taylor_n": 0.125, "tau": 1.0, "chips": 0.15, "chip_size": 0.02e-3, "alpha_c": 1.0e3},
         "carbide": {"taylor_n": 0.25, "tau": 0.7, "chips": 4.0, "chip_size": 0.04e-3, "alpha_c": 1.2e3}}


@dataclass(eq=False)
class ToolLife:
    """One simulated tool life: the calibration session and the truth behind it.

    Attributes
    ----------
    experiment : WearExperiment
        The conditions.
    seed : int
        Random seed.
    table : CutTable
        Calibration cuts (with ``calibration`` and ``distance`` [m]) and their measured cutting power [W].
    spindle_power, air_power : ndarray
        Measured mean spindle power in each cut and in the air cut before it [W].
    truth : dict of ndarray
        Per calibration: ``distance`` [m], ``VB`` [m], ``chip_depth`` [m], ``Ktc`` [N/m^2], ``Kte`` [N/m]
        (calibration-material values at the start of the calibration).
    failure_distance : float
        Cut distance at which the life criterion was reached [m].
    failure_mode : {"flank", "chipping"}
        The criterion closer to its limit at failure.
    chips : list of (float, float)
        Chipping events: (distance [m], depth [m]).
    reference_index : int
        Index, within a calibration, of the cut at the wear condition (for the percent-power indicator).
    production : CutTable or None
        The production passes between calibrations (at the wear condition, ``PASS_LENGTH`` each, with
        ``distance`` [m] at the start of each pass) and their measured cutting power [W]; None for
        experiments that calibrate continuously (every cut is a calibration cut). Measured from a random
        stream of their own: the calibration cuts are the same with or without them.
    production_spindle_power, production_air_power : ndarray
        Measured mean spindle power in each production pass and in the air cut before it [W].
    production_truth : dict of ndarray
        Per production pass: ``distance`` [m], ``VB`` [m], ``chip_depth`` [m], ``Ktc`` [N/m^2], ``Kte``
        [N/m] (steel, the tool's state during the pass); empty without production passes.
    cut_truth : dict of ndarray
        Per calibration cut (rows of ``table``): ``VB`` [m] and ``chip_depth`` [m] when it was cut.
    """

    experiment: WearExperiment
    seed: int
    table: CutTable
    spindle_power: np.ndarray
    air_power: np.ndarray
    truth: dict
    failure_distance: float
    failure_mode: str
    chips: list = field(default_factory=list)
    reference_index: int = 0
    production: CutTable | None = None
    production_spindle_power: np.ndarray = field(default_factory=lambda: np.zeros(0))
    production_air_power: np.ndarray = field(default_factory=lambda: np.zeros(0))
    production_truth: dict = field(default_factory=dict)
    cut_truth: dict = field(default_factory=dict)


class _Tool:
    """The state and the random make-up of one tool."""

    def __init__(self, exp: WearExperiment, rng: np.random.Generator) -> None:
        self.exp, self.rng = exp, rng
        mat = _TOOL[exp.tool_material]
        self.mat = mat
        self.b = rng.uniform(3.0, 6.0)
        self.w_b = 0.02e-3
        self.vb_acc = rng.uniform(0.19e-3, 0.24e-3)
        self.q = rng.uniform(3.0, 5.0)
        self.c_e = rng.uniform(0.04, 0.10)
        self.tau = _TAU_W * mat["tau"] * rng.lognormal(0.0, 0.15)
        self.alpha_c = mat["alpha_c"] * rng.lognormal(0.0, 0.2)
        self.k_scatter = rng.lognormal(0.0, 0.15)    # new-tool edge preparation: K0 scatter
        self.kte_scatter = rng.lognormal(0.0, 0.1)
        self.runout = rng.uniform(0.0, 7.5e-6) if exp.flutes > 1 else 0.0
        self.runout_phase = rng.uniform(0, 2 * math.pi)
        self.vb, self.chip = 0.0, 0.0
        self.grid = np.linspace(0.0, 2.5 * VB_LIMIT, 4001)
        rate = (1 + self.b * np.exp(-self.grid / self.w_b)) * (1 + (self.grid / self.vb_acc) ** self.q)
        self.G = np.concatenate([[0.0], np.cumsum(0.5 * (1 / rate[1:] + 1 / rate[:-1]) * np.diff(self.grid))])
        # nominal life at the wear condition [s], with log-normal tool-to-tool scatter
        cycle = self._cycle_seconds()
        self.life = exp.nominal_calibrations * cycle * rng.lognormal(0.0, 0.3)
        ref = exp.wear_cut()
        self.ref_v, self.ref_h = ref.cutting_speed, ref.average_chip_thickness
        self.k_ref = np.interp(VB_LIMIT, self.grid, self.G) / self.life
        self.chip_rate_ref = mat["chips"] / (exp.nominal_calibrations * cycle)
        # chipping draws from a stream of its own, as a Poisson process in integrated hazard: the same tool
        # chips at the same points of its cutting history however the measurements or the cadence go
        self.chip_rng = np.random.default_rng(rng.integers(2 ** 63))
        self.hazard_left = self.chip_rng.exponential()
        self.cache: dict = {}

    def _cycle_seconds(self) -> float:
        exp = self.exp
        cal = sum(CUT_SECONDS + c.radius / c.feed_speed for c in exp.calibration_cuts())
        cal *= 1.0 if exp.calibration_material == "steel" else 0.0
        if exp.continuous:
            return cal
        return cal + exp.calibration_interval / exp.wear_cut().feed_speed

    def wear_rate(self, cut: CutConditions) -> float:
        """Scale k [1/s] of the wear-rate law at this cut (extended Taylor law)."""
        n = self.mat["taylor_n"]
        return self.k_ref * (cut.cutting_speed / self.ref_v) ** (1 / n) * (cut.average_chip_thickness
                                                                           / self.ref_h) ** 0.5

    def chip_rate(self, cut: CutConditions) -> float:
        """Chipping events per second at this cut and the present damage."""
        hmax = cut.feed_per_tooth * (1.0 if cut.entry_angle <= math.pi / 2 <= cut.exit_angle
                                     else max(math.sin(cut.entry_angle), math.sin(cut.exit_angle)))
        href = self.exp.wear_cut().feed_per_tooth
        rate = self.chip_rate_ref * (hmax / href) ** 2 * (1 + self.chip / 0.15e-3) ** 2
        if self.exp.tool_material == "HSS":
            rate *= (cut.cutting_speed / 1.0) ** 4        # (V / 60 m/min)^4, 60 m/min = 1 m/s
        return rate

    def advance(self, cut: CutConditions, seconds: float, wears: bool, clock: float, events: list,
                trace: list | None = None) -> None:
        """Cut for `seconds`; wear (if `wears`) and chip by sub-steps of at most 5 s.

        `trace` (optional) receives ``(distance [m], VB [m], chip depth [m])`` after each sub-step; it
        only records, so the tool's history is the same with or without it.
        """
        if not wears or seconds <= 0:
            return
        steps = max(1, int(math.ceil(seconds / 5.0)))
        dt = seconds / steps
        k = self.wear_rate(cut)
        for i in range(steps):
            g = np.interp(self.vb, self.grid, self.G) + k * dt
            self.vb = float(np.interp(g, self.G, self.grid))
            self.hazard_left -= self.chip_rate(cut) * dt
            if self.hazard_left <= 0.0:
                s = self.chip_rng.lognormal(math.log(self.mat["chip_size"]), 0.5)
                self.chip += s
                self.vb *= 1.0 - self.chip_rng.uniform(0.2, 0.5) * min(1.0, s / 0.05e-3)
                events.append((clock + (i + 1) * dt * cut.feed_speed, s))
                self.hazard_left = self.chip_rng.exponential()
            if trace is not None:
                trace.append((clock + (i + 1) * dt * cut.feed_speed, self.vb, self.chip))

    @property
    def failed(self) -> bool:
        return self.vb >= VB_LIMIT or self.chip >= CHIP_LIMIT

    def coefficients(self, material: str, vb: float | None = None, chip: float | None = None) -> tuple[float, float]:
        """True K_tc [N/m^2], K_te [N/m] now (or at flank wear `vb`, chip depth `chip` [m]), cutting `material`."""
        vb = self.vb if vb is None else vb
        chip = self.chip if chip is None else chip
        ktc0, kte0 = _K0[(self.exp.tool_material, material)]
        scale = 1.0 if material == "steel" else 0.35
        soften = 1 + self.c_e * (vb / self.vb_acc) ** self.q
        ktc = ktc0 * self.k_scatter * soften * (1 + self.alpha_c * chip)
        kte = kte0 * self.kte_scatter + scale * self.tau * vb
        return ktc, kte

    def mean_power(self, cut: CutConditions, ktc: float, kte: float) -> float:
        """Mean cutting power [W] from the mechanistic model (helix 30 deg, runout), linear in K."""
        key = (cut.feed_per_tooth, cut.entry_angle, cut.exit_angle)
        if key not in self.cache:
            tool = cut.end_mill(30.0, self.runout, self.runout_phase)
            angle = np.linspace(0.0, 2 * math.pi, 720, endpoint=False)
            basis = []
            for k in ((1.0, 0, 0, 0, 0, 0), (0, 0, 0, 1.0, 0, 0)):
                f = milling_forces(tool, CuttingCoefficients(*k), cut.milling_cut(8), angle, cut.feed_per_tooth)
                basis.append(float(f.torque.mean()) * cut.spindle_speed)
            self.cache[key] = basis
        bc, be = self.cache[key]
        return ktc * bc + kte * be


def power_trace(cutting_power: float, air_power: float, rng: np.random.Generator, *, drift: float = 1.0,
                noise: float = 10.0, lag: float = 0.1) -> np.ndarray:
    """Spindle power samples of one calibration cut: air cut, then the steady cut, as a power sensor gives them.

    Parameters
    ----------
    cutting_power : float
        True mean cutting power during the cut [W].
    air_power : float
        True air-cut (idle) power [W].
    rng : numpy.random.Generator
        Random source.
    drift : float
        Standard deviation of the slow power drift over the trace [W] (random walk).
    noise : float
        White measurement noise [W rms] at the 100 Hz sensor rate.
    lag : float
        Sensor time constant [s].

    Returns
    -------
    ndarray
        Power [W] at 100 Hz: ``AIR_SECONDS`` (2 s) of air cut, then ``CUT_SECONDS`` (10 s) of cut.
    """
    n_air, n_cut = int(AIR_SECONDS * FS_POWER), int(CUT_SECONDS * FS_POWER)
    n = n_air + n_cut
    true = np.full(n, air_power)
    true[n_air:] += cutting_power
    walk = np.cumsum(rng.normal(0.0, drift / math.sqrt(n), n))
    a = math.exp(-1.0 / (lag * FS_POWER))
    sensed = lfilter([1 - a], [1, -a], true + walk, zi=[a * air_power])[0]
    return sensed + rng.normal(0.0, noise, n)


def _measure(trace: np.ndarray) -> tuple[float, float]:
    """(mean spindle power in the cut, mean air-cut power) as a user windows them [W]."""
    n_air = int(AIR_SECONDS * FS_POWER)
    return float(trace[n_air + int(0.8 * FS_POWER):].mean()), float(trace[int(0.2 * FS_POWER):n_air - 10].mean())


def _air_power(omega: float, minutes: float) -> float:
    """Idle spindle power [W] at omega [rad/s], falling by 15 % as the spindle warms up (20 min)."""
    return (150.0 + 0.8 * omega + 3e-4 * omega ** 2) * (1 + 0.15 * math.exp(-minutes / 20.0))


def _experiment(experiment) -> WearExperiment:
    if isinstance(experiment, WearExperiment):
        return experiment
    known = table1_experiments()
    if not isinstance(experiment, str) or experiment.upper() not in known:
        raise ConfigError(f"unknown experiment {experiment!r} (known: {', '.join(known)})")
    return known[experiment.upper()]


def simulate_tool_life(experiment: WearExperiment | str, seed: int = 0, *, max_calibrations: int = 200,
                       cadence=None) -> ToolLife:
    """Simulate one tool of an experiment from new to its life criterion.

    Parameters
    ----------
    experiment : WearExperiment or str
        The experiment, or its Table 1 letter.
    seed : int
        Random seed (tool make-up, chipping, noise).
    max_calibrations : int
        Safety stop.
    cadence : callable, optional
        ``cadence(table, distance) -> interval``: after each calibration, given its cuts with the
        measured cutting power (a :class:`~drivesense.machine.cutting_power.CutTable`) and its cut
        distance [m], the wear-cut distance to the next calibration [m] (e.g.
        :class:`drivesense.condition.cadence.AdaptiveCadence`). Default: the experiment's fixed
        ``calibration_interval``. Continuous experiments calibrate on every sweep whatever it says.

    Returns
    -------
    ToolLife
    """
    exp = _experiment(experiment)
    rng = np.random.default_rng([seed, *exp.name.encode()])
    tool = _Tool(exp, rng)
    prod_rng = np.random.default_rng([seed, *exp.name.encode(), 3])   # production passes: a stream of their own
    prev_threads = numba.get_num_threads()
    numba.set_num_threads(1)                     # one revolution per call: threads cost more than they give
    try:
        return _run(exp, seed, tool, rng, max_calibrations, cadence, prod_rng)
    finally:
        numba.set_num_threads(prev_threads)


def _run(exp, seed, tool, rng, max_calibrations, cadence=None, prod_rng=None) -> ToolLife:
    cal_cuts = exp.calibration_cuts()
    wear_cut = exp.wear_cut()
    clock, minutes = 0.0, 0.0
    cuts, sp, ap, cal_no, dist, events = [], [], [], [], [], []
    cut_truth = {"VB": [], "chip_depth": []}
    production: list = []
    truth = {k: [] for k in ("distance", "VB", "chip_depth", "Ktc", "Kte")}
    failure = None
    for k in range(max_calibrations):
        ktc, kte = tool.coefficients(exp.calibration_material)
        for name, value in zip(truth, (clock, tool.vb, tool.chip, ktc, kte)):
            truth[name].append(value)
        rows = []
        for cut in cal_cuts:
            ktc, kte = tool.coefficients(exp.calibration_material)
            hard = rng.lognormal(0.0, 0.02)
            p_true = tool.mean_power(cut, ktc * hard, kte * hard)
            s, a = _measure(power_trace(p_true, _air_power(cut.spindle_speed, minutes), rng))
            rows.append((cut, s, a, clock, tool.vb, tool.chip))
            seconds = CUT_SECONDS + cut.radius / cut.feed_speed       # entry, then the measured steady part
            tool.advance(cut, seconds, exp.calibration_material == "steel", clock, events)
            clock += seconds * cut.feed_speed
            minutes += (seconds + AIR_SECONDS) / 60
            if tool.failed:
                failure = clock
                break
        if failure is not None:
            if len(rows) == len(cal_cuts):           # the last calibration completed just at failure
                _append(rows, k, cuts, sp, ap, cal_no, dist, cut_truth)
            else:
                for v in truth.values():
                    v.pop()
            break
        _append(rows, k, cuts, sp, ap, cal_no, dist, cut_truth)
        if exp.continuous:
            continue
        interval = exp.calibration_interval
        if cadence is not None:
            done = CutTable(tuple(r[0] for r in rows), np.array([r[1] - r[2] for r in rows]),
                            name=f"experiment {exp.name}, seed {seed}, calibration {k}")
            interval = float(cadence(done, float(np.mean([r[3] for r in rows]))))
            if not math.isfinite(interval) or interval <= 0:
                raise ConfigError(f"the cadence proposed an interval of {interval!r} m after calibration {k}; "
                                  "it must be > 0")
        seconds = interval / wear_cut.feed_speed
        steps = max(1, int(math.ceil(seconds / 30.0)))
        start, start_minutes, trace = clock, minutes, []
        for _ in range(steps):
            tool.advance(wear_cut, seconds / steps, True, clock, events, trace)
            clock += seconds / steps * wear_cut.feed_speed
            minutes += seconds / steps / 60
            if tool.failed:
                failure = clock
                break
        _passes(tool, wear_cut, start, start + interval, clock, start_minutes, trace, prod_rng, production)
        if failure is not None:
            break
    else:
        failure = clock
    mode = "chipping" if tool.chip / CHIP_LIMIT > tool.vb / VB_LIMIT else "flank"
    table = CutTable(tuple(cuts), np.array(sp) - np.array(ap), np.array(cal_no), np.array(dist),
                     name=f"experiment {exp.name}, seed {seed}")
    ref = (len(cal_cuts) // 2) if exp.continuous else 2
    prod_table, prod_truth, prod_sp, prod_ap = None, {}, np.zeros(0), np.zeros(0)
    if production:
        cols = list(zip(*production))
        prod_sp, prod_ap = np.array(cols[1]), np.array(cols[2])
        prod_table = CutTable(tuple(cols[0]), prod_sp - prod_ap, distance=np.array(cols[3]),
                              name=f"experiment {exp.name}, seed {seed}, production")
        prod_truth = {k: np.array(v) for k, v in zip(("distance", "VB", "chip_depth", "Ktc", "Kte"), cols[3:])}
    return ToolLife(exp, seed, table, np.array(sp), np.array(ap), {k: np.array(v) for k, v in truth.items()},
                    float(failure), mode, events, ref, prod_table, prod_sp, prod_ap, prod_truth,
                    {k: np.array(v) for k, v in cut_truth.items()})


def _append(rows, k, cuts, sp, ap, cal_no, dist, cut_truth) -> None:
    for cut, s, a, d, vb, chip in rows:
        cuts.append(cut)
        sp.append(s)
        ap.append(a)
        cal_no.append(k)
        dist.append(d)
        cut_truth["VB"].append(vb)
        cut_truth["chip_depth"].append(chip)


def _passes(tool, cut, start, end, reached, minutes, trace, rng, out) -> None:
    """Measure the production passes of one interval between calibrations (appended to `out`).

    The interval [start, end] m is cut as passes of ``PASS_LENGTH`` from its start (a last part shorter
    than half a pass is not measured); a pass is measured when the tool got through it (``reached`` m:
    the interval's end, or where the tool failed) at the mean state of the wear sub-steps inside it
    (`trace`), with its own hardness scatter, air cut before it and sensor, from `rng` (the calibrations'
    random stream is not touched).
    """
    if not trace:
        return
    d_trace = np.array([t[0] for t in trace])
    j = 0
    while True:
        a, b = start + j * PASS_LENGTH, min(start + (j + 1) * PASS_LENGTH, end)
        if b - a < 0.5 * PASS_LENGTH or b > reached + 1e-12:
            break
        inside = np.flatnonzero((d_trace > a) & (d_trace <= b + 1e-12))
        if inside.size == 0:
            inside = np.array([int(np.argmin(np.abs(d_trace - 0.5 * (a + b))))])
        vb = float(np.mean([trace[i][1] for i in inside]))
        chip = float(np.mean([trace[i][2] for i in inside]))
        ktc, kte = tool.coefficients("steel", vb, chip)
        hard = rng.lognormal(0.0, 0.02)
        air = _air_power(cut.spindle_speed, minutes + (a - start) / cut.feed_speed / 60)
        s, p_air = _measure(power_trace(tool.mean_power(cut, ktc * hard, kte * hard), air, rng))
        out.append((cut, s, p_air, a, vb, chip, ktc, kte))
        j += 1


def simulate_calibration(experiment: WearExperiment | str, seed: int = 0, *, vb: float = 0.0,
                         chip_depth: float = 0.0, repeats: int = 1,
                         runout: float | None = None, measured_runout: float | None = None
                         ) -> tuple[CutTable, tuple[float, float]] | tuple[CutTable, tuple[float, float], object]:
    """One set of calibration cuts at a frozen wear state, measured with the same noise as a tool life.

    Parameters
    ----------
    experiment : WearExperiment or str
        The experiment (its calibration cuts and material), or its Table 1 letter.
    seed : int
        Random seed (tool make-up and measurement noise).
    vb : float
        Flank wear VB [m].
    chip_depth : float
        Chipped depth D_c [m].
    repeats : int
        Times each cut is measured; the table holds the mean (the paper's Sec. 4 averaged 10).
    runout : float, optional
        Tool runout [m] instead of the tool's random one (0: Eq. 2 holds exactly, only noise remains).
    measured_runout : float, optional
        Also return the runout as a user would measure it
        (:class:`~drivesense.machine.tool_runout.ToolRunout`): the true offset with a dial
        indicator's error of this standard deviation [m], and the phase with an error of that
        error over the offset [rad] (at least 0.1 rad, at most pi).

    Returns
    -------
    table : CutTable
        The cuts and their measured cutting power [W].
    truth : (float, float)
        The tool's true K_tc [N/m^2] and K_te [N/m] at that state.
    """
    exp = _experiment(experiment)
    rng = np.random.default_rng([seed, *exp.name.encode(), 1])
    tool = _Tool(exp, rng)
    tool.vb, tool.chip = float(vb), float(chip_depth)
    if runout is not None:
        tool.runout = float(runout)
    ktc, kte = tool.coefficients(exp.calibration_material)
    cuts, power = exp.calibration_cuts(), []
    prev_threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for i, cut in enumerate(cuts):
            reps = []
            for _ in range(max(1, int(repeats))):
                hard = rng.lognormal(0.0, 0.02)
                s, a = _measure(power_trace(tool.mean_power(cut, ktc * hard, kte * hard),
                                            _air_power(cut.spindle_speed, 30.0 + i / 4), rng))
                reps.append(s - a)
            power.append(float(np.mean(reps)))
    finally:
        numba.set_num_threads(prev_threads)
    table = CutTable(tuple(cuts), np.array(power), name=f"calibration {exp.name}, seed {seed}")
    if measured_runout is None:
        return table, (ktc, kte)
    from drivesense.machine.tool_runout import ToolRunout

    err = np.random.default_rng([seed, *exp.name.encode(), 2]).normal(0.0, 1.0, 2)
    phase_sd = min(math.pi, max(0.1, measured_runout / max(tool.runout, 1e-9)))
    measured = ToolRunout(max(0.0, tool.runout + measured_runout * err[0]), tool.runout_phase + phase_sd * err[1])
    return table, (ktc, kte), measured
