"""Plausibility of controller traces: physically impossible samples, found, named, refused or repaired.

Traces exported by an edge device carry glitches: a spindle-speed sample of
-3.3e6 rpm, a position that jumps by centimetres in one sample and back (an
encoder glitch), a NaN.  :func:`check_channels` (arrays) and
:func:`check_plausibility` (a Recording) find them and return a
:class:`PlausibilityReport` that names each flagged sample: its channel, its
line in the source file (CSV: the file's line number, header and comments
counted; otherwise the sample index), its value (in the file's unit where
known, else SI) and why it was flagged.

What is checked, per channel of the data model (other channels, forces among
them, only for non-finite values: a force peak may be real):

- every channel: non-finite values (NaN, inf);
- ``spindle_speed``: beyond the physical limit (``|n| > 100 000 rpm``), or an
  isolated spike;
- ``{ax}_velocity`` (``|v| > 10 m/s``), ``{ax}_acceleration``
  (``|a| > 1000 m/s^2``): beyond the physical limit, or an isolated spike;
- ``{ax}_current``, ``{ax}_current_ref``, ``spindle_current``: isolated spikes;
- ``{ax}_position``, ``{ax}_table_position``: jumps, i.e. a step between two
  samples larger than the motion the trace allows: ``3 * max|v| * dt + 10 um``
  with ``max|v|`` the logged ``{ax}_velocity`` within 3 samples of the step,
  or ``2 m/s * dt + 10 um`` without a velocity channel.  A jump that comes
  back within 3 samples flags the samples between (an encoder glitch); a jump
  that stays is flagged as a step, which interpolation cannot repair.

An *isolated spike* is a sample off both neighbours, in the same direction,
while the neighbours agree.  "Off" means farther than the
largest of ``5 * (p99 - p1)`` of the channel (its spread without the extremes),
``30 * 1.4826 * MAD`` of its sample-to-sample differences (its noise and slope)
and a floor per quantity (10 mm/s, 2 m/s^2, 1 A, 100 rpm).  The thresholds are
generous on purpose: the simulator's traces (every scenario of
``drivesense simulate --list``) raise no flag; a real glitch is orders of
magnitude beyond them.  Samples at either end of a trace have one neighbour
and are only checked against the limits.  :class:`PlausibilityLimits` holds
every number.

A policy (:data:`BAD_SAMPLE_POLICIES`, the CLI's ``--bad-samples``) decides:
``refuse`` raises :class:`~drivesense.errors.ImplausibleSampleError` naming the
samples; ``repair`` replaces each flagged sample by linear interpolation of its
good neighbours, lists it in ``meta["repaired_samples"]`` and warns
(:class:`BadSampleWarning`); ``off`` reads the values as they are.

The data model (the limits, :class:`BadSample`, :class:`PlausibilityReport`,
:class:`BadSampleWarning`) lives in :mod:`drivesense.io.plausibility_report`
and is re-exported here.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .. import units as _units
from ..errors import ConfigError, ImplausibleSampleError, InvalidSignalError
from .plausibility_report import (SHOWN, BadSample, BadSampleWarning, PlausibilityLimits, PlausibilityReport,
                                  RPM, shows_rpm)

if TYPE_CHECKING:  # pragma: no cover
    from ..recording import Recording

__all__ = ["BAD_SAMPLE_POLICIES", "PlausibilityLimits", "BadSample", "PlausibilityReport", "BadSampleWarning",
           "check_channels", "check_plausibility", "repair_channels", "enforce_policy", "screen_recording",
           "check_policy", "repaired_meta"]

#: The values of ``bad_samples`` (``--bad-samples``): refuse (default), repair by interpolation, off (no check).
BAD_SAMPLE_POLICIES = ("refuse", "repair", "off")

#: A position that outruns its allowance in at least this many steps, and in more than this fraction of them,
#: has a wrong unit or rate rather than glitches (a note, not flags).
_SYSTEMATIC_COUNT = 10
_SYSTEMATIC_FRACTION = 0.05


# ------------------------------------------------------------------ formatting
def _fmt_amount(si: float, unit: str, factor: float) -> str:
    """An SI amount in `unit` (3 significant digits)."""
    return f"{si / factor:.3g} {unit}".rstrip()


def _fmt_dt(dt: float) -> str:
    return f"{dt * 1e3:.3g} ms"


# ------------------------------------------------------------------ the checks
def _channel_kind(name: str) -> str | None:
    """``"position"``, ``"spike"``, ``"angle"`` (finite only) or None (finite only)."""
    q = _units.quantity_of_channel(name)
    if q == _units.LENGTH and name[:2] in ("x_", "y_", "z_"):
        return "position"
    if q in (_units.VELOCITY, _units.ACCELERATION, _units.CURRENT, _units.ANGULAR_SPEED):
        return "spike"
    return None


def _limit(name: str, limits: PlausibilityLimits) -> float | None:
    q = _units.quantity_of_channel(name)
    return {_units.ANGULAR_SPEED: limits.spindle_speed_max, _units.VELOCITY: limits.velocity_max,
            _units.ACCELERATION: limits.acceleration_max}.get(q)


def _fill(x: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """`x` with the samples `bad` (bool mask) linearly interpolated from the others (edges held)."""
    if not bad.any():
        return x
    good = np.flatnonzero(~bad)
    out = x.copy()
    out[bad] = np.interp(np.flatnonzero(bad), good, x[good])
    return out


def _glitch_runs(x: np.ndarray, step_allow: np.ndarray, span_allow: Callable[[int, int], float],
                 max_run: int) -> tuple[list[tuple[int, int]], list[int]]:
    """Runs ``(k, j)`` of samples ``k..j-1`` off both neighbours ``k-1`` and ``j``, and unpaired jumps ``k``.

    A *jump* is a step ``x[k] - x[k-1]`` beyond ``step_allow[k-1]``.  A run starts with a jump at ``k`` and
    ends with a jump back at ``j <= k + max_run``, every sample between lies beyond the allowance from both
    neighbours on the same side, and the neighbours agree (``|x[j] - x[k-1]| <= span_allow(k-1, j)``).
    """
    d = np.diff(x)
    jumps = np.flatnonzero(np.abs(d) > step_allow) + 1        # sample k after the step k-1 -> k
    is_jump = np.zeros(x.size + 1, dtype=bool)
    is_jump[jumps] = True
    runs, unpaired = [], []
    consumed = 0
    for k in jumps.tolist():
        if k < consumed:
            continue
        sign = np.sign(d[k - 1])
        found = None
        for j in range(k + 1, min(k + max_run, x.size - 1) + 1):
            if not is_jump[j] or np.sign(d[j - 1]) != -sign:
                continue
            if abs(x[j] - x[k - 1]) > span_allow(k - 1, j):
                continue
            inner = range(k, j)
            if all(sign * (x[m] - x[k - 1]) > span_allow(k - 1, m) and sign * (x[m] - x[j]) > span_allow(m, j)
                   for m in inner):
                found = j
                break
        if found is None:
            unpaired.append(k)
            consumed = k + 1
        else:
            runs.append((k, found))
            consumed = found + 1
    return runs, unpaired


def _check_spikes(name: str, x: np.ndarray, skip: np.ndarray, unit: str, factor: float,
                  limits: PlausibilityLimits) -> list[tuple[int, str, bool]]:
    """Isolated spikes of a current, velocity, acceleration or speed channel (filled `x`, SI)."""
    if x.size < 3:
        return []
    lo, hi = np.percentile(x, [1.0, 99.0])
    d = np.diff(x)
    mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    floor = limits.spike_floor.get(_units.quantity_of_channel(name), 0.0)
    thr = max(limits.spike_spread_factor * float(hi - lo), limits.spike_mad_factor * mad, floor)
    runs, _ = _glitch_runs(x, np.full(x.size - 1, thr), lambda p, q: thr, limits.spike_run)
    out = []
    for k, j in runs:
        off = float(min(np.min(np.abs(x[k:j] - x[k - 1])), np.min(np.abs(x[k:j] - x[j]))))
        what = "an isolated spike" if j - k == 1 else f"a spike of {j - k} samples"
        reason = (f"is {what}: {_fmt_amount(off, unit, factor)} off both neighbours, which agree within "
                  f"{_fmt_amount(abs(x[j] - x[k - 1]), unit, factor)} (threshold {_fmt_amount(thr, unit, factor)}: "
                  f"{limits.spike_spread_factor:g} x the channel's spread {_fmt_amount(hi - lo, unit, factor)})")
        out += [(m, reason, True) for m in range(k, j) if not skip[m]]
    return out


def _check_position(name: str, x: np.ndarray, skip: np.ndarray, unit: str, factor: float, dt: np.ndarray,
                    velocity: tuple[str, np.ndarray] | None, limits: PlausibilityLimits,
                    notes: list[str]) -> list[tuple[int, str, bool]]:
    """Jumps of a position channel (filled `x`, SI) against its axis's logged velocity or the hard limit.

    Jumps in more than :data:`_SYSTEMATIC_FRACTION` of the steps (and at least :data:`_SYSTEMATIC_COUNT`) are
    a unit or rate problem, not glitches: a note is appended to `notes` instead.
    """
    if x.size < 2:
        return []
    if velocity is not None:
        v = np.abs(velocity[1])
        w = int(limits.position_window)
        padded = np.pad(v, w, mode="edge")
        vloc = np.lib.stride_tricks.sliding_window_view(padded, 2 * w + 1).max(axis=1)
        speed = np.maximum(vloc[1:], vloc[:-1])
        allow = limits.position_factor * speed * dt + limits.position_tolerance
        basis = (f"the logged {velocity[0]} allows at most {{allowed}} per step of {{dt}} "
                 f"({limits.position_factor:g} x its largest |v| nearby + {limits.position_tolerance * 1e6:g} um)")
    else:
        allow = limits.position_speed_max * dt + limits.position_tolerance
        basis = (f"at most {{allowed}} per step of {{dt}} without a velocity channel "
                 f"({limits.position_speed_max:g} m/s + {limits.position_tolerance * 1e6:g} um)")
    cum = np.concatenate([[0.0], np.cumsum(allow)])
    jumps = np.flatnonzero(np.abs(np.diff(x)) > allow)
    out: list[tuple[int, str, bool]] = []
    if jumps.size >= _SYSTEMATIC_COUNT and jumps.size > _SYSTEMATIC_FRACTION * (x.size - 1):
        k = int(jumps[0]) + 1
        notes.append(f"{name} moves farther than allowed in {jumps.size} of {x.size - 1} steps (first a step of "
                     f"{(x[k] - x[k - 1]) / factor:+.3g} {unit}; "
                     + basis.format(allowed=_fmt_amount(allow[k - 1], unit, factor), dt=_fmt_dt(dt[k - 1]))
                     + "): too many for glitches, not flagged; check the units of the position"
                     + (f" and of {velocity[0]}" if velocity is not None else "") + " and the sample rate")
        return out
    runs, unpaired = _glitch_runs(x, allow, lambda p, q: float(cum[q] - cum[p]), limits.position_run)
    for k, j in runs:
        allowed = basis.format(allowed=_fmt_amount(allow[k - 1], unit, factor), dt=_fmt_dt(dt[k - 1]))
        for m in range(k, j):
            line = x[k - 1] + (x[j] - x[k - 1]) * (m - k + 1) / (j - k + 1)
            reason = (f"is {(x[m] - line) / factor:+.3g} {unit} off the line between its neighbours: the position "
                      f"jumps away and back within {j - k} sample{'s' if j - k > 1 else ''} ({allowed})")
            if not skip[m]:
                out.append((m, reason, True))
    for k in unpaired:
        size = x[k] - x[k - 1]
        reason = (f"follows a position step of {size / factor:+.3g} {unit} that stays ("
                  + basis.format(allowed=_fmt_amount(allow[k - 1], unit, factor), dt=_fmt_dt(dt[k - 1]))
                  + "): not an isolated sample, interpolation cannot repair it")
        if not skip[k]:
            out.append((k, reason, False))
    return out


def _steps(n: int, time: ArrayLike | None, fs: float | None) -> np.ndarray:
    """Sample steps [s] (n - 1 of them): from the time stamps (bad steps -> their median) or 1/fs."""
    if time is not None:
        t = np.asarray(time, dtype=np.float64)
        if t.shape != (n,):
            raise InvalidSignalError(f"time has {t.size} stamps, the channels {n} samples")
        dt = np.diff(t)
        ok = np.isfinite(dt) & (dt > 0)
        typical = float(np.median(dt[ok])) if ok.any() else (1.0 / fs if fs else 1.0)
        return np.where(ok, dt, typical)
    if fs is None or not fs > 0:
        raise ConfigError("check_channels needs the time stamps (time=) or the sample rate (fs=)")
    return np.full(max(n - 1, 0), 1.0 / float(fs))


def check_channels(channels: Mapping[str, ArrayLike], *, time: ArrayLike | None = None, fs: float | None = None,
                   units: Mapping[str, str] | None = None, source: str = "trace",
                   limits: PlausibilityLimits | None = None) -> PlausibilityReport:
    """Find physically impossible samples in SI channel arrays.

    Parameters
    ----------
    channels : mapping of str to array_like
        Canonical channel name -> samples [SI unit of the channel's quantity],
        all of one length; may hold NaN/inf.
    time : array_like, optional
        Time stamps of the samples [s] (e.g. a CSV time column, possibly with
        jitter); sets the step of each position check.
    fs : float, optional
        Sample rate [Hz] when there are no time stamps.
    units : mapping of str to str, optional
        Unit each channel was given in (a CSV header's), for the values and
        reasons of the report; default SI.
    source : str, optional
        Name of the trace in messages (file name).
    limits : PlausibilityLimits, optional
        The thresholds (default :class:`PlausibilityLimits`).

    Returns
    -------
    PlausibilityReport
        Samples named by index (``line`` None: see :meth:`PlausibilityReport.located`).

    Raises
    ------
    InvalidSignalError
        Channels of different lengths, or not 1-D.
    ConfigError
        Neither `time` nor `fs`.
    """
    limits = limits or PlausibilityLimits()
    units = dict(units or {})
    arrays = {}
    for name, values in channels.items():
        a = np.asarray(values, dtype=np.float64)
        if a.ndim != 1:
            raise InvalidSignalError(f"channel {name!r} must be 1-D, got shape {a.shape}")
        arrays[name] = a
    n = next(iter(arrays.values())).size if arrays else 0
    if any(a.size != n for a in arrays.values()):
        raise InvalidSignalError("channels of different lengths: "
                                 + ", ".join(f"{k} {a.size}" for k, a in arrays.items()))
    dt = _steps(n, time, fs)

    def display(name: str) -> tuple[str, float]:
        quantity = _units.quantity_of_channel(name)
        unit = units.get(name) or (_units.si_unit(quantity) if quantity else "1")
        return unit, _units.unit_info(unit).factor

    flagged: dict[str, list[tuple[int, str, bool]]] = {}
    filled: dict[str, np.ndarray] = {}
    notes: list[str] = []
    checked = []
    order = sorted(arrays, key=lambda c: _channel_kind(c) == "position")   # velocities before positions
    for name in order:
        x = arrays[name]
        unit, factor = display(name)
        found: list[tuple[int, str, bool]] = []
        bad = ~np.isfinite(x)
        found += [(int(i), "is not a finite number", True) for i in np.flatnonzero(bad)]
        kind = _channel_kind(name)
        if kind is None or bad.all():
            flagged[name] = found
            continue
        checked.append(name)
        limit = _limit(name, limits)
        if limit is not None:
            over = np.isfinite(x) & (np.abs(x) > limit)
            if over.any():
                text = _fmt_amount(limit, unit, factor)
                if shows_rpm(name, unit):
                    text += f" ({limit / RPM:.6g} rpm)"
                found += [(int(i), f"is beyond the physical limit of +-{text}", True) for i in np.flatnonzero(over)]
                bad = bad | over
        xf = _fill(x, bad)
        if kind == "spike":
            found += _check_spikes(name, xf, bad, unit, factor, limits)
            spikes = np.zeros(n, dtype=bool)
            spikes[[i for i, _, _ in found]] = True
            filled[name] = _fill(x, spikes | bad) if found else xf
        else:
            axis_velocity = f"{name[0]}_velocity"
            velocity = (axis_velocity, filled[axis_velocity]) if axis_velocity in filled else None
            found += _check_position(name, xf, bad, unit, factor, dt, velocity, limits, notes)
        flagged[name] = sorted(found)
    samples = []
    for name in arrays:                     # the channels' order
        unit, factor = display(name)
        x = arrays[name]
        samples += [BadSample(name, i, None, float(x[i]) / factor, unit, reason, ok) for i, reason, ok in flagged[name]]
    return PlausibilityReport(tuple(samples), source, tuple(c for c in arrays if c in checked), n, limits,
                              tuple(notes))


def check_plausibility(recording: Recording, *, units: Mapping[str, str] | None = None,
                       limits: PlausibilityLimits | None = None) -> PlausibilityReport:
    """Find physically impossible samples in a Recording (see the module's docstring for the checks).

    Parameters
    ----------
    recording : Recording
        The trace (SI).
    units : mapping of str to str, optional
        Units to state the values in, per channel (default SI).
    limits : PlausibilityLimits, optional
        The thresholds.

    Returns
    -------
    PlausibilityReport
        Samples named by their index (``sample 16``).

    Examples
    --------
    >>> import numpy as np
    >>> from drivesense.recording import Recording
    >>> n = np.full(200, 600.0); n[50] = -3.3e6 * 2 * np.pi / 60
    >>> report = check_plausibility(Recording.from_arrays({"spindle_speed": n}, fs=500.0))
    >>> [(s.channel, s.index) for s in report]
    [('spindle_speed', 50)]
    """
    return check_channels({c: recording[c] for c in recording.channels}, fs=recording.fs, units=units,
                          source=recording.name or "recording", limits=limits)


def repair_channels(channels: Mapping[str, ArrayLike], report: PlausibilityReport) -> tuple[dict, list[dict]]:
    """Replace every flagged sample by linear interpolation of its channel's good neighbours.

    Parameters
    ----------
    channels : mapping of str to array_like
        The channels the report was made from [SI].
    report : PlausibilityReport
        Its flagged samples.

    Returns
    -------
    channels : dict of str to numpy.ndarray
        New arrays (unflagged channels copied).
    repaired : list of dict
        One entry per sample: :meth:`BadSample.to_dict` plus ``replaced_by``
        (the interpolated value, in the sample's unit).

    Raises
    ------
    ImplausibleSampleError
        The report holds samples interpolation cannot stand in for (a
        position step that stays, a run longer than ``limits.max_repair``, a
        channel without good samples).
    """
    problems = report.unrepairable()
    out = {k: np.array(v, dtype=np.float64) for k, v in channels.items()}
    groups = report.by_channel()
    for channel, flagged in groups.items():
        if len(flagged) >= out[channel].size:
            problems.append(f"{channel}: every sample is flagged")
    if problems:
        raise _error(f"{report.source}: --bad-samples repair cannot mend this trace: " + "; ".join(problems[:SHOWN])
                     + (f"; and {len(problems) - SHOWN} more" if len(problems) > SHOWN else "")
                     + ". Correct the file, or read it as it is with --bad-samples off.", report)
    repaired = []
    for channel, flagged in groups.items():
        x = out[channel]
        bad = np.zeros(x.size, dtype=bool)
        bad[[s.index for s in flagged]] = True
        out[channel] = _fill(x, bad)
        factor = _units.unit_info(flagged[0].unit).factor
        repaired += [{**s.to_dict(), "replaced_by": float(out[channel][s.index]) / factor} for s in flagged]
    return out, repaired


def _error(message: str, report: PlausibilityReport) -> ImplausibleSampleError:
    exc = ImplausibleSampleError(message)
    exc.report = report
    return exc


def check_policy(policy: Any) -> str:
    """`policy` if it is one of :data:`BAD_SAMPLE_POLICIES`, else ConfigError naming ``--bad-samples``.

    Parameters
    ----------
    policy : str
        ``"refuse"``, ``"repair"`` or ``"off"``.

    Returns
    -------
    str
    """
    if policy not in BAD_SAMPLE_POLICIES:
        raise ConfigError(f"--bad-samples must be one of {', '.join(BAD_SAMPLE_POLICIES)}, got {policy!r}")
    return policy


def enforce_policy(channels: Mapping[str, ArrayLike], report: PlausibilityReport, policy: str = "refuse",
                   *, stacklevel: int = 2) -> tuple[dict, list[dict]]:
    """Apply ``--bad-samples`` to a report: refuse, repair (and warn) or pass the channels through.

    Parameters
    ----------
    channels : mapping of str to array_like
        The channels the report was made from [SI].
    report : PlausibilityReport
        The check's result.
    policy : {"refuse", "repair", "off"}, optional
        What to do with flagged samples.
    stacklevel : int, optional
        Of the :class:`BadSampleWarning` a repair raises [-].

    Returns
    -------
    channels : dict of str to numpy.ndarray
        The channels (repaired ones replaced).
    repaired : list of dict
        What was repaired (:func:`repair_channels`); [] unless ``repair``.

    Raises
    ------
    ImplausibleSampleError
        ``refuse`` and something was flagged, or ``repair`` and it cannot be
        repaired; the message names channel, line, value and why, and the
        option that repairs or skips.
    """
    policy = check_policy(policy)
    if policy == "off":
        return dict(channels), []
    for note in report.notes:
        warnings.warn(f"{report.source}: {note}", BadSampleWarning, stacklevel=stacklevel + 1)
    if report.ok:
        return dict(channels), []
    if policy == "refuse":
        how = ("Give --bad-samples repair to replace them by linear interpolation of their neighbours, or "
               "--bad-samples off to read them as they are.") if not report.unrepairable() else \
              "Correct the file, or read it as it is with --bad-samples off."
        raise _error(f"{report.summary()}. {how}", report)
    out, repaired = repair_channels(channels, report)
    n = len(repaired)
    done = [f"{s.describe()} -> {r['replaced_by']:.6g} {s.unit}".rstrip()
            for s, r in zip(report.samples[:SHOWN], repaired)]
    warnings.warn(f"{report.source}: repaired {n} implausible sample{'s' if n != 1 else ''} by linear "
                  "interpolation (--bad-samples repair): " + "; ".join(done)
                  + (f"; and {n - SHOWN} more" if n > SHOWN else ""), BadSampleWarning, stacklevel=stacklevel + 1)
    return out, repaired


def repaired_meta(meta: Mapping, repaired: list[dict]) -> dict:
    """``{"repaired_samples": [...]}``: the list in `meta` extended by `repaired` (earlier repairs kept).

    Parameters
    ----------
    meta : mapping
        A Recording's metadata (its sidecar's, for a CSV file).
    repaired : list of dict
        New entries (:func:`repair_channels`).

    Returns
    -------
    dict
        To merge into the metadata.
    """
    before = meta.get("repaired_samples", [])
    return {"repaired_samples": [*(before if isinstance(before, list) else []), *repaired]}


def screen_recording(recording: Recording, policy: str = "refuse", *, limits: PlausibilityLimits | None = None,
                     source: str | None = None, stacklevel: int = 2) -> Recording:
    """Check a Recording and apply ``--bad-samples``: the recording itself, a repaired copy, or an error.

    Parameters
    ----------
    recording : Recording
        The trace (SI); samples are named by index.
    policy : {"refuse", "repair", "off"}, optional
        What to do with flagged samples (``off``: nothing is checked).
    limits : PlausibilityLimits, optional
        The thresholds.
    source : str, optional
        Name of the trace in messages (default: the recording's name).
    stacklevel : int, optional
        Of the :class:`BadSampleWarning` a repair raises [-].

    Returns
    -------
    Recording
        Unchanged when nothing was flagged; repaired copies carry
        ``meta["repaired_samples"]`` and a provenance step.

    Raises
    ------
    ImplausibleSampleError
        See :func:`enforce_policy`.
    """
    if check_policy(policy) == "off":
        return recording
    report = check_plausibility(recording, limits=limits)
    if source is not None:
        report = dataclasses.replace(report, source=source)
    if report.ok and not report.notes:
        return recording
    channels, repaired = enforce_policy({c: recording[c] for c in recording.channels}, report, policy,
                                        stacklevel=stacklevel + 1)
    if not repaired:
        return recording
    fixed = recording.with_channels({c: channels[c] for c in report.by_channel()})
    return fixed.with_meta(**repaired_meta(recording.meta, repaired)).with_provenance(
        f"--bad-samples repair: {len(repaired)} implausible sample(s) replaced by linear interpolation "
        "(meta['repaired_samples'])")
