"""Inputs, targets and their scaling for the learned force reconstruction (third paper, Sec. 2.3).

Inputs are the controller's NC data: positions, velocities, accelerations and
motor currents of X, Y, Z, spindle speed and spindle current.  Each is scaled
linearly to ``[-1, 1]`` from its training range, or to ``[0, 1]`` when it is
strictly positive in the training data.  The range ignores implausible
samples (a logger's corrupt value, e.g. a spindle speed of -3.3e6 rpm): a
sample further from the bulk of its column (0.5-99.5 % quantiles, at least two
samples trimmed at each end) than ten times the bulk's width is flagged with
a warning naming the channel and the count, left out of the range and clipped
to the plausible limits wherever the scaler is applied.  A column that does
not vary in the training data (one spindle speed in every training cut: its
plausible samples span less than 1 % of their magnitude) tells the networks
nothing: it is scaled to zero wherever the scaler is applied, so
no weight can be put on it (a weight that would otherwise share the constant
output with the bias, and turn a held-out trace's other spindle speed into an
offset of hundreds of newtons).  Targets (the
reference force) are low-passed zero-phase (Butterworth) at the paper's
120 Hz, or at 0.48 times the trace's rate where that is lower
(:func:`target_cutoff_hz`: a trace at 50 Hz is filtered at 24 Hz), and scaled
by Eq. 17, ``F* = F / (2 |F_max|) + 0.5``.  The scalers are plain numbers
saved as JSON beside the model.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import signal as sps

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.recording import Recording

__all__ = ["INPUT_CHANNELS", "TARGET_CHANNELS", "TARGET_CUTOFF_HZ", "Scaler", "TargetScaler", "InputRangeWarning",
           "plausible_range", "input_matrix", "filtered_target", "target_cutoff_hz", "position_features",
           "presliding_features", "resample_to", "resample_onto"]

#: NC channels the networks read, in order.
INPUT_CHANNELS = tuple(f"{ax}_{q}" for q in ("position", "velocity", "acceleration", "current")
                       for ax in "xyz") + ("spindle_speed", "spindle_current")
#: Force channels the networks reconstruct (one network each).
TARGET_CHANNELS = ("force_x", "force_y", "force_z")
#: The paper's target filter [Hz] (its dynamometer chain), used where the trace's rate allows it.
TARGET_CUTOFF_HZ = 120.0
#: Share of a column's samples trimmed at each end for its bulk (at least two samples).
_BULK_QUANTILE = 0.005
#: A sample further from the bulk than this many bulk widths is implausible.
_PLAUSIBLE_WIDTHS = 10.0
#: The bulk's width is taken as at least this share of its largest magnitude (near-constant columns).
_WIDTH_FLOOR = 0.1
#: A column whose plausible training samples span less than this share of their largest magnitude is constant:
#: a spindle speed held at one value with 0.1 % ripple, a Z axis parked within a millimetre at 0.15 m.
_CONSTANT_SPAN = 0.01


class InputRangeWarning(UserWarning):
    """Input samples outside the plausible range of their channel (flagged in fitting, clipped in use)."""


def plausible_range(x: np.ndarray) -> tuple[float, float]:
    """Limits of the plausible values of one input column, from robust statistics.

    The bulk is the 0.5-99.5 % quantile range (at least the two most extreme
    samples at each end trimmed, so a single corrupt sample cannot move it);
    its width is taken as at least 10 % of its largest magnitude (a nearly
    constant column such as a spindle speed).  Plausible is the bulk widened by
    ten widths on each side: legitimate excursions (ramps, rapid moves, a
    spindle stop) stay inside, a logger's corrupt value does not.

    Parameters
    ----------
    x : ndarray
        Samples of one column [SI unit of the column].

    Returns
    -------
    low, high : float
        Plausible limits [SI unit of the column]; ``(-inf, inf)`` for a
        constant column or fewer than five samples (nothing to judge by).
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    k = max(2, int(np.ceil(_BULK_QUANTILE * n)))
    if n < 2 * k + 1:
        return -np.inf, np.inf
    part = np.partition(x, (k, n - 1 - k))
    lo, hi = float(part[k]), float(part[n - 1 - k])
    width = max(hi - lo, _WIDTH_FLOOR * max(abs(lo), abs(hi)))
    if not width > 0:
        return -np.inf, np.inf
    return lo - _PLAUSIBLE_WIDTHS * width, hi + _PLAUSIBLE_WIDTHS * width


@dataclass
class Scaler:
    """Linear scaling of each input column to ``[-1, 1]`` (or ``[0, 1]`` if strictly positive).

    Attributes
    ----------
    low, high : ndarray
        Training minimum and maximum of each column's plausible samples [SI unit of the column].
    positive : ndarray of bool
        Columns scaled to ``[0, 1]``.
    clip_low, clip_high : ndarray, optional
        Plausible limits of each column [SI unit of the column]
        (:func:`plausible_range`); inputs are clipped to them before scaling.
        None: no clipping (models saved before the limits existed).
    constant : ndarray of bool, optional
        Columns that did not vary in the training data, scaled to zero
        whatever their value.  None: none (models saved before this existed).
    """

    low: np.ndarray
    high: np.ndarray
    positive: np.ndarray
    clip_low: np.ndarray | None = field(default=None)
    clip_high: np.ndarray | None = field(default=None)
    constant: np.ndarray | None = field(default=None)

    @classmethod
    def fit(cls, matrices, names=None) -> "Scaler":
        """Ranges from a list of ``(n_samples, n_inputs)`` training matrices, ignoring implausible samples.

        A sample outside its column's :func:`plausible_range` (over all
        matrices) is left out of the range; an :class:`InputRangeWarning`
        names each such column and its count.  A column whose plausible
        samples do not vary is marked constant (scaled to zero).

        Parameters
        ----------
        matrices : iterable of ndarray
            Training input matrices [SI unit of each column], e.g. from
            :func:`input_matrix`.
        names : sequence of str, optional
            Column names for the warning (default :data:`INPUT_CHANNELS` when
            the widths match, else ``column k``).

        Returns
        -------
        Scaler
        """
        stacked = np.vstack(list(matrices))
        n_cols = stacked.shape[1]
        if names is None:
            names = INPUT_CHANNELS if n_cols == len(INPUT_CHANNELS) else [f"column {k}" for k in range(n_cols)]
        clip_low, clip_high = np.full(n_cols, -np.inf), np.full(n_cols, np.inf)
        low, high = np.empty(n_cols), np.empty(n_cols)
        flagged = []
        for j in range(n_cols):
            col = stacked[:, j]
            clip_low[j], clip_high[j] = plausible_range(col)
            bad = (col < clip_low[j]) | (col > clip_high[j])
            count = int(np.count_nonzero(bad))
            if count:
                col = col[~bad]
                worst = float(stacked[bad, j][np.argmax(np.abs(stacked[bad, j]))])
                flagged.append(f"'{names[j]}': {count} sample(s) (e.g. {worst:.4g}) outside "
                               f"[{clip_low[j]:.4g}, {clip_high[j]:.4g}]")
            low[j], high[j] = col.min(), col.max()
        if flagged:
            warnings.warn("training inputs hold implausible samples, left out of the scaling and clipped: "
                          + "; ".join(flagged), InputRangeWarning, stacklevel=2)
        constant = (high - low) <= _CONSTANT_SPAN * np.maximum(np.abs(low), np.abs(high))
        positive = (low > 0) & ~constant
        low = np.where(positive, 0.0, low)
        high = np.where(constant, low + 1.0, high)
        return cls(low, high, positive, clip_low, clip_high, constant)

    def outside(self, x: np.ndarray) -> np.ndarray:
        """Samples per column outside the plausible limits (those :meth:`transform` clips).

        Parameters
        ----------
        x : ndarray, shape (n_samples, n_inputs)
            Inputs [SI unit of each column].

        Returns
        -------
        ndarray of int, shape (n_inputs,)
        """
        x = np.asarray(x, float)
        if self.clip_low is None:
            return np.zeros(x.shape[1], dtype=np.int64)
        return np.count_nonzero((x < self.clip_low) | (x > self.clip_high), axis=0)

    def transform(self, x: np.ndarray) -> np.ndarray:
        """Scaled copy of ``x`` (float32), clipped to the plausible limits first.

        Parameters
        ----------
        x : ndarray, shape (n_samples, n_inputs)
            Inputs [SI unit of each column].

        Returns
        -------
        ndarray
            Scaled inputs [-].
        """
        x = np.asarray(x, float)
        if self.clip_low is not None:
            x = np.clip(x, self.clip_low, self.clip_high)
        u = (x - self.low) / (self.high - self.low)
        u = np.where(self.positive, u, 2.0 * u - 1.0)
        if self.constant is not None:
            u = np.where(self.constant, 0.0, u)
        return u.astype(np.float32)

    def to_dict(self) -> dict:
        """JSON-ready form (infinite limits as None)."""
        d = {"low": self.low.tolist(), "high": self.high.tolist(), "positive": self.positive.tolist()}
        if self.clip_low is not None:
            d["clip_low"] = [None if not np.isfinite(v) else float(v) for v in self.clip_low]
            d["clip_high"] = [None if not np.isfinite(v) else float(v) for v in self.clip_high]
        if self.constant is not None:
            d["constant"] = self.constant.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Scaler":
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            ``{"low", "high", "positive"}`` lists, ``{"clip_low", "clip_high"}``
            (None for no limit) where the model has plausible limits, and
            ``"constant"`` where it marks constant columns.

        Returns
        -------
        Scaler
        """
        try:
            clip = [None, None]
            if "clip_low" in d:
                clip = [np.array([sign * np.inf if v is None else v for v in d[key]], float)
                        for key, sign in (("clip_low", -1.0), ("clip_high", 1.0))]
            constant = np.asarray(d["constant"], bool) if "constant" in d else None
            return cls(np.asarray(d["low"], float), np.asarray(d["high"], float), np.asarray(d["positive"], bool),
                       *clip, constant)
        except KeyError as exc:
            raise ConfigError(f"input scaler lacks {exc.args[0]!r}") from None


@dataclass
class TargetScaler:
    """Eq. 17 for one force component: ``F* = F / (2 |F_max|) + 0.5``.

    Attributes
    ----------
    f_max : float
        Largest absolute (filtered) training force [N].
    """

    f_max: float

    def transform(self, f: np.ndarray) -> np.ndarray:
        """Scaled force (float32).

        Parameters
        ----------
        f : ndarray
            Force [N].

        Returns
        -------
        ndarray
            ``F*`` [-].
        """
        return (np.asarray(f, float) / (2.0 * self.f_max) + 0.5).astype(np.float32)

    def inverse(self, f_star: np.ndarray) -> np.ndarray:
        """Force [N] from the scaled value.

        Parameters
        ----------
        f_star : ndarray
            Scaled force ``F*`` [-].

        Returns
        -------
        ndarray
            Force [N].
        """
        return (np.asarray(f_star, float) - 0.5) * 2.0 * self.f_max


def input_matrix(recording: Recording) -> np.ndarray:
    """The ``(n_samples, 14)`` input matrix of a trace, in SI (before scaling).

    Parameters
    ----------
    recording : Recording
        A trace holding :data:`INPUT_CHANNELS`.

    Returns
    -------
    ndarray, shape (n_samples, 14)
    """
    recording.require(*INPUT_CHANNELS)
    return np.column_stack([recording[c] for c in INPUT_CHANNELS])


def position_features(positions, pole_pitch: float, harmonics: int) -> np.ndarray:
    """Sine and cosine of harmonics 1..``harmonics`` of the pole pitch for each axis position (float32).

    Cogging repeats with the motors' pole pitch (a catalogue value): a small
    LSTM cannot make a periodic function of a position scaled to [-1, 1], but
    it can weigh these columns.  They are already in [-1, 1] and not scaled.
    The harmonics follow from the first by the angle-addition formulas: one
    sine and cosine per axis instead of one per harmonic (2.3x faster; in
    float32 the same values but for a last-bit rounding in one of millions).

    Parameters
    ----------
    positions : sequence of array_like
        Axis positions [m] (x, y, z), equally long.
    pole_pitch : float
        Pole pitch [m].
    harmonics : int
        Number of harmonics (0: no columns).

    Returns
    -------
    ndarray, shape (n_samples, 2 * harmonics * len(positions))
    """
    n = len(np.asarray(positions[0])) if len(positions) else 0
    out = np.empty((n, 2 * harmonics * len(positions)), dtype=np.float32)
    col = 0
    for s in positions:
        phase = 2.0 * np.pi * np.asarray(s, float) / pole_pitch
        sin1, cos1 = np.sin(phase), np.cos(phase)
        sin_h, cos_h = sin1, cos1
        for h in range(1, harmonics + 1):
            if h > 1:
                sin_h, cos_h = sin_h * cos1 + cos_h * sin1, cos_h * cos1 - sin_h * sin1
            out[:, col], out[:, col + 1] = sin_h, cos_h
            col += 2
    return out


def presliding_features(positions, x_pre: float, state: dict | None = None) -> np.ndarray:
    """Dahl presliding state of each axis from its position, in [-1, 1] (float32).

    At a reversal the guides' friction turns over within a few micrometres of
    travel, a sample or two at 250 Hz: the state follows the position there,
    where the sampled velocity only changes sign (see
    :func:`drivesense.machine.presliding.presliding_direction`).

    Parameters
    ----------
    positions : sequence of array_like
        Axis positions [m] (x, y, z), equally long.
    x_pre : float
        Presliding distance [m] (> 0).
    state : dict, optional
        ``{axis index: (last position [m], state [-])}`` carried between
        stream chunks, updated in place; None: a fresh start.

    Returns
    -------
    ndarray, shape (n_samples, len(positions))
    """
    from drivesense.machine.presliding import carried_presliding_direction

    return np.column_stack([carried_presliding_direction(s, x_pre, state, i)
                            for i, s in enumerate(positions)]).astype(np.float32)


def target_cutoff_hz(fs: float) -> float:
    """Cut-off of the target filter at sample rate ``fs`` [Hz]: the paper's 120 Hz, below 0.48 ``fs``.

    At the paper's 250 Hz this is 120 Hz (0.96 of the Nyquist frequency); a
    trace at 50 Hz is filtered at 24 Hz.  Below 120 Hz the filter only keeps
    the target band-limited like the inputs: the reference of a slow trace is
    already anti-aliased by its own chain.

    Parameters
    ----------
    fs : float
        Sample rate of the trace [Hz].

    Returns
    -------
    float
        Cut-off [Hz].
    """
    return min(TARGET_CUTOFF_HZ, 0.48 * float(fs))


def filtered_target(recording: Recording, channel: str, *, cutoff_hz: float | None = None, order: int = 4,
                    aligned: bool = True) -> np.ndarray:
    """Reference force low-passed zero-phase (Butterworth) at ``cutoff_hz`` [Hz], in N.

    With ``aligned`` the force is delayed by the trace's declared NC delay
    (``meta["nc_delay_s"]``, e.g. a logger's anti-alias filter), so that it lines
    up with the NC inputs: a causal network cannot undo that delay, and the
    learned estimators declare it as their latency.

    Parameters
    ----------
    recording : Recording
        Trace holding the reference force.
    channel : str
        Force channel (``force_x``...).
    cutoff_hz : float, optional
        Cut-off [Hz], below the trace's Nyquist frequency; default
        :func:`target_cutoff_hz` of the trace's rate (120 Hz at 250 Hz).
    order : int, optional
        Butterworth order (applied forwards and backwards).
    aligned : bool, optional
        Delay by ``meta["nc_delay_s"]`` (default True).

    Returns
    -------
    ndarray
        Filtered force [N].
    """
    recording.require(channel)
    f = recording[channel]
    nyq = 0.5 * recording.fs
    if cutoff_hz is None:
        cutoff_hz = target_cutoff_hz(recording.fs)
    if cutoff_hz >= nyq:
        raise ConfigError(f"target filter {cutoff_hz} Hz is not below the Nyquist frequency {nyq:g} Hz")
    sos = sps.butter(order, cutoff_hz, fs=recording.fs, output="sos")
    if f.size <= 3 * (2 * sos.shape[0] + 1):
        raise InvalidSignalError(f"trace '{recording.meta.get('name', '')}' is too short for the target filter")
    out = sps.sosfiltfilt(sos, f)
    delay = float(recording.meta.get("nc_delay_s", 0.0)) if aligned else 0.0
    if delay > 0:
        idx = np.arange(out.size) - delay * recording.fs
        out = np.interp(idx, np.arange(out.size), out)
    return out


def resample_to(recording: Recording, fs: float) -> Recording:
    """The trace on a uniform grid at ``fs`` [Hz] (polyphase, anti-aliased); provenance says so.

    The first sample stays at the trace's start time.  Each channel is held
    at its first and last values beyond its ends (``padtype="edge"``, the
    machine at rest, as the networks are primed), so that the edges carry no
    filter transient (a position of 0.15 m does not start from zero), and is
    filtered relative to its first value with a Kaiser window of beta 8
    (scipy's default of 5 leaves a ripple of 0.1 % of a channel's level
    between the polyphase branches: 0.1 mm on a position of 0.13 m).

    Parameters
    ----------
    recording : Recording
        The trace.
    fs : float
        Target sample rate [Hz].

    Returns
    -------
    Recording
        The same object when it is already at `fs`.
    """
    if abs(recording.fs - fs) < 1e-9 * fs:
        return recording
    from fractions import Fraction

    ratio = Fraction(fs / recording.fs).limit_denominator(1000)
    channels = {}
    for c in recording.channels:
        x = recording[c]
        first = x[0] if x.size else 0.0
        channels[c] = first + sps.resample_poly(x - first, ratio.numerator, ratio.denominator, padtype="edge",
                                                window=("kaiser", 8.0))
    units = {c: recording.units(c) for c in recording.channels}
    meta = recording.meta
    meta["provenance"] = list(meta.get("provenance", [])) + [
        f"resampled {recording.fs:g} Hz -> {fs:g} Hz (polyphase {ratio.numerator}/{ratio.denominator})"]
    return Recording.from_arrays(channels, fs=fs, t0=recording.t0, units=units, meta=meta)


def resample_onto(recording: Recording, like: Recording) -> Recording:
    """``recording`` resampled onto the time base of ``like`` (its rate, start and length).

    Used to put an estimate made at a model's rate back onto the grid of the
    trace it came from; the last samples are cut or held so that the lengths
    match exactly.

    Parameters
    ----------
    recording : Recording
        The signals to move (e.g. forces at the model's rate).
    like : Recording
        The trace whose time base they must share.

    Returns
    -------
    Recording
        At ``like.fs`` from ``like.t0``, ``like.n_samples`` long.
    """
    out = resample_to(recording, like.fs)
    n = like.n_samples
    channels = {}
    for c in out.channels:
        v = out[c][:n]
        channels[c] = np.concatenate([v, np.full(n - v.size, v[-1] if v.size else 0.0)]) if v.size < n else v
    return Recording.from_arrays(channels, fs=like.fs, t0=like.t0, units={c: out.units(c) for c in out.channels},
                                 meta=out.meta)
