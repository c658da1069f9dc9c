"""Measurement models of the rotary encoder and the linear scale.

The rotary encoder of the first paper has 2^23 counts/rev made of 512 signal
periods/rev interpolated 16 384 times; interpolation leaves a periodic error at
the signal period and its harmonics.  The linear scale has a 4 um signal
period interpolated to 244 pm.  Both add white noise before quantisation.

:func:`quantise` is the one quantiser of every simulated sensor (these two,
and the scale and current measurement of the linear-motor machine in
:mod:`drivesense.sim.linear_machine`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["RotaryEncoder", "LinearScale", "EncoderParams", "ScaleParams", "quantise"]


@njit(cache=True)
def quantise(value: float, step: float) -> float:
    """Round ``value`` to the nearest multiple of ``step`` (halves round up).

    Parameters
    ----------
    value : float
        Reading before quantisation (any unit).
    step : float
        Quantisation step in the unit of ``value``; ``<= 0``: none.

    Returns
    -------
    float
        ``floor(value / step + 0.5) * step``, or ``value`` unchanged.
    """
    if step > 0.0:
        return math.floor(value / step + 0.5) * step
    return value


class EncoderParams(NamedTuple):
    """Rotary encoder model for compiled code (see :meth:`RotaryEncoder.params`).

    Attributes
    ----------
    resolution : float
        Angle per count [rad] (0: no quantisation).
    signal_periods : float
        Signal periods per revolution [-].
    noise : float
        White noise before quantisation, 1 sigma [rad].
    interpolation_error : ndarray
        Amplitudes [rad] of the interpolation error at 1x, 2x ... the signal period.
    """

    resolution: float
    signal_periods: float
    noise: float
    interpolation_error: np.ndarray


class ScaleParams(NamedTuple):
    """Linear scale model for compiled code (see :meth:`LinearScale.params`).

    Attributes
    ----------
    resolution : float
        Quantisation step [m] (0: none).
    noise : float
        White noise before quantisation, 1 sigma [m].
    """

    resolution: float
    noise: float


@dataclass(frozen=True)
class RotaryEncoder:
    """Motor encoder model.

    Parameters
    ----------
    counts_per_rev : int
        Resolution [counts/rev].
    signal_periods : int
        Signal periods per revolution (interpolation-error fundamental).
    interpolation_error : tuple of float
        Amplitudes [rad] of the interpolation error at 1x, 2x ... the signal period.
    noise_rad : float
        White noise before quantisation, 1 sigma [rad].
    """

    counts_per_rev: int = 2**23
    signal_periods: int = 512
    interpolation_error: tuple[float, ...] = (1.9e-5, 0.6e-5)
    noise_rad: float = 4.0e-7

    @property
    def resolution(self) -> float:
        """Angle per count [rad]."""
        return 2.0 * math.pi / self.counts_per_rev

    def ideal(self) -> "RotaryEncoder":
        """Perfect encoder: no quantisation, interpolation error or noise."""
        return RotaryEncoder(counts_per_rev=0, signal_periods=self.signal_periods,
                             interpolation_error=(), noise_rad=0.0)

    def params(self) -> EncoderParams:
        """The model as the named tuple the compiled simulator reads.

        Returns
        -------
        EncoderParams
        """
        res = self.resolution if self.counts_per_rev > 0 else 0.0
        return EncoderParams(float(res), float(self.signal_periods), float(self.noise_rad),
                             np.array(self.interpolation_error, dtype=np.float64))


@dataclass(frozen=True)
class LinearScale:
    """Linear scale model.

    Parameters
    ----------
    resolution : float
        Quantisation step [m] (0: none).
    noise_m : float
        White noise before quantisation, 1 sigma [m].
    """

    resolution: float = 244e-12
    noise_m: float = 0.5e-9

    def ideal(self) -> "LinearScale":
        """Perfect scale."""
        return LinearScale(resolution=0.0, noise_m=0.0)

    def params(self) -> ScaleParams:
        """The model as the named tuple the compiled simulator reads.

        Returns
        -------
        ScaleParams
        """
        return ScaleParams(float(self.resolution), float(self.noise_m))
