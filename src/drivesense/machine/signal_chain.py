"""The drive's signal chain as the ball-screw estimators see it (first paper, Sec. 2.3): dead times,
current-loop model and the estimators' low-pass.  Read from AXIS.toml by :mod:`drivesense.io.axis_file`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from drivesense.errors import ConfigError
from drivesense.machine.validation import dataclass_from_dict

__all__ = ["SignalParams"]


@dataclass(frozen=True)
class SignalParams:
    """Phase-lag compensation and filtering of an estimator.

    Parameters
    ----------
    T_a : float
        Driver dead time [s] (current reference to current loop).
    T_b : float
        Encoder-side dead time [s] (transmission and differentiation delay of
        the encoder signals): the estimate's irreducible latency.
    T_comp : float
        Delay applied to the current reference so that it lines up with the
        encoder signals [s]; normally ``T_a + T_b`` (Fig. 4).
    omega_cc : float
        Current-loop bandwidth of the model ``H(s) = omega_cc / (s + omega_cc)``
        [rad/s]; 0 disables the model.
    lpf_hz : float
        Cut-off of the Butterworth low-pass [Hz].
    lpf_order : int
        Order of the low-pass (even, 2-8).
    encoder_signal_periods : int
        Signal periods per revolution of the motor encoder; 0: not known.  Its
        interpolation error repeats every ``lead / encoder_signal_periods`` of
        travel and, through the twice-differentiated position, shows in the
        force estimate as a line at that pitch's frequency ``|v| / pitch``,
        which an override moves through the chatter band
        (:meth:`drive_pitches`).
    """

    T_a: float = 0.2e-3
    T_b: float = 0.2e-3
    T_comp: float = 0.4e-3
    omega_cc: float = 5000.0
    lpf_hz: float = 1000.0
    lpf_order: int = 4
    encoder_signal_periods: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"signal parameter '{f.name}' must be a finite number, got {v!r}")
            if v < 0:
                raise ConfigError(f"signal parameter '{f.name}' must be >= 0, got {v!r}")
        if self.lpf_hz <= 0:
            raise ConfigError(f"signal parameter 'lpf_hz' must be > 0, got {self.lpf_hz!r}")
        if int(self.lpf_order) != self.lpf_order or not 1 <= self.lpf_order <= 8:
            raise ConfigError(f"signal parameter 'lpf_order' must be an integer 1-8, got {self.lpf_order!r}")
        if int(self.encoder_signal_periods) != self.encoder_signal_periods:
            raise ConfigError(f"signal parameter 'encoder_signal_periods' must be a whole number of periods per "
                              f"revolution (0: not known), got {self.encoder_signal_periods!r}")

    def drive_pitches(self, lead: float) -> tuple[float, ...]:
        """The travel over which the drive's measuring error repeats [m]: the encoder's signal period.

        Parameters
        ----------
        lead : float
            Screw lead [m/rev].

        Returns
        -------
        tuple of float
            ``(lead / encoder_signal_periods,)``, or empty when the encoder is not known.
        """
        return (lead / self.encoder_signal_periods,) if self.encoder_signal_periods > 0 and lead > 0 else ()

    def check_rate(self, fs: float) -> None:
        """Raise :class:`ConfigError` if the low-pass cut-off is not below Nyquist at ``fs`` [Hz].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        if self.lpf_hz >= 0.5 * fs:
            raise ConfigError(f"signal parameter 'lpf_hz' = {self.lpf_hz} Hz is not below the Nyquist "
                              f"frequency {0.5 * fs:g} Hz of a {fs:g} Hz trace")

    def to_dict(self) -> dict[str, float]:
        """Parameters as a plain dict (SI)."""
        return {k: (int(v) if k in ("lpf_order", "encoder_signal_periods") else float(v)) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict, *, source: str = "signal parameters") -> "SignalParams":
        """Build from a mapping; absent keys take the defaults, unknown keys are an error.

        Parameters
        ----------
        values : dict
            Parameter name -> value [SI unit of the parameter].
        source : str, optional
            Where the values come from (a file name), to start error messages.

        Returns
        -------
        SignalParams
        """
        return dataclass_from_dict(cls, values, source, optional=None)
