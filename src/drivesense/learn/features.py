"""Inputs, targets and their scaling for the learned force reconstruction (third paper, Sec. 2.3).

Inputs are the controller's NC data: positions, velocities, accelerations and
motor currents of X, Y, Z, spindle speed and spindle current.  Each is scaled
linearly to ``[-1, 1]`` from its training range, or to ``[0, 1]`` when it is
strictly positive in the training data.  Targets (the reference force) are
low-passed zero-phase at 120 Hz (Butterworth) and scaled by Eq. 17,
``F* = F / (2 |F_max|) + 0.5``.  The scalers are plain numbers saved as JSON
beside the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.recording import Recording

__all__ = ["INPUT_CHANNELS", "TARGET_CHANNELS", "Scaler", "TargetScaler", "input_matrix", "filtered_target",
           "position_features", "presliding_features", "resample_to"]

#: NC channels the networks read, in order.
INPUT_CHANNELS = tuple(f"{ax}_{q}" for q in ("position", "velocity", "acceleration", "current")
                       for ax in "xyz") + ("spindle_speed", "spindle_current")
#: Force channels the networks reconstruct (one network each).
TARGET_CHANNELS = ("force_x", "force_y", "force_z")


@dataclass
class Scaler:
    """Linear scaling of each input column to ``[-1, 1]`` (or ``[0, 1]`` if strictly positive).

    Attributes
    ----------
    low, high : ndarray
        Training minimum and maximum of each column [SI unit of the column].
    positive : ndarray of bool
        Columns scaled to ``[0, 1]``.
    """

    low: np.ndarray
    high: np.ndarray
    positive: np.ndarray

    @classmethod
    def fit(cls, matrices) -> "Scaler":
        """Ranges from a list of ``(n_samples, n_inputs)`` training matrices.

        Parameters
        ----------
        matrices : iterable of ndarray
            Training input matrices [SI unit of each column], e.g. from
            :func:`input_matrix`.

        Returns
        -------
        Scaler
        """
        stacked = np.vstack(list(matrices))
        low, high = stacked.min(axis=0), stacked.max(axis=0)
        positive = low > 0
        low = np.where(positive, 0.0, low)
        span = high - low
        high = np.where(span > 0, high, low + 1.0)  # constant columns map to the bottom of the range
        return cls(low, high, positive)

    def transform(self, x: np.ndarray) -> np.ndarray:
        """Scaled copy of ``x`` (float32).

        Parameters
        ----------
        x : ndarray, shape (n_samples, n_inputs)
            Inputs [SI unit of each column].

        Returns
        -------
        ndarray
            Scaled inputs [-].
        """
        u = (np.asarray(x, float) - self.low) / (self.high - self.low)
        return np.where(self.positive, u, 2.0 * u - 1.0).astype(np.float32)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {"low": self.low.tolist(), "high": self.high.tolist(), "positive": self.positive.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Scaler":
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            ``{"low", "high", "positive"}`` lists.

        Returns
        -------
        Scaler
        """
        try:
            return cls(np.asarray(d["low"], float), np.asarray(d["high"], float), np.asarray(d["positive"], bool))
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
    cols = []
    for s in positions:
        phase = 2.0 * np.pi * np.asarray(s, float) / pole_pitch
        for h in range(1, harmonics + 1):
            cols += [np.sin(h * phase), np.cos(h * phase)]
    if not cols:
        return np.zeros((len(np.asarray(positions[0])) if len(positions) else 0, 0), dtype=np.float32)
    return np.column_stack(cols).astype(np.float32)


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


def filtered_target(recording: Recording, channel: str, *, cutoff_hz: float = 120.0, order: int = 4,
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
        Cut-off [Hz] (default 120), below the trace's Nyquist frequency.
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
    channels = {c: sps.resample_poly(recording[c], ratio.numerator, ratio.denominator) for c in recording.channels}
    units = {c: recording.units(c) for c in recording.channels}
    meta = recording.meta
    meta["provenance"] = list(meta.get("provenance", [])) + [
        f"resampled {recording.fs:g} Hz -> {fs:g} Hz (polyphase {ratio.numerator}/{ratio.denominator})"]
    return Recording.from_arrays(channels, fs=fs, t0=recording.t0, units=units, meta=meta)
