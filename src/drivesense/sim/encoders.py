"""Measurement models of the rotary encoder and the linear scale.

The rotary encoder of the first paper has 2^23 counts/rev made of 512 signal
periods/rev interpolated 16 384 times; interpolation leaves a periodic error at
the signal period and its harmonics.  The linear scale has a 4 um signal
period interpolated to 244 pm.  Both add white noise before quantisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["RotaryEncoder", "LinearScale"]


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

    def pack(self) -> np.ndarray:
        """``[resolution or 0, periods, noise, n, amps...]`` for compiled code."""
        res = self.resolution if self.counts_per_rev > 0 else 0.0
        return np.asarray([res, float(self.signal_periods), self.noise_rad,
                           float(len(self.interpolation_error)), *self.interpolation_error], dtype=np.float64)


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

    def pack(self) -> np.ndarray:
        """``[resolution, noise]`` for compiled code."""
        return np.asarray([self.resolution, self.noise_m], dtype=np.float64)
