"""Base of the ball-screw estimators of the first paper: one linear observer, one compiled kernel.

::

    est = ds.estimate.VibrationMode(axis, signal)
    est.fit(idle_runs)                 # friction map from air-cut runs (Sec. 4)
    est.tare(recording, 0.5, 1.5)      # or: a tare for a standing axis
    forces = est.estimate(recording)   # Recording with force_x, meta latency_s

The four methods differ only in the combination of signals
(:class:`~drivesense.estimate.design.ForceCombination`); each is discretised
into per-channel FIR taps plus one IIR cascade that
:func:`~drivesense.estimate.kernel.run_kernel` runs for batch and stream.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from drivesense.errors import CoverageError, SampleRateError, SignalTooShortError
from drivesense.estimate.base import ForceEstimator
from drivesense.estimate.design import ForceCombination, ObserverDesign, discretise
from drivesense.estimate.friction_map import build_friction_map
from drivesense.estimate.kernel import FrictionTable, KernelState, run_kernel
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.signal_chain import SignalParams
from drivesense.recording import Recording

__all__ = ["BallScrewEstimator", "INPUT_CHANNELS"]

#: Channels a ball-screw estimator reads, per axis letter.
INPUT_CHANNELS = ("current_ref", "motor_angle", "table_position")


class BallScrewEstimator(ForceEstimator):
    """A linear force observer on current reference, motor angle and table position.

    Parameters
    ----------
    axis : BallScrewAxis
        Axis parameters.
    signal : SignalParams, optional
        Phase-lag compensation and low-pass (default: the paper's values).
    axis_name : str
        Axis letter of the input and output channels.
    """

    drive = "ballscrew"
    #: Discretisation of the derivatives (``"central"`` or ``"bilinear"``).
    discretisation = "central"
    #: Whether the method's equation holds the ball screw's vibration mode (motor minus table motion): then
    #: a trace must resolve the mode, i.e. its natural frequency must lie below the Nyquist frequency.
    models_vibration_mode = False

    def __init__(self, axis: BallScrewAxis, signal: SignalParams | None = None, *, axis_name: str = "x") -> None:
        self.axis = axis
        self.signal = signal or SignalParams()
        self.axis_name = axis_name     # sets the channel names (kept: the stream's hot path reads them)
        self.friction = FrictionTable.zero()
        self.friction_map = None
        self._designs: dict[float, ObserverDesign] = {}

    # ----------------------------------------------------------------- design
    def check_rate(self, fs: float) -> None:
        """Refuse a sample rate that cannot resolve what the method models.

        A method that models the vibration mode (:attr:`models_vibration_mode`) needs the mode's natural
        frequency below the Nyquist frequency: sampled slower, the mode aliases into the band and the
        estimate is wrong, even in sign.  The low-pass cut-off must lie below Nyquist as well.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].

        Raises
        ------
        SampleRateError
            Naming the method, the mode's frequency, the rate it needs and the methods that work at `fs`.
        """
        f_mode = self.axis.natural_frequency_hz
        if self.models_vibration_mode and f_mode >= 0.5 * fs:
            raise SampleRateError(
                f"--method {self.name} models the ball screw's vibration mode at {f_mode:.0f} Hz, which a "
                f"{fs:g} Hz trace cannot resolve (Nyquist {0.5 * fs:g} Hz; it needs > {2 * f_mode:.0f} Hz): for a "
                f"controller trace at this rate identify the axes with 'drivesense identify nc' and estimate with "
                f"--method model, or use --method current or rigid")
        self.signal.check_rate(fs)

    def combination(self) -> ForceCombination:
        """The estimating equation (each method defines it)."""
        raise NotImplementedError

    def design(self, fs: float) -> ObserverDesign:
        """Discrete observer for sample rate ``fs`` [Hz] (cached).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        if fs not in self._designs:
            self.check_rate(fs)
            self._designs[fs] = discretise(self.combination(), self.axis, self.signal, fs, self.discretisation)
        return self._designs[fs]

    @property
    def axis_name(self) -> str:
        """Axis letter of the input and output channels."""
        return self._axis_name

    @axis_name.setter
    def axis_name(self, name: str) -> None:
        self._axis_name = name
        self._channels = tuple(f"{name}_{c}" for c in INPUT_CHANNELS)
        self._output = f"force_{name}"

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Input channel names for this axis (``x_current_ref``, ``x_motor_angle``, ``x_table_position``)."""
        return self._channels

    @property
    def output_channel(self) -> str:
        """Name of the output channel (``force_x``...)."""
        return self._output

    @property
    def output_channels(self) -> tuple[str, ...]:
        """The one output channel, ``(force_{ax},)``."""
        return (self.output_channel,)

    def latency_s(self, fs: float) -> float:
        """Encoder-side dead time ``T_b`` plus the discretisation's own delay at ``fs`` [Hz], in s.

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return self.design(fs).latency_s

    # ------------------------------------------------------------ compensation
    def fit(self, runs: Sequence[Recording], **kwargs) -> "BallScrewEstimator":
        """Build this method's friction map from idling (air-cut) runs (Sec. 4).

        Parameters
        ----------
        runs : sequence of Recording
            Runs over the same trajectory as the cuts, with no cutting.
        **kwargs
            Passed to :func:`drivesense.estimate.friction_map.build_friction_map`
            (e.g. ``bin_width`` [m]).

        Returns
        -------
        self
        """
        self.friction = FrictionTable.zero()
        self.friction_map = None
        fmap = build_friction_map(self, runs, **kwargs)
        self.friction_map = fmap
        self.friction = fmap.table()
        return self

    def tare(self, recording: Recording, start: float, end: float) -> float:
        """Take a constant tare from the uncompensated estimate over ``[start, end)`` [s].

        For an axis that stands (cross-feed): the static friction and offsets
        are whatever they were before the cut; their sum is removed.

        Parameters
        ----------
        recording : Recording
            Trace whose window holds no process force.
        start, end : float
            Window [s].

        Returns
        -------
        float
            The tare [N], also stored in the estimator.
        """
        self.friction = FrictionTable.zero()
        self.friction_map = None
        raw = self.estimate(recording)
        t = raw.time
        sel = (t >= start) & (t < end)
        if not sel.any():
            raise CoverageError(f"tare window {start}:{end} s lies outside the trace "
                                f"({t[0]:.4g}-{t[-1]:.4g} s)")
        settle = self.settle_time(recording.fs)
        if start < t[0] + settle:
            raise CoverageError(f"tare window starts at {start} s, inside the estimator's "
                                f"start-up ({settle:.4g} s from the trace start)")
        value = float(np.mean(raw[self.output_channel][sel]))
        self.friction = FrictionTable([value])
        return value

    def settle_time(self, fs: float) -> float:
        """Time the filters need to forget their start [s] (about 10 low-pass time constants).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return max(10.0 / self.signal.lpf_hz, 30.0 / fs)

    def compensation(self) -> str:
        """``"friction map"``, ``"tare"`` or ``"none"``."""
        if self.friction_map is not None:
            return "friction map"
        return "tare" if self.friction.values.size == 1 and self.friction.values[0] != 0 else "none"

    # ------------------------------------------------------------- estimation
    def new_state(self, fs: float) -> KernelState:
        """Filter state of the compiled kernel at ``fs`` [Hz], with the current compensation.

        Parameters
        ----------
        fs : float
            Sample rate [Hz]; the low-pass must lie below its Nyquist frequency.
        """
        return KernelState(self.design(fs), self.friction)

    def process(self, state: KernelState, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``{force_ax: F}`` [N] from the three input arrays (SI), carrying ``state``.

        Parameters
        ----------
        state : KernelState
            From :meth:`new_state`.
        arrays : mapping of str to ndarray
            The input channels (:attr:`channel_names`) [A, rad, m].
        """
        names = self._channels
        return {self._output: run_kernel(state, arrays[names[0]], arrays[names[1]], arrays[names[2]])}

    def fast_path(self, state: KernelState) -> Callable[..., dict[str, np.ndarray]]:
        """``step(current_ref [A], motor_angle [rad], table_position [m]) -> {force_ax: F [N]}`` on ``state``:
        the compiled kernel called directly.

        Parameters
        ----------
        state : KernelState
            From :meth:`new_state`; carried by the function.
        """
        name = self._output

        def step(current_ref: np.ndarray, motor_angle: np.ndarray, table_position: np.ndarray) -> dict:
            return {name: run_kernel(state, current_ref, motor_angle, table_position)}

        return step

    def describe(self) -> str:
        """Method, low-pass and compensation, for the provenance."""
        return (f"{type(self).__name__}, low-pass {self.signal.lpf_order}th order {self.signal.lpf_hz:g} Hz, "
                f"compensation {self.compensation()}")

    def check_length(self, recording: Recording) -> None:
        """Raise :class:`SignalTooShortError` if the trace is shorter than the filters' start-up.

        Parameters
        ----------
        recording : Recording
            The trace.
        """
        need = int(np.ceil(3 * self.settle_time(recording.fs) * recording.fs))
        if recording.n_samples < need:
            raise SignalTooShortError(
                f"trace '{recording.meta.get('name', 'trace')}' has {recording.n_samples} samples; "
                f"{self.name} needs at least {need} ({need / recording.fs * 1e3:.1f} ms at "
                f"{recording.fs:g} Hz) for its {self.signal.lpf_hz:g} Hz low-pass to settle")

    def check_trace(self, recording: Recording) -> None:
        """Refuse a trace too short for the filters or leaving the friction map's positions.

        Parameters
        ----------
        recording : Recording
            The trace.
        """
        self.check_length(recording)
        if self.friction_map is not None:
            self.friction_map.check_coverage(recording[f"{self.axis_name}_table_position"],
                                             recording.meta.get("name", "trace"))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(axis={self.axis_name!r}, compensation={self.compensation()})"
