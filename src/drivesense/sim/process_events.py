"""Process events on the ball-screw stage with their ground truth: breakage, chipping, chatter, collision,
overload, a missing tool and feed-rate overrides.

:func:`simulate_event_cut` runs one cut of the first paper's stage
(:mod:`drivesense.sim.scenarios`, X feeding) with the time-domain milling model
of :mod:`drivesense.machine.milling_dynamics`:

* ``breakage`` / ``chipping``: a flute loses all / part of its engaged edge
  (:class:`~drivesense.machine.milling_dynamics.EdgeDamage`); the next flute
  takes the chip it leaves;
* chatter: give the tool modes (``dynamics``); the cut is labelled from the
  simulated force itself (:func:`chatter_onset`) and, by the caller, against the
  stability lobes (:mod:`drivesense.machine.stability`);
* ``collision`` (a step, rise ``rise_s`` <= 1 ms) and ``overload`` (a ramp) add
  a force ``force_n`` on the table along X for ``hold_s``;
* ``missing_tool``: the programmed cut removes nothing (no tool in the spindle);
* ``feed_override``: the feed changes to ``factor`` times the programmed one
  (which must not alarm).

The trace's ``meta["truth"]`` lists the events with their times, and
``stable_peak_n``, the peak table force of the same cut with a rigid tool and
no event (what "the stable force" means for the chatter criteria).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from drivesense.errors import ConfigError
from drivesense.machine.milling import EndMill, MillingCut, check_number
from drivesense.machine.milling_dynamics import EdgeDamage, dynamic_milling_forces
from drivesense.machine.tool_dynamics import ToolDynamics
from drivesense.recording import Recording
from drivesense.sim.scenarios import CutCondition, ScenarioSettings, run_scenario

__all__ = ["ProcessEvent", "EVENT_SIM_KINDS", "simulate_event_cut", "chatter_onset"]

#: Event kinds the simulator can inject.
EVENT_SIM_KINDS = ("breakage", "chipping", "collision", "overload", "missing_tool", "feed_override")


@dataclass(frozen=True)
class ProcessEvent:
    """One injected event.

    Parameters
    ----------
    kind : str
        One of :data:`EVENT_SIM_KINDS`.
    time_s : float
        When it happens [s].
    flute : int
        Damaged flute (breakage, chipping).
    edge_loss : float
        Share of the edge lost [-] (chipping; breakage is 1).
    force_n : float
        Extra table force along X at its peak [N] (collision, overload); signed.
    rise_s : float
        Rise time of that force [s] (a collision's is <= 1 ms, an overload's longer).
    hold_s : float
        How long the extra force stays at its peak [s].
    factor : float
        Feed-rate override [-] (feed_override).
    """

    kind: str
    time_s: float
    flute: int = 0
    edge_loss: float = 1.0
    force_n: float = 0.0
    rise_s: float = 0.0
    hold_s: float = 0.3
    factor: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in EVENT_SIM_KINDS:
            raise ConfigError(f"event kind must be one of {', '.join(EVENT_SIM_KINDS)}, got {self.kind!r}")
        check_number(self.time_s, "time_s", nonneg=True)
        check_number(self.rise_s, "rise_s", nonneg=True)
        check_number(self.hold_s, "hold_s", positive=True)
        check_number(self.factor, "factor", positive=True)
        if self.kind == "breakage":
            object.__setattr__(self, "edge_loss", 1.0)

    def to_json(self) -> dict:
        """The event as the trace's truth lists it."""
        out = {"kind": self.kind, "time_s": float(self.time_s)}
        if self.kind in ("breakage", "chipping"):
            out.update(flute=int(self.flute), edge_loss=float(self.edge_loss))
        elif self.kind in ("collision", "overload"):
            out.update(force_n=float(self.force_n), rise_s=float(self.rise_s), hold_s=float(self.hold_s))
        elif self.kind == "feed_override":
            out.update(factor=float(self.factor))
        return out


def _extra_force(t: np.ndarray, events) -> np.ndarray:
    """Collision / overload force on the table [N] at times ``t`` [s]."""
    out = np.zeros(t.size)
    for e in events:
        if e.kind not in ("collision", "overload"):
            continue
        rise = max(e.rise_s, 1e-9)
        up = np.clip((t - e.time_s) / rise, 0.0, 1.0)
        down = np.clip((t - e.time_s - rise - e.hold_s) / rise, 0.0, 1.0)
        out += e.force_n * (up - down)
    return out


def chatter_onset(force: np.ndarray, fs: float, spindle_rpm: float, reference: np.ndarray, *,
                  start_s: float = 0.0, share: float = 0.03, sustain_revs: int = 5) -> float | None:
    """When chatter starts in a simulated force: its part that does not repeat every revolution grows.

    The once-per-revolution comb ``e(t) = d(t) - d(t - T_rev)`` of the
    difference ``d = F - F_rigid`` between the force and the same cut's force
    with a rigid tool is zero for a cut that repeats every revolution (runout,
    static deflection) and small for a slowly growing engagement; its RMS over
    one revolution, divided by sqrt(2), against the rigid force's RMS is the
    chatter share.

    Parameters
    ----------
    force : ndarray
        True force [N].
    fs : float
        Sample rate [Hz].
    spindle_rpm : float
        Spindle speed [min^-1].
    reference : ndarray
        The same cut's force with a rigid tool [N].
    start_s : float
        Ignore earlier times [s] (before the tool reaches the part).
    share : float
        Threshold on the RMS ratio [-].
    sustain_revs : int
        Revolutions the share must stay above ``share`` from the onset on.

    Returns
    -------
    float or None
        Onset time [s], None for a stable cut.
    """
    lag = int(round(60.0 / spindle_rpm * fs))
    d = force - reference
    e = np.zeros_like(force)
    e[lag:] = d[lag:] - d[:-lag]
    kernel = np.ones(lag) / lag
    rms_e = np.sqrt(np.convolve(e ** 2, kernel, mode="full")[:force.size] / 2.0)
    rms_f = np.sqrt(np.convolve((reference - np.convolve(reference, kernel, mode="same")) ** 2, kernel,
                                mode="full")[:force.size])
    over = (rms_e > share * np.maximum(rms_f, 1e-9)) & (rms_f > 0.05 * np.max(rms_f))
    over[:max(int(start_s * fs), 2 * lag)] = False
    need = sustain_revs * lag
    run = np.convolve(over.astype(float), np.ones(need), mode="full")[need - 1:need - 1 + over.size]
    hits = np.flatnonzero((run >= need - 0.5) & over)
    return float(hits[0] / fs) if hits.size else None


def simulate_event_cut(cond: CutCondition, *, events=(), tool: EndMill | None = None,
                       dynamics: ToolDynamics | None = None, settings: ScenarioSettings | None = None,
                       exit_length: float | None = None, seed: int = 0) -> Recording:
    """One cut of the ball-screw stage (X feeding) with injected events and their truth.

    Parameters
    ----------
    cond : CutCondition
        Cutting condition (``direction`` must be ``"feed"``).
    events : sequence of ProcessEvent
        What happens during the cut.
    tool : EndMill, optional
        The tool (default: the scenario's 6 mm two-flute end mill).
    dynamics : ToolDynamics, optional
        Tool-tip modes (chatter); None: a rigid tool.
    settings : ScenarioSettings, optional
        Stage, servo and trace length (default: the first paper's).
    exit_length : float, optional
        Length of the part along the feed [m]: the tool leaves it (an exit).
    seed : int
        Seed of every random element.

    Returns
    -------
    Recording
        As :func:`~drivesense.sim.scenarios.simulate_cut`; ``meta["truth"]``
        holds ``events`` (their JSON), ``chatter_onset_s`` (None if stable),
        ``stable_peak_n`` [N] and the tool.
    """
    if cond.direction != "feed":
        raise ConfigError("simulate_event_cut: the condition must feed the X axis (direction 'feed')")
    settings = settings or ScenarioSettings()
    if tool is not None:
        settings = replace(settings, tool=tool)
    events = tuple(events)
    for e in events:
        if not isinstance(e, ProcessEvent):
            raise ConfigError(f"events must be ProcessEvent objects, got {type(e).__name__}")
    overrides = tuple((e.time_s, e.factor) for e in events if e.kind == "feed_override")
    damage = [e for e in events if e.kind in ("breakage", "chipping")]
    missing = any(e.kind == "missing_tool" for e in events)
    fine_fs = settings.servo.fs * settings.servo.substeps
    truth: dict = {"events": [e.to_json() for e in events]}

    def forces(t_fine, feed_axis, omega, phase0, t):
        tl = settings.tool
        vel = np.interp(t_fine, t, feed_axis.velocity)
        feed_pos = np.interp(t_fine, t, feed_axis.position)
        progress = feed_pos - np.interp(settings.t_contact, t, feed_axis.position) - tl.diameter / 2
        c = 2 * math.pi * np.abs(vel) / (tl.flutes * omega)
        cut = MillingCut(cond.radial_depth, cond.axial_depth, cond.mode, axial_slices=8)
        angle = omega * t_fine + phase0
        common = dict(feed_progress=progress, exit_length=exit_length)
        rigid = dynamic_milling_forces(tl, settings.coefficients, cut, angle, c, fine_fs, **common).forces
        truth["stable_peak_n"] = float(np.max(np.abs(rigid.feed)))
        if missing:
            zero = np.zeros(t_fine.size)
            truth["chatter_onset_s"] = None
            return zero, zero, zero
        dmg = (EdgeDamage(damage[0].flute, damage[0].edge_loss, int(round(damage[0].time_s * fine_fs)))
               if damage else None)
        if dmg is None and dynamics is None:
            mf = rigid
        else:
            mf = dynamic_milling_forces(tl, settings.coefficients, cut, angle, c, fine_fs, dynamics=dynamics,
                                        damage=dmg, **common).forces
        onset = None
        if dynamics is not None:
            step = settings.servo.substeps
            onset = chatter_onset(mf.feed[::step], settings.servo.fs, cond.spindle_rpm, rigid.feed[::step],
                                  start_s=settings.t_contact)
        truth["chatter_onset_s"] = onset
        return mf.feed + _extra_force(t_fine, events), mf.normal, -mf.axial

    tl = settings.tool
    truth["tool"] = {"diameter_m": tl.diameter, "flutes": tl.flutes, "runout_m": tl.runout}
    truth["dynamics"] = None if dynamics is None else {
        "x": [[m.frequency_hz, m.damping_ratio, m.stiffness] for m in dynamics.x],
        "y": [[m.frequency_hz, m.damping_ratio, m.stiffness] for m in dynamics.y]}
    rec = run_scenario(cond, settings, seed, True, f"{cond.name}_events_seed{seed}", overrides=overrides, forces=forces,
                       extra_meta={"truth": truth}, part_length=exit_length)
    return rec
