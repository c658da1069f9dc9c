"""From a trace and its estimated forces to events: the inputs detectors read, the default set, one run.

::

    inputs = detector_inputs(trace, forces)      # forces + spindle_speed + feed_speed + table positions
    report = run_detectors(inputs, default_detectors("x", teeth=2, force_limit_n=300))
    report.events, report.latency_s

``feed_speed`` [m/s] is the tool-path speed from the trace's table positions
(smoothed over at least 50 ms): the detectors hold off while it changes (a feed-override
ramp) instead of taking the new pattern for an event.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage

from drivesense.errors import ConfigError
from drivesense.events.breakage import BreakageDetector
from drivesense.events.chatter import ChatterDetector
from drivesense.events.detector import Detector, Event, attach_latency
from drivesense.events.overload import OverloadDetector
from drivesense.events.teach import TeachInDetector, TeachLimits
from drivesense.events.teeth import TeethChoice, resolve_teeth
from drivesense.nc_context import CONTEXT_CHANNELS
from drivesense.recording import Recording

__all__ = ["detector_inputs", "feed_speed_of", "default_detectors", "estimate_limits", "run_detectors",
           "DetectionReport",
           "tool_teeth", "detect_in_trace", "TraceDetection", "check_detector_settings", "CLI_OPTION_NAMES"]

#: What notes call a detector's events.
_LABELS = {"breakage": "breakage/chipping"}

#: How :func:`check_detector_settings` names the settings: the CLI's options.
CLI_OPTION_NAMES = {"spindle_rpm": "--spindle-rpm", "teeth": "--teeth", "baseline_revs": "--baseline-revs",
                    "force_limit_n": "--force-limit"}


def check_detector_settings(*, spindle_rpm: float | None = None, teeth: int | None = None,
                            baseline_revs: int | None = None, force_limit_n: float | None = None,
                            names: dict | None = None) -> None:
    """Refuse a spindle speed or force limit that is not a finite number > 0, fewer than one tooth or fewer
    than 3 baseline revolutions, naming the setting (``--force-limit must be > 0 [N], got -5.0``).

    Parameters
    ----------
    spindle_rpm : float, optional
        Spindle speed [min^-1].
    teeth : int, optional
        Number of teeth [-].
    baseline_revs : int, optional
        Revolutions of the breakage baseline [-].
    force_limit_n : float, optional
        Collision/overload limit [N].
    names : dict, optional
        What messages call each setting (default :data:`CLI_OPTION_NAMES`).

    Raises
    ------
    ConfigError
        Naming the setting, its unit and the value given.
    """
    names = {**CLI_OPTION_NAMES, **(names or {})}
    for key, value, unit in (("spindle_rpm", spindle_rpm, ""), ("force_limit_n", force_limit_n, " [N]")):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            raise ConfigError(f"{names[key]} must be > 0{unit}, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{names[key]} must be a finite number > 0{unit}, got {value!r}")
    if teeth is not None and (isinstance(teeth, bool) or not isinstance(teeth, int) or teeth < 1):
        raise ConfigError(f"{names['teeth']} must be >= 1, got {teeth!r}")
    if baseline_revs is not None and (isinstance(baseline_revs, bool) or not isinstance(baseline_revs, int)
                                      or baseline_revs < 3):
        raise ConfigError(f"{names['baseline_revs']} must be >= 3 revolutions, got {baseline_revs!r}")

#: Smoothing of the path speed [s].
FEED_SMOOTHING_S = 50e-3


def feed_speed_of(trace: Recording) -> np.ndarray | None:
    """Tool-path speed [m/s] from the trace's ``*_table_position`` channels (None without any).

    Averaged over whole spindle revolutions spanning at least
    ``FEED_SMOOTHING_S`` when the trace has ``spindle_speed`` (the table's
    vibration under the cutting force repeats every revolution and cancels),
    else over ``FEED_SMOOTHING_S``.

    Parameters
    ----------
    trace : Recording
        The drive-signal trace.
    """
    chans = sorted(c for c in trace.channels if c.endswith("_table_position"))
    if not chans:
        return None
    v2 = sum(np.gradient(trace[c]) ** 2 for c in chans) * trace.fs ** 2
    width = FEED_SMOOTHING_S * trace.fs
    if "spindle_speed" in trace.channels:
        w = float(np.median(trace["spindle_speed"]))
        if w > 0:
            rev = 2 * np.pi / w * trace.fs
            width = rev * max(1, int(np.ceil(width / rev)))
    return scipy.ndimage.uniform_filter1d(np.sqrt(v2), max(1, int(round(width))), mode="nearest")


def detector_inputs(trace: Recording, forces: Recording) -> Recording:
    """The force channels with what detectors also read from the trace, on the forces' time base.

    Parameters
    ----------
    trace : Recording
        The drive-signal trace (``spindle_speed`` [rad/s], ``*_table_position`` [m], ``spindle_power`` [W]
        when present).
    forces : Recording
        An estimator's output (``force_*`` [N]), on the trace's time base.

    Returns
    -------
    Recording
        ``force_*``, and ``spindle_speed``, ``spindle_power``, ``feed_speed`` and the table positions
        where the trace has them; ``meta["latency_s"]`` the forces'.
    """
    if forces.n_samples != trace.n_samples:
        raise ConfigError(f"the forces have {forces.n_samples} samples, the trace {trace.n_samples}: detect on "
                          f"forces estimated from this trace")
    channels = {c: forces[c] for c in forces.channels}
    for c in trace.channels:
        if c in ("spindle_speed", "spindle_power") or c.endswith("_table_position") or c in CONTEXT_CHANNELS:
            channels[c] = trace[c]
    feed = feed_speed_of(trace)
    if feed is not None:
        channels["feed_speed"] = feed
    return Recording.from_arrays(channels, fs=trace.fs, t0=trace.t0,
                                 meta={"name": forces.meta.get("name", "forces"),
                                       "latency_s": float(forces.meta.get("latency_s", 0.0))})


def default_detectors(axis: str, *, teeth: int | None = None, spindle_rpm: float | None = None,
                      limits: TeachLimits | None = None, force_limit_n: float | None = None,
                      band_hz: float | None = None,
                      kinds: Sequence[str] = ("breakage", "chatter", "overload", "teach-in"),
                      baseline_revs: int | None = None, drive_modes_hz: Sequence[float] = (),
                      drive_pitches_m: Sequence[float] = ()) -> list[Detector]:
    """The detectors ``drivesense detect`` runs on one axis.

    Parameters
    ----------
    axis : str
        Axis letter of the force.
    teeth : int, optional
        Number of teeth (breakage needs it; without it breakage is not run).
    spindle_rpm : float, optional
        Fixed spindle speed [min^-1] for traces without ``spindle_speed``.
    limits : TeachLimits, optional
        Taught bands (teach-in runs only with them); their force limit serves overload.
    force_limit_n : float, optional
        Collision/overload limit [N] (overrides the taught one).
    band_hz : float, optional
        The force estimate's bandwidth [Hz] (its low-pass): chatter is looked for below 0.8 of it.
    kinds : sequence of str
        Which detectors to consider.
    baseline_revs : int, optional
        Revolutions of each cut the breakage detector learns its baseline over (default: its own).
    drive_modes_hz : sequence of float
        The feed drive's own mode frequencies [Hz] (:func:`estimate_limits`): a feed change rings them, and
        a line there is not chatter.
    drive_pitches_m : sequence of float
        Travel over which the drive's measuring error repeats [m] (:func:`estimate_limits`): the lines the
        feed moves it to are not chatter.
    """
    out: list[Detector] = []
    if "breakage" in kinds and teeth is not None:
        out.append(BreakageDetector(axis, teeth, spindle_rpm=spindle_rpm))
        if baseline_revs is not None:
            out[-1].baseline_revs = int(baseline_revs)
    if "chatter" in kinds:
        out.append(ChatterDetector(axis, spindle_rpm=spindle_rpm, exclude_hz=tuple(drive_modes_hz),
                                   highest_hz=None if band_hz is None else 0.8 * band_hz,
                                   pitches_m=tuple(drive_pitches_m), teeth=teeth))
    limit = force_limit_n if force_limit_n is not None else (limits.force_limit_n if limits is not None else None)
    if "overload" in kinds and limit is not None:
        out.append(OverloadDetector(axis, limit))
    if "teach-in" in kinds and limits is not None:
        out.append(TeachInDetector(limits))
    return out


@dataclass
class DetectionReport:
    """Events of a run of detectors and what they saw.

    Attributes
    ----------
    events : list of Event
        In time order; latencies include the force stream's.
    latency_s : float
        The largest declared latency [s] (estimator's included).
    statistics : dict
        Detector name -> (statistic, threshold) arrays per sample.
    detectors : list of Detector
        What ran.
    held : dict
        Detector name -> its guard codes per sample (0: judged; > 0: its guards held the statistic, see
        the detector's ``GUARDS``), for the detectors that report them.
    """

    events: list
    latency_s: float
    statistics: dict = field(default_factory=dict)
    detectors: list = field(default_factory=list)
    held: dict = field(default_factory=dict)


def estimate_limits(estimator) -> dict:
    """What the detectors must know of a force estimate, as keywords of :func:`default_detectors` and
    :func:`detect_in_trace`: its bandwidth (``band_hz``, the estimator's low-pass: chatter is looked for below
    it) and the feed drive's own mode frequencies (``drive_modes_hz``: a ball-screw axis's natural
    frequency, which a feed-override ramp rings; a spectral line there is the drive, not chatter) and the
    travel over which its measuring error repeats (``drive_pitches_m``: the motor encoder's signal period,
    where the axis file gives ``encoder_signal_periods``).

    Parameters
    ----------
    estimator : estimator
        Any of the registry's (those without a low-pass or an axis model give None and ``()``).
    """
    band = getattr(getattr(estimator, "signal", None), "lpf_hz", None)
    mode = getattr(getattr(estimator, "axis", None), "natural_frequency_hz", None)
    modes = (float(mode),) if isinstance(mode, (int, float)) and math.isfinite(mode) and mode > 0 else ()
    axis, signal = getattr(estimator, "axis", None), getattr(estimator, "signal", None)
    lead = getattr(axis, "lead", None)
    pitches = signal.drive_pitches(float(lead)) if isinstance(lead, (int, float)) and hasattr(
        signal, "drive_pitches") else ()
    return {"band_hz": band, "drive_modes_hz": modes, "drive_pitches_m": pitches}


def run_detectors(inputs: Recording, detectors: Sequence[Detector], *, check: bool = True) -> DetectionReport:
    """Run detectors over a whole force trace (each one push from a fresh state).

    Parameters
    ----------
    inputs : Recording
        From :func:`detector_inputs`.
    detectors : sequence of Detector
        What to run.
    check : bool
        Refuse a trace a detector could not arm on (e.g. too short a cut for a baseline).
    """
    if not detectors:
        raise ConfigError("no detector to run: give --teeth for breakage, --force-limit or --limits for overload")
    extra = float(inputs.meta.get("latency_s", 0.0))
    events: list[Event] = []
    stats = {}
    held = {}
    latency = 0.0
    for det in detectors:
        stream = det.stream(inputs.fs, t0=inputs.t0)
        out = stream.push(inputs)
        if check:
            det.check_ready(stream.state)
        events += attach_latency(out.events, extra)
        stats[det.name] = (out.statistic, out.threshold)
        if out.held is not None:
            held[det.name] = out.held
        latency = max(latency, stream.latency_s + extra)
    return DetectionReport(sorted(events, key=lambda e: e.time_s), latency, stats, list(detectors), held)


def tool_teeth(trace: Recording, teeth: int | None, *, forces: Recording | None = None,
               spindle_rpm: float | None = None, band_hz: float | None = None) -> int | None:
    """``teeth`` if given, else the flutes of the trace's tool, else the count read from its spectrum.

    The count of :func:`~drivesense.events.teeth.resolve_teeth` (None when it stays unknown; its
    ``TeethChoice`` says why).

    Parameters
    ----------
    trace : Recording
        The trace (``meta["tool"]["flutes"]``; its signals for the inference).
    teeth : int, optional
        The number of teeth given by the user (``--teeth``).
    forces : Recording, optional
        Estimated forces on the trace's time base (read first by the inference).
    spindle_rpm : float, optional
        Fixed spindle speed [min^-1] when the trace has no ``spindle_speed``.
    band_hz : float, optional
        The estimated forces' bandwidth [Hz].
    """
    return resolve_teeth(trace, teeth, forces=forces, spindle_rpm=spindle_rpm, band_hz=band_hz).teeth


@dataclass
class TraceDetection:
    """What :func:`detect_in_trace` found and how it looked.

    Attributes
    ----------
    report : DetectionReport
        Events, statistics and the declared latency.
    detectors : list of Detector
        The detectors run (every axis).
    teeth : int or None
        Teeth used (None: breakage and chipping were not looked for).
    spindle_rpm : float or None
        Spindle speed the detectors were given [min^-1].
    teeth_choice : TeethChoice or None
        Where the teeth came from (``--teeth``, the tool's metadata, the spectrum) and the evidence.
    notes : list of str
        Each detector that is off and why, with what turns it on (one line each).
    """

    report: DetectionReport
    detectors: list
    teeth: int | None
    spindle_rpm: float | None
    teeth_choice: TeethChoice | None = None
    notes: list = field(default_factory=list)

    def to_json(self) -> dict:
        """The detection's settings for EVENTS.json: detectors, teeth (with source and evidence), notes.

        Returns
        -------
        dict
        """
        out = {"detectors": [d.name for d in self.detectors]}
        out.update(self.teeth_choice.to_json() if self.teeth_choice is not None else {"teeth": self.teeth})
        if self.notes:
            out["notes"] = list(self.notes)
        return out


def detect_in_trace(trace: Recording, inputs: Recording, *, band_hz: float | None = None, teeth: int | None = None,
                    spindle_rpm: float | None = None, limits: TeachLimits | None = None,
                    force_limit_n: float | None = None, baseline_revs: int | None = None,
                    drive_modes_hz: Sequence[float] = (), drive_pitches_m: Sequence[float] = ()) -> TraceDetection:
    """Run the default detectors on every estimated force of a trace (``drivesense detect``'s rule).

    The teeth come from ``teeth``, the trace's tool or the spectrum of the forces and drive signals
    (:func:`~drivesense.events.teeth.resolve_teeth`); without them breakage and chipping are off and a
    note says so.  The spindle speed comes from ``spindle_rpm`` or the median of the trace's
    ``spindle_speed`` (it sets the latency the detectors declare); the taught limits serve the first axis.
    A detector the trace's sample rate or the estimate's bandwidth rules out (chatter on a 50 Hz trace) is
    left out with a note.

    Parameters
    ----------
    trace : Recording
        The drive-signal trace (its metadata may name the tool).
    inputs : Recording
        :func:`detector_inputs` of the trace and its estimated forces.
    band_hz : float, optional
        The estimate's bandwidth [Hz].
    teeth, spindle_rpm, limits, force_limit_n, baseline_revs, drive_modes_hz, drive_pitches_m
        As in :func:`default_detectors` (``--teeth``, ``--spindle-rpm``, ``--limits``, ``--force-limit``,
        ``--baseline-revs``; :func:`estimate_limits` gives ``band_hz``, ``drive_modes_hz`` and
        ``drive_pitches_m``).

    Raises
    ------
    ConfigError
        Neither a ``spindle_speed`` channel nor ``spindle_rpm``; no detector that can run on the trace.
    """
    if "spindle_speed" not in inputs.channels and spindle_rpm is None:
        raise ConfigError("the trace has no spindle_speed column: give the spindle speed with --spindle-rpm RPM")
    choice = resolve_teeth(trace, teeth, forces=inputs, spindle_rpm=spindle_rpm, band_hz=band_hz)
    z = choice.teeth
    notes = [choice.note] if choice.note else []
    rpm = spindle_rpm
    if rpm is None:
        rpm = float(np.median(inputs["spindle_speed"])) * 60.0 / (2 * np.pi)
        rpm = rpm if rpm > 0 else None
    axes = [c.split("_", 1)[1] for c in inputs.channels if c.startswith("force_")]
    limit = force_limit_n if force_limit_n is not None else (limits.force_limit_n if limits else None)
    detectors: list[Detector] = []
    for ax in axes:
        detectors += default_detectors(ax, teeth=z, spindle_rpm=rpm, limits=limits if ax == axes[0] else None,
                                       force_limit_n=limit, band_hz=band_hz, baseline_revs=baseline_revs,
                                       drive_modes_hz=drive_modes_hz, drive_pitches_m=drive_pitches_m)
    for det in [d for d in detectors if d.unusable(inputs.fs, rpm)]:
        detectors.remove(det)
        note = f"{_LABELS.get(det.name, det.name)} detection is off: {det.unusable(inputs.fs, rpm)}"
        notes += [] if note in notes else [note]
    if not detectors and notes:
        raise ConfigError("no detector can run on this trace (" + "; ".join(notes) + "): give --force-limit N "
                          "(collision/overload) or --limits LIMITS.json (teach-in), which run at any sample rate")
    return TraceDetection(run_detectors(inputs, detectors), detectors, z, rpm, choice, notes)
