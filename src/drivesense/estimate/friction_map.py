"""Friction maps from idling runs (first paper, Sec. 4), through the estimator's own kernel.

Friction of a ball-screw stage is position dependent but highly repeatable.
Running the cutting trajectory without cutting ("idling", 3 times in the
paper) and reading what the uncompensated estimator reports gives the friction
in that estimator's modal space as a function of table position; averaging the
runs and subtracting the map during the cut removes it.  The spread between
runs is the map's repeatability.

The map is read from the very kernel that estimates (run with no
compensation), so a method's map and its estimate cannot drift apart: MEDOB's
map is in observer form because MEDOB estimates in observer form.  The
kernel's output is lined up with the table position by removing the
discretisation's own delay and, with a backward pass of the same low-pass, its
phase lag; the kernel applies the map through the same low-pass when it
compensates.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np
from scipy import signal as sps

from drivesense.errors import CoverageError, InvalidSignalError
from drivesense.estimate.design import lowpass_sos
from drivesense.estimate.kernel import FrictionTable, KernelState, run_kernel
from drivesense.recording import Recording

if TYPE_CHECKING:
    from drivesense.estimate.ballscrew import BallScrewEstimator

__all__ = ["FrictionMap", "build_friction_map", "uncompensated_estimate"]


@dataclass
class FrictionMap:
    """Friction versus table position in one estimator's space.

    Attributes
    ----------
    position : ndarray
        Bin centres [m].
    force : ndarray
        Run-averaged friction as the uncompensated estimator reads it [N].
    spread : ndarray
        Standard deviation across runs in each bin [N] (NaN with one run).
    runs : ndarray, shape (n_runs, n_bins)
        Per-run maps [N] (NaN where a run did not reach a bin).
    direction : int
        Sign of the feed during the idle runs (+1, -1, or 0 for standing).
    method : str
        Name of the estimator the map belongs to.
    """

    position: np.ndarray
    force: np.ndarray
    spread: np.ndarray
    runs: np.ndarray
    direction: int
    method: str

    @property
    def bin_width(self) -> float:
        """Bin spacing [m]."""
        return float(self.position[1] - self.position[0]) if self.position.size > 1 else 0.0

    @property
    def repeatability_rms(self) -> float:
        """RMS over bins of the run-to-run standard deviation [N]."""
        s = self.spread[np.isfinite(self.spread)]
        return float(np.sqrt(np.mean(s**2))) if s.size else float("nan")

    def table(self) -> FrictionTable:
        """Uniform-grid lookup table for the compiled kernel."""
        return FrictionTable(self.force, self.position[0], self.bin_width or 1.0)

    def check_coverage(self, table_position: np.ndarray, name: str = "trace") -> None:
        """Raise :class:`CoverageError` if ``table_position`` [m] leaves the mapped range.

        Parameters
        ----------
        table_position : ndarray
            Table positions of the trace to estimate [m].
        name : str
            Trace name for the message.
        """
        lo, hi = self.position[0], self.position[-1]
        tol = max(5.0 * self.bin_width, 10e-6)  # cut-load deflection moves the table a few um
        bad = (table_position < lo - tol) | (table_position > hi + tol)
        if bad.any():
            first = int(np.argmax(bad))
            raise CoverageError(
                f"idle runs cover table positions {lo * 1e3:.4f} to {hi * 1e3:.4f} mm, but '{name}' "
                f"reaches {table_position[first] * 1e3:.4f} mm at sample {first} "
                f"({int(bad.sum())} samples outside): run the idle trajectory over the cut's positions")


def uncompensated_estimate(estimator: "BallScrewEstimator", recording: Recording) -> np.ndarray:
    """The estimator's kernel output with no compensation, lined up with the table position [N].

    The kernel's output is shifted back by the discretisation's own delay
    (latency minus the encoder dead time ``T_b``, which the table position
    carries too) and filtered backwards with the estimator's low-pass, which
    removes the forward pass's phase lag (zero phase overall).

    Parameters
    ----------
    estimator : BallScrewEstimator
        The method (its design and signal settings; its compensation is ignored).
    recording : Recording
        An idle run with the estimator's input channels.

    Returns
    -------
    ndarray
        Same length as the recording; the last samples repeat the last aligned value.
    """
    fs = recording.fs
    design = estimator.design(fs)
    names = estimator.channel_names
    state = KernelState(design, FrictionTable.zero())
    out = run_kernel(state, *(recording[c] for c in names))
    sos = lowpass_sos(estimator.signal, fs)
    back = sps.sosfilt(sos, out[::-1], zi=sps.sosfilt_zi(sos) * out[-1])[0][::-1]
    shift = int(round((design.latency_s - estimator.signal.T_b) * fs))
    if shift > 0:
        back = np.concatenate([back[shift:], np.full(shift, back[-1])])
    return back


def build_friction_map(estimator: "BallScrewEstimator", idle_runs: Sequence[Recording], *,
                       bin_width: float = 1e-6, min_samples_per_bin: int = 3) -> FrictionMap:
    """Average the uncompensated estimate of idle runs over table-position bins.

    Parameters
    ----------
    estimator : BallScrewEstimator
        The estimator whose friction is mapped (its kernel and signal settings).
    idle_runs : sequence of Recording
        Air-cut runs over the cutting trajectory.
    bin_width : float
        Requested bin spacing [m]; widened if a run would put fewer than
        ``min_samples_per_bin`` samples in a bin at its median speed.
    min_samples_per_bin : int
        See ``bin_width``.

    Returns
    -------
    FrictionMap
    """
    runs = list(idle_runs)
    if not runs:
        raise CoverageError("no idle runs given: a friction map needs at least one")
    raws, positions, speeds = [], [], []
    for rec in runs:
        if not isinstance(rec, Recording):
            raise InvalidSignalError(f"idle runs must be Recordings, got {type(rec).__name__}")
        rec.require(*estimator.channel_names)
        estimator.check_length(rec)
        raw = uncompensated_estimate(estimator, rec)
        x_t = rec[f"{estimator.axis_name}_table_position"]
        skip = int(estimator.settle_time(rec.fs) * rec.fs)   # the kernel's start-up
        raws.append(raw[skip:])
        positions.append(x_t[skip:])
        speeds.append(np.median(np.abs(np.diff(x_t))) * rec.fs)
    fastest = max(speeds)
    width = max(bin_width, min_samples_per_bin * fastest / runs[0].fs)
    lo = min(p.min() for p in positions)
    hi = max(p.max() for p in positions)
    n_bins = max(int(np.floor((hi - lo) / width)) + 1, 1)
    centres = lo + width * np.arange(n_bins)
    per_run = np.full((len(runs), n_bins), np.nan)
    for k, (raw, pos) in enumerate(zip(raws, positions)):
        idx = np.clip(np.round((pos - lo) / width).astype(np.int64), 0, n_bins - 1)
        sums = np.bincount(idx, weights=raw, minlength=n_bins)
        counts = np.bincount(idx, minlength=n_bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            per_run[k] = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # bins no run reached: NaN, filled below
        mean = np.nanmean(per_run, axis=0)
        spread = np.nanstd(per_run, axis=0, ddof=1) if len(runs) > 1 else np.full(n_bins, np.nan)
    good = np.isfinite(mean)
    if not good.any():
        raise InvalidSignalError("idle runs gave no usable samples for the friction map")
    mean = np.interp(centres, centres[good], mean[good])
    direction = int(np.sign(np.median([np.median(np.diff(p)) for p in positions])))
    return FrictionMap(centres, mean, spread, per_run, direction, estimator.name)
