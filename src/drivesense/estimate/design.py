"""Discrete design of the linear force observers.

Every ball-screw estimator of the first paper is linear in the three servo
signals.  In drivesense's sign convention (``force_x`` is the process force on
the table along +x, i.e. ``-F_cut`` of the paper) an estimator reads

    force_x = LPF[ -c_I * (K_t/R) H(s) e^{-s T_comp} I_ref
                   + m_m a_m + c_m v_m + k_m x_m
                   + m_t a_t + c_t v_t + k_t x_t ]  - friction

with ``x_m = R theta_m``.  :class:`ForceCombination` holds the seven
coefficients; :func:`discretise` turns them into FIR taps per input channel
plus one common IIR section cascade, which the compiled kernel runs in a single
pass.  Two discretisations exist:

``"central"``
    Central differences (one sample of delay) followed by the Butterworth
    low-pass: the explicit numerical differentiation of the paper.
``"bilinear"``
    The disturbance-observer form: the derivatives are folded into the
    low-pass, ``s^k Q(s)``, and both are discretised with the same bilinear
    transform (pseudo-differentiation, no extra delay).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

from drivesense.machine.signal_chain import SignalParams
from drivesense.machine.ballscrew import BallScrewAxis

__all__ = ["ForceCombination", "ObserverDesign", "discretise", "lowpass_sos"]


@dataclass(frozen=True)
class ForceCombination:
    """Coefficients of one estimating equation (SI, drivesense sign convention).

    Attributes
    ----------
    c_I : float
        Weight of the motor thrust ``K_t I / R`` [-].
    m_m, c_m, k_m : float
        Weights of motor-side acceleration [kg], velocity [N*s/m], position [N/m].
    m_t, c_t, k_t : float
        Weights of table acceleration [kg], velocity [N*s/m], position [N/m].
    """

    c_I: float
    m_m: float = 0.0
    c_m: float = 0.0
    k_m: float = 0.0
    m_t: float = 0.0
    c_t: float = 0.0
    k_t: float = 0.0


@dataclass(frozen=True)
class ObserverDesign:
    """FIR taps per channel plus a common IIR cascade, ready for the kernel.

    Attributes
    ----------
    taps_current : ndarray
        Taps on the current after the current-loop model [N/A].
    taps_motor : ndarray
        Taps on the motor angle [N/rad].
    taps_table : ndarray
        Taps on the table position [N/m].
    taps_friction : ndarray
        Taps on the friction-map value [-].
    sos : ndarray, shape (n, 6)
        Common IIR cascade (second-order sections) [-].
    h_pole : float
        Pole of the discrete current-loop model, ``exp(-omega_cc / fs)`` [-] (0: no model).
    latency_s : float
        Pure delay of the estimate against the true force [s].
    """

    taps_current: np.ndarray
    taps_motor: np.ndarray
    taps_table: np.ndarray
    taps_friction: np.ndarray
    sos: np.ndarray
    h_pole: float
    latency_s: float

    @property
    def n_taps(self) -> int:
        """Length of the longest FIR."""
        return max(self.taps_current.size, self.taps_motor.size, self.taps_table.size, self.taps_friction.size)

    def padded(self) -> np.ndarray:
        """All four FIRs zero-padded to one ``(4, n_taps)`` array (current, motor, table, friction)."""
        n = self.n_taps
        out = np.zeros((4, n))
        for i, taps in enumerate((self.taps_current, self.taps_motor, self.taps_table, self.taps_friction)):
            out[i, : taps.size] = taps
        return out


def lowpass_sos(params: SignalParams, fs: float) -> np.ndarray:
    """The estimator's Butterworth low-pass as second-order sections at ``fs`` [Hz].

    Parameters
    ----------
    params : SignalParams
        Order and cut-off of the low-pass.
    fs : float
        Sample rate [Hz].

    Returns
    -------
    ndarray, shape (n, 6)
    """
    params.check_rate(fs)
    return sps.butter(int(params.lpf_order), params.lpf_hz, btype="low", fs=fs, output="sos")


def _fractional_delay(delay_samples: float) -> np.ndarray:
    """Linear-interpolation FIR for a (fractional) delay of ``delay_samples`` >= 0."""
    i = int(math.floor(delay_samples + 1e-9))
    frac = delay_samples - i
    taps = np.zeros(i + 2)
    taps[i] = 1.0 - frac
    taps[i + 1] = frac
    return np.trim_zeros(taps, "b") if frac < 1e-9 else taps


def _poly(*factors: np.ndarray) -> np.ndarray:
    out = np.array([1.0])
    for f in factors:
        out = np.convolve(out, f)
    return out


def discretise(comb: ForceCombination, axis: BallScrewAxis, params: SignalParams, fs: float,
               method: str = "central") -> ObserverDesign:
    """Build the discrete observer of ``comb`` for signals sampled at ``fs`` [Hz].

    Parameters
    ----------
    comb : ForceCombination
        Estimating equation.
    axis : BallScrewAxis
        Axis parameters (``K_t``, ``R``).
    params : SignalParams
        Dead times, current-loop model and low-pass.
    fs : float
        Sample rate [Hz].
    method : {"central", "bilinear"}
        Discretisation of the derivatives (see module docstring).

    Returns
    -------
    ObserverDesign
    """
    T = 1.0 / fs
    sos = lowpass_sos(params, fs)
    R = axis.R
    thrust_gain = -comb.c_I * axis.K_t / R
    h_pole = math.exp(-params.omega_cc * T) if params.omega_cc > 0 else 0.0
    comp = params.T_comp * fs
    if method == "central":
        center = 1  # central differences are centred one sample back
        d1 = np.array([0.5 * fs, 0.0, -0.5 * fs])
        d2 = np.array([fs * fs, -2.0 * fs * fs, fs * fs])
        d0 = np.array([0.0, 1.0, 0.0])
        taps_current = thrust_gain * _fractional_delay(comp + center)
        taps_motor = R * (comb.m_m * d2 + comb.c_m * d1 + comb.k_m * d0)
        taps_table = comb.m_t * d2 + comb.c_t * d1 + comb.k_t * d0
        taps_friction = -d0
        latency = params.T_b + center * T
        iir = sos
    elif method == "bilinear":
        # Q(z) = g (1 + z^-1)^N / A(z); s -> 2 fs (1 - z^-1)/(1 + z^-1)
        order = int(params.lpf_order)
        num = _poly(*[sec[:3] for sec in sos])
        gain = num.sum() / 2.0**order
        plus = np.array([1.0, 1.0])
        minus = np.array([1.0, -1.0])
        c = 2.0 * fs
        q0 = gain * _poly(*[plus] * order)
        q1 = gain * c * _poly(minus, *[plus] * (order - 1))
        q2 = gain * c * c * _poly(minus, minus, *[plus] * (order - 2))
        taps_current = thrust_gain * np.convolve(q0, _fractional_delay(comp))
        taps_motor = R * (comb.m_m * q2 + comb.c_m * q1 + comb.k_m * q0)
        taps_table = comb.m_t * q2 + comb.c_t * q1 + comb.k_t * q0
        taps_friction = -q0
        latency = params.T_b
        iir = sos.copy()
        iir[:, :3] = [1.0, 0.0, 0.0]
    else:
        raise ValueError(f"unknown discretisation {method!r} (use 'central' or 'bilinear')")
    return ObserverDesign(np.asarray(taps_current, float), np.asarray(taps_motor, float),
                          np.asarray(taps_table, float), np.asarray(taps_friction, float),
                          np.ascontiguousarray(iir), h_pole, latency)
