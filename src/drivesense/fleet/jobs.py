"""What a batch does to one input: estimate, detect, wear, identify (the same rules as the single-file commands).

A job is built once on the client (:meth:`BatchJob.prepare`: the estimator made
from its files and fitted on the idle runs), shipped to the workers, and run on
each input by :meth:`BatchJob.run`, which writes the input's result files
(atomically) and returns its summary row.  :meth:`BatchJob.config` describes
everything that decides the result -- the method, every option, and the
*content* (not the path) of every file it reads -- so that a batch can tell
which results are still valid.

=========  =====================================  ==================================================
job        input                                  result files
=========  =====================================  ==================================================
estimate   drive-signal trace (CSV, .nc, .xml)    ``<stem>.force.nc``: the estimated force Recording
detect     drive-signal trace                     ``<stem>.events.json``: the events (``detect``'s JSON)
wear       session table of cuts (CSV)            ``<stem>.wear.json``: the wear history
identify   FRF excitation trace                   ``<stem>.axis.toml`` + ``<stem>.frf.json``
=========  =====================================  ==================================================
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from drivesense.errors import ConfigError

__all__ = ["BatchJob", "EstimateJob", "DetectJob", "WearJob", "IdentifyJob", "JOBS", "file_digest"]

#: Bytes read at a time when hashing a file.
_BLOCK = 1 << 20


def file_digest(path: str | Path) -> str:
    """BLAKE2b-128 of a file's bytes, hex.

    Parameters
    ----------
    path : str or Path
        The file (a folder: every file in it, by relative name, sorted).
    """
    h = hashlib.blake2b(digest_size=16)
    p = Path(path)
    files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
    for q in files:
        if p.is_dir():
            h.update(str(q.relative_to(p)).encode() + b"\0")
        with open(q, "rb") as fh:
            while block := fh.read(_BLOCK):
                h.update(block)
    return h.hexdigest()


def _digest_or_none(path: Path | None, option: str) -> str | None:
    if path is None:
        return None
    if not Path(path).exists():
        raise ConfigError(f"{option} {path}: no such file")
    return file_digest(path)


def _stats(values: np.ndarray) -> dict:
    v = np.asarray(values, dtype=float)
    return {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max()), "std": float(v.std())}


@dataclass
class BatchJob:
    """A method with its options, run on many inputs.  Subclasses set :attr:`kind` and :meth:`_run`.

    Parameters
    ----------
    reader : dict, optional
        How CSV traces are read: ``fs``, ``resample``, ``assume_si``, ``bad_samples`` (``--fs`` ...).
    """

    kind: ClassVar[str] = ""
    #: Suffixes of the result files (the first names the main one).
    outputs: ClassVar[tuple[str, ...]] = ()
    reader: dict = field(default_factory=dict)
    prepared: bool = field(default=False, init=False, repr=False, compare=False)

    def ensure_prepared(self) -> None:
        """:meth:`prepare` unless it ran already (a job run in several batches is prepared once)."""
        if not self.prepared:
            self.prepare()
            self.prepared = True

    def config(self) -> dict:
        """Everything that decides the result, as strict JSON (file contents by digest)."""
        from drivesense import __version__

        reader = {k: v for k, v in sorted(self.reader.items()) if v not in (None, False)}    # defaults left out
        return {"kind": self.kind, "version": __version__, "reader": reader, **self._config()}

    def config_hash(self) -> str:
        """BLAKE2b-128 of :meth:`config` (hex)."""
        text = json.dumps(self.config(), sort_keys=True, allow_nan=False)
        return hashlib.blake2b(text.encode(), digest_size=16).hexdigest()

    def prepare(self) -> None:
        """Client side, once: build what every input shares (estimator, fitted friction map)."""

    def run(self, source: Any, out_stem: Path) -> dict:
        """Run on one input; write its result files ``out_stem`` + suffix (atomically); its summary row.

        Parameters
        ----------
        source : Recording or Path
            The input: a Recording (traces, already read) or a file path (wear session tables).
        out_stem : Path
            Result files are this path plus :attr:`outputs`' suffixes.

        Returns
        -------
        dict
            Summary values (numbers and strings; the batch adds the input, key, status, timing).
        """
        return self._run(source, out_stem)

    # -- for subclasses
    def _config(self) -> dict:
        raise NotImplementedError

    def _run(self, source: Any, out_stem: Path) -> dict:
        raise NotImplementedError

    def read(self, path: Path, axis_name: str = "x"):
        """Read a trace file as ``drivesense estimate`` does (units from the header, ``reader`` options).

        Parameters
        ----------
        path : Path
            CSV, .nc or .xml trace.
        axis_name : str
            Axis letter of a CSV's bare channel names.
        """
        from drivesense.io import read_trace

        return read_trace(path, axis_name, **self.reader)


@dataclass
class EstimateJob(BatchJob):
    """Force estimate of each trace (``drivesense estimate``'s methods and friction rules).

    Parameters
    ----------
    method : str
        ``--method``.
    axis_file, axes_file, model_dir : Path, optional
        ``--axis``, ``--axes``, ``--model``.
    idle : list of Path
        ``--idle`` runs (friction map, fitted once on the client, in this order).
    tare : tuple of float, optional
        ``--tare START:END`` [s] (applied to each trace).
    axis_name : str
        ``--axis-name``.
    """

    kind: ClassVar[str] = "estimate"
    outputs: ClassVar[tuple[str, ...]] = (".force.nc",)
    method: str = "vibration"
    axis_file: Path | None = None
    axes_file: Path | None = None
    model_dir: Path | None = None
    idle: list = field(default_factory=list)
    tare: tuple | None = None
    axis_name: str = "x"
    estimator: Any = field(default=None, init=False, repr=False)

    def _config(self) -> dict:
        return {"method": self.method, "axis_name": self.axis_name, "tare": list(self.tare) if self.tare else None,
                "axis_file": _digest_or_none(self.axis_file, "--axis"),
                "axes_file": _digest_or_none(self.axes_file, "--axes"),
                "model": _digest_or_none(self.model_dir, "--model"),
                "idle": [_digest_or_none(p, "--idle") for p in self.idle]}     # in order: the fit depends on it

    def prepare(self) -> None:
        from drivesense.estimate.registry import make_from_files
        from drivesense.monitor.config import fit_or_tare

        est = make_from_files(self.method, axis_file=self.axis_file, axes_file=self.axes_file,
                              model_dir=self.model_dir, axis_name=self.axis_name)
        idle_runs = (lambda: [self.read(Path(p), self.axis_name) for p in self.idle]) if self.idle else None
        if not (est.drive == "ballscrew" and self.tare is not None and not self.idle):
            fit_or_tare(est, self.method, idle_runs=idle_runs, tare=self.tare, trace=None)
        # else: the tare window calibrates (a copy of) the estimator on each trace, in forces()
        self.estimator = est

    def read_input(self, path: Path):
        """The trace, read as the method needs it (a ball-screw axis' channels, or a 3-axis NC trace).

        Parameters
        ----------
        path : Path
            The input file.
        """
        est = self._est()
        return self.read(path, self.axis_name) if est.drive == "ballscrew" else self.read(path)

    def _est(self):
        if self.estimator is None:
            raise ConfigError("the batch job was not prepared (call prepare() on the client first)")
        return self.estimator

    def forces(self, rec):
        """The estimator used and the estimated force Recording of one trace.

        A tare window calibrates a copy of the estimator on the trace.

        Parameters
        ----------
        rec : Recording
            The trace.
        """
        est = self._est()
        if self.tare is not None:
            est = copy.deepcopy(est)
            est.tare(rec, *self.tare)
        return est, est.estimate(rec)

    def _run(self, rec: Any, out_stem: Path) -> dict:
        from drivesense.io import write_recording

        est, force = self.forces(rec)
        write_recording(force, Path(f"{out_stem}{self.outputs[0]}"))
        row = {"samples": int(rec.n_samples), "fs_hz": float(rec.fs), "duration_s": float(rec.duration),
               "latency_s": float(force.meta.get("latency_s", 0.0))}
        for ch in force.channels:
            row.update({f"{ch}_{k}": v for k, v in _stats(force[ch]).items()})
        score = _score(est, rec, force)
        if score is not None:
            row.update(score)
        return row


def _score(est, rec, force) -> dict | None:
    """Error of the estimate against the trace's own reference force, when it has one (as ``estimate`` does)."""
    channel = getattr(est, "output_channel", None)
    if channel is None or channel not in rec.channels or getattr(est, "drive", "") != "ballscrew":
        return None
    from drivesense.estimate.design import lowpass_sos
    from drivesense.score import score_estimate

    window = (rec.t0 + est.settle_time(rec.fs), rec.t0 + rec.duration)
    s = score_estimate(force, rec, channel=channel, window=tuple(rec.meta.get("score_window", window)),
                       sos=lowpass_sos(est.signal, rec.fs)).to_dict()
    return {f"score_{k}": float(v) for k, v in s.items() if isinstance(v, (int, float)) and math.isfinite(v)}


@dataclass
class DetectJob(EstimateJob):
    """Events in each trace (``drivesense detect``'s estimator, detectors and options).

    Takes :class:`EstimateJob`'s parameters (the estimator: ``method``, ``axis_file``, ``idle`` ...) and:

    Parameters
    ----------
    teeth : int, optional
        ``--teeth`` (default: the trace's tool, else inferred from the spectrum: see
        :func:`drivesense.events.teeth.resolve_teeth`).
    spindle_rpm : float, optional
        ``--spindle-rpm`` [min^-1] (default: the trace's spindle_speed).
    limits : Path, optional
        ``--limits`` LIMITS.json.
    force_limit : float, optional
        ``--force-limit`` [N].
    baseline_revs : int
        ``--baseline-revs``.
    """

    kind: ClassVar[str] = "detect"
    outputs: ClassVar[tuple[str, ...]] = (".events.json",)
    teeth: int | None = None
    spindle_rpm: float | None = None
    limits: Path | None = None
    force_limit: float | None = None
    baseline_revs: int = 8
    taught: Any = field(default=None, init=False, repr=False)

    def _config(self) -> dict:
        return {**super()._config(), "teeth": self.teeth, "spindle_rpm": self.spindle_rpm,
                "limits": _digest_or_none(self.limits, "--limits"), "force_limit": self.force_limit,
                "baseline_revs": self.baseline_revs}

    def prepare(self) -> None:
        from drivesense.io import read_json_file
        from drivesense.events import TeachLimits

        super().prepare()
        if self.limits is not None:
            self.taught = TeachLimits.from_json(read_json_file(self.limits, "--limits file"))

    def _run(self, rec: Any, out_stem: Path) -> dict:
        from drivesense.io import write_json_file
        from drivesense.events.detector import events_to_json
        from drivesense.events.pipeline import detect_in_trace, detector_inputs, estimate_limits

        est, force = self.forces(rec)
        inputs = detector_inputs(rec, force)
        found = detect_in_trace(rec, inputs, **estimate_limits(est), teeth=self.teeth, spindle_rpm=self.spindle_rpm, limits=self.taught,
                                force_limit_n=self.force_limit, baseline_revs=self.baseline_revs)
        events = found.report.events
        payload = events_to_json(events, found.report.latency_s)
        payload.update({"method": self.method, **found.to_json(),
                        "estimator_latency_s": float(inputs.meta["latency_s"])})
        write_json_file(Path(f"{out_stem}{self.outputs[0]}"), payload)
        kinds = sorted({e.kind for e in events})
        return {"samples": int(rec.n_samples), "duration_s": float(rec.duration), "events": len(events),
                "event_kinds": ",".join(kinds), "first_event_s": float(events[0].time_s) if events else None,
                "teeth": found.teeth, "teeth_source": found.teeth_choice.source if found.teeth_choice else None,
                "latency_s": float(found.report.latency_s)}


@dataclass
class WearJob(BatchJob):
    """Wear history of each session table (``drivesense wear track``).

    Parameters
    ----------
    diameter : float, optional
        Tool diameter [m] when the table has none (``--diameter`` is in mm at the CLI).
    flutes : int, optional
        ``--flutes``.
    mode : str
        ``--mode`` up | down.
    reference : int, optional
        ``--reference`` cut.
    """

    kind: ClassVar[str] = "wear"
    outputs: ClassVar[tuple[str, ...]] = (".wear.json",)
    diameter: float | None = None
    flutes: int | None = None
    mode: str = "down"
    reference: int | None = None

    def _config(self) -> dict:
        return {"diameter": self.diameter, "flutes": self.flutes, "mode": self.mode, "reference": self.reference}

    def _run(self, path: Any, out_stem: Path) -> dict:
        from drivesense.identify.coefficients import read_cut_table
        from drivesense.io import write_json_file
        from drivesense.condition.wear import track_wear

        table = read_cut_table(path, diameter=self.diameter, flutes=self.flutes, mode=self.mode)
        report = track_wear(table, reference=self.reference)
        write_json_file(Path(f"{out_stem}{self.outputs[0]}"), report.to_dict())
        last = report.states[-1]
        return {"calibrations": len(report.states), "state": report.state, "mode": report.mode,
                "alarm_index": report.alarm_index, "alarm_distance_m": report.alarm_distance,
                "Ktc_last": float(last.Ktc), "Kte_last": float(last.Kte), "distance_last_m": float(last.distance)}


@dataclass
class IdentifyJob(BatchJob):
    """Ball-screw parameters from each FRF excitation trace (``drivesense identify frf``).

    Parameters
    ----------
    fix : dict
        ``--fix``: K_t [N*m/A] and lead [m] required, any fit parameter or T_a, omega_cc optional.
    fmin, fmax : float
        Fitted band [Hz].
    nperseg : int
        Welch segment length.
    axis_name : str
        ``--axis-name``.
    """

    kind: ClassVar[str] = "identify"
    outputs: ClassVar[tuple[str, ...]] = (".axis.toml", ".frf.json")
    fix: dict = field(default_factory=dict)
    fmin: float = 5.0
    fmax: float = 2000.0
    nperseg: int = 8192
    axis_name: str = "x"

    def _config(self) -> dict:
        return {"fix": dict(sorted(self.fix.items())), "fmin": self.fmin, "fmax": self.fmax,
                "nperseg": self.nperseg, "axis_name": self.axis_name}

    def prepare(self) -> None:
        from drivesense.identify.frf import split_fix

        split_fix(self.fix)                            # K_t and lead given: refused on the client, not per input

    def read_input(self, path: Path):
        """The excitation trace (the axis' channels).

        Parameters
        ----------
        path : Path
            The input file.
        """
        return self.read(path, self.axis_name)

    def _run(self, rec: Any, out_stem: Path) -> dict:
        from drivesense.identify.frf import fit_frf, measure_frf, split_fix
        from drivesense.io import write_json_file
        from drivesense.io.axis_file import write_axis_file

        K_t, lead, chain, given = split_fix(self.fix)
        measured = measure_frf(rec, K_t=K_t, lead=lead, axis_name=self.axis_name, nperseg=self.nperseg,
                               fmin=self.fmin, fmax=self.fmax)
        fit = fit_frf(measured, K_t=K_t, lead=lead, fixed=given, **chain)
        write_axis_file(Path(f"{out_stem}{self.outputs[0]}"), fit.axis, fit.signal)
        info = fit.to_dict()
        info.pop("seconds", None)                   # wall time: not part of a reproducible result
        write_json_file(Path(f"{out_stem}{self.outputs[1]}"), info)
        return {**{k: float(fit.values[k]) for k in ("J_r", "M_t", "C_t", "C_k", "D_r", "K_r", "T_b")},
                "normalised_rms": float(fit.normalised_rms), "iterations": int(fit.iterations)}


#: Job classes by name (``drivesense batch NAME``).
JOBS: dict[str, type[BatchJob]] = {j.kind: j for j in (EstimateJob, DetectJob, WearJob, IdentifyJob)}
