"""Tool runout from the once-per-revolution component of a vibration or force signal (second paper, Sec. 1.4).

A radially offset tool makes one flute cut a thicker chip than the next, so force and vibration
carry a component at the spindle frequency (order 1) beside the tooth-passing orders. It is
extracted by order tracking: the spindle angle ``theta(t)`` is integrated from the spindle speed
(or taken from an encoder), and ``y = c + sum_k (a_k cos k theta + b_k sin k theta)`` is fitted
by least squares over the orders 1..``orders`` (so the tooth-passing harmonics cannot leak into
order 1, even at a varying speed). The once-per-revolution amplitude is ``hypot(a_1, b_1)`` and its
phase ``atan2(b_1, a_1)``: ``y_1 = A cos(theta - phase)``, measured from ``theta = 0`` (the spindle
index when ``spindle_angle`` comes from an encoder, else the first sample).

In micrometres: an acceleration amplitude divides by ``omega^2`` (harmonic motion at the spindle
frequency); a force amplitude divides by a stiffness [N/m] the caller gives; a displacement is one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError, SignalTooShortError

__all__ = ["RunoutEstimate", "estimate_runout"]

_KINDS = ("acceleration", "force", "displacement")


@dataclass(frozen=True)
class RunoutEstimate:
    """Once-per-revolution component of a signal.

    Attributes
    ----------
    amplitude : float
        Amplitude A of order 1 [signal unit: m/s^2, N or m].
    phase : float
        Phase [rad]: the component is ``A cos(theta - phase)``.
    amplitude_se : float
        Standard error of A from the fit residual [signal unit].
    frequency : float
        Mean spindle frequency [Hz].
    revolutions : float
        Revolutions in the analysed signal [-].
    displacement : float or None
        Runout amplitude [m] (None for a force signal without a stiffness).
    harmonics : ndarray
        Amplitudes of orders 1..K [signal unit].
    kind : str
        ``acceleration``, ``force`` or ``displacement``.
    """

    amplitude: float
    phase: float
    amplitude_se: float
    frequency: float
    revolutions: float
    displacement: float | None
    harmonics: np.ndarray
    kind: str

    def to_dict(self) -> dict:
        """JSON-ready summary (displacement also in micrometres, phase also in degrees).

        Returns
        -------
        dict
        """
        return {"amplitude": self.amplitude, "amplitude_se": self.amplitude_se, "phase_rad": self.phase,
                "phase_deg": math.degrees(self.phase), "frequency_hz": self.frequency,
                "revolutions": self.revolutions, "kind": self.kind, "displacement_m": self.displacement,
                "displacement_um": None if self.displacement is None else self.displacement * 1e6,
                "harmonics": [float(h) for h in self.harmonics]}


def _array(values, name: str) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"'{name}' must be numeric: {exc}") from None
    if not np.all(np.isfinite(arr)):
        raise InvalidSignalError(f"'{name}' holds non-finite values (NaN or inf)")
    return arr


def estimate_runout(signal, fs: float | None = None, spindle_speed=None, *, channel: str | None = None,
                    kind: str | None = None, stiffness: float | None = None, spindle_angle=None,
                    orders: int = 8) -> RunoutEstimate:
    """Once-per-revolution amplitude and phase of a vibration or force signal.

    Parameters
    ----------
    signal : array_like or Recording
        Samples (acceleration [m/s^2], force [N] or displacement [m]), or a Recording holding them.
    fs : float, optional
        Sampling rate [Hz] (taken from the Recording when one is given).
    spindle_speed : float or array_like, optional
        Spindle speed omega [rad/s], constant or one value per sample (a Recording's
        ``spindle_speed`` channel when omitted).
    channel : str, optional
        Channel of a Recording to analyse (default the only ``force_*`` or acceleration channel).
    kind : {"acceleration", "force", "displacement"}, optional
        What the signal measures; taken from the channel's unit when omitted.
    stiffness : float, optional
        Stiffness [N/m] turning a force amplitude into a displacement.
    spindle_angle : array_like, optional
        Spindle angle [rad] per sample from an encoder; the phase is then relative to its zero.
    orders : int
        Highest spindle order fitted (>= 1; include the tooth-passing orders).

    Returns
    -------
    RunoutEstimate

    Raises
    ------
    ConfigError
        Bad kind, stiffness, fs or orders; no spindle speed.
    InvalidSignalError, SignalTooShortError
        Non-finite data, mismatched lengths, less than two revolutions.
    """
    from drivesense.recording import Recording

    if isinstance(signal, Recording):
        rec = signal
        fs = rec.fs
        if channel is None:
            cands = [c for c in rec.channels if c.startswith("force_") or rec.units(c) == "m/s^2"]
            if len(cands) != 1:
                raise ConfigError(f"give 'channel' (candidates: {', '.join(cands) or 'none'})")
            channel = cands[0]
        rec.require(channel)
        if kind is None:
            kind = {"m/s^2": "acceleration", "N": "force", "m": "displacement"}.get(rec.units(channel))
        if spindle_speed is None and spindle_angle is None:
            rec.require("spindle_speed")
            spindle_speed = rec["spindle_speed"]
        signal = rec[channel]
    y = _array(signal, "signal")
    if y.ndim != 1:
        raise InvalidSignalError(f"'signal' must be 1-D, got shape {y.shape}")
    if kind not in _KINDS:
        raise ConfigError(f"'kind' must be one of {', '.join(_KINDS)}, got {kind!r}")
    if fs is None or not (isinstance(fs, (int, float)) and math.isfinite(fs) and fs > 0):
        raise ConfigError(f"'fs' must be a sampling rate > 0 Hz, got {fs!r}")
    if isinstance(orders, bool) or not isinstance(orders, int) or orders < 1:
        raise ConfigError(f"'orders' must be an integer >= 1, got {orders!r}")
    if stiffness is not None and not (math.isfinite(stiffness) and stiffness > 0):
        raise ConfigError(f"'stiffness' must be > 0 N/m, got {stiffness!r}")
    n = y.size
    if spindle_angle is not None:
        theta = _array(spindle_angle, "spindle_angle")
        if theta.shape != y.shape:
            raise InvalidSignalError(f"'spindle_angle' has {theta.size} samples, 'signal' {n}")
        omega = np.gradient(theta) * fs if n > 1 else np.zeros(1)
    elif spindle_speed is not None:
        omega = np.broadcast_to(_array(spindle_speed, "spindle_speed"), (n,)) if np.ndim(spindle_speed) == 0 \
            else _array(spindle_speed, "spindle_speed")
        if omega.shape != y.shape:
            raise InvalidSignalError(f"'spindle_speed' has {omega.size} samples, 'signal' {n}")
        if np.any(omega <= 0):
            raise InvalidSignalError("'spindle_speed' must be > 0 rad/s throughout")
        theta = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / fs)])
    else:
        raise ConfigError("give 'spindle_speed' [rad/s] or 'spindle_angle' [rad]")
    revs = float((theta[-1] - theta[0]) / (2 * math.pi))
    if revs < 2.0:
        raise SignalTooShortError(f"the signal covers {revs:.2f} spindle revolutions; at least 2 are needed")
    k = np.arange(1, orders + 1)
    X = np.column_stack([np.ones(n), np.cos(np.outer(theta, k)), np.sin(np.outer(theta, k))])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    a, b = coef[1:orders + 1], coef[orders + 1:]
    amps = np.hypot(a, b)
    s2 = float(resid @ resid) / max(n - X.shape[1], 1)
    inv = np.linalg.pinv(X.T @ X)
    var_a, var_b = inv[1, 1] * s2, inv[orders + 1, orders + 1] * s2
    amp_se = math.sqrt(0.5 * (var_a + var_b))
    w_mean = float(np.mean(omega))
    if kind == "acceleration":
        disp = float(amps[0]) / w_mean ** 2
    elif kind == "displacement":
        disp = float(amps[0])
    else:
        disp = None if stiffness is None else float(amps[0]) / stiffness
    phase = float(math.atan2(b[0], a[0]))
    return RunoutEstimate(float(amps[0]), phase, amp_se, w_mean / (2 * math.pi), revs, disp, amps, kind)
