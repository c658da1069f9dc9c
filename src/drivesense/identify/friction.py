"""Friction maps from idling runs (first paper, Sec. 4).

Friction of a ball-screw stage is position dependent but highly repeatable.
Running the cutting trajectory without cutting ("idling", 3 times in the
paper) and reading what the uncompensated estimator reports gives the friction
in that estimator's modal space as a function of table position; averaging the
runs and subtracting the map during the cut removes it.  The spread between
runs is the map's repeatability.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import signal as sps

from drivesense.errors import CoverageError, InvalidSignalError
from drivesense.estimate.design import lowpass_sos
from drivesense.estimate.kernel import FrictionTable
from drivesense.recording import Recording

__all__ = ["FrictionMap", "build_friction_map", "aligned_thrust"]


def aligned_thrust(estimator, recording: Recording) -> np.ndarray:
    """Motor thrust ``K_t I / R`` [N] through the current-loop model, delayed by ``T_comp``.

    The result lines up with the encoder samples of the same index, like the
    thrust path inside the compiled estimator.
    """
    axis, sig, fs = estimator.axis, estimator.signal, recording.fs
    current = recording[f"{estimator.axis_name}_current_ref"]
    if sig.omega_cc > 0:
        a = np.exp(-sig.omega_cc / fs)
        current = sps.lfilter([0.0, 1.0 - a], [1.0, -a], current, zi=sps.lfilter_zi([0.0, 1.0 - a], [1.0, -a]) * current[0])[0]
    n = current.size
    idx = np.arange(n) - sig.T_comp * fs
    delayed = np.interp(idx, np.arange(n), current)
    return axis.K_t / axis.R * delayed


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


def build_friction_map(estimator, idle_runs: Sequence[Recording], *, bin_width: float = 1e-6,
                       min_samples_per_bin: int = 3) -> FrictionMap:
    """Average the uncompensated estimate of idle runs over table-position bins.

    Parameters
    ----------
    estimator : LinearForceEstimator
        The estimator whose friction is mapped (its combination and signal settings).
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
    comb = estimator.map_combination()
    ax = estimator.axis
    name = estimator.axis_name
    raws, positions, speeds = [], [], []
    for k, rec in enumerate(runs):
        estimator.check_length(rec)
        rec.require(*estimator.channel_names)
        thrust = aligned_thrust(estimator, rec)
        x_m = ax.R * rec[f"{name}_motor_angle"]
        x_t = rec[f"{name}_table_position"]
        raw = comb.raw(ax, thrust, x_m, x_t, rec.fs)
        raw = sps.sosfiltfilt(lowpass_sos(estimator.signal, rec.fs), raw)
        skip = int(estimator.settle_time(rec.fs) * rec.fs)
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
    with np.errstate(invalid="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(per_run, axis=0)
            spread = np.nanstd(per_run, axis=0, ddof=1) if len(runs) > 1 else np.full(n_bins, np.nan)
    good = np.isfinite(mean)
    if not good.any():
        raise InvalidSignalError("idle runs gave no usable samples for the friction map")
    mean = np.interp(centres, centres[good], mean[good])
    direction = int(np.sign(np.median([np.median(np.diff(p)) for p in positions])))
    return FrictionMap(centres, mean, spread, per_run, direction, estimator.name)
