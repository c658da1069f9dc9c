"""The protocol every force estimator follows, and the linear ball-screw base class.

::

    est = ds.estimate.VibrationMode(axis, signal)
    est.fit(idle_runs)                 # friction map from air-cut runs (optional)
    est.tare(recording, 0.5, 1.5)      # or: a tare for a standing axis
    forces = est.estimate(recording)   # Recording with force_x, attrs latency_s
    state = est.stream(); state.push(chunk)

Batch and streaming run the same compiled kernel with the same state, so
they agree to the bit.
"""

from __future__ import annotations

from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from drivesense.errors import CoverageError, SignalTooShortError
from drivesense.estimate.design import ForceCombination, ObserverDesign, discretise
from drivesense.estimate.kernel import FrictionTable, KernelState, run_kernel
from drivesense.estimate.signal import SignalParams
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.recording import Recording

__all__ = ["ForceEstimator", "LinearForceEstimator", "EstimatorStream", "INPUT_CHANNELS"]

#: Channels a ball-screw estimator reads, per axis letter.
INPUT_CHANNELS = ("current_ref", "motor_angle", "table_position")


@runtime_checkable
class ForceEstimator(Protocol):
    """What benchmarks, the CLI and the monitor rely on."""

    name: str

    def fit(self, idle_runs: Sequence[Recording]) -> "ForceEstimator": ...

    def estimate(self, recording: Recording) -> Recording: ...

    def stream(self): ...


class EstimatorStream:
    """Chunk-by-chunk estimation with carried state (see :meth:`LinearForceEstimator.stream`).

    The state's size does not depend on how much has been pushed.
    """

    def __init__(self, estimator: "LinearForceEstimator", fs: float) -> None:
        self.estimator = estimator
        self.fs = float(fs)
        self._state = estimator._new_state(fs)
        self._channels = estimator.channel_names
        self.samples_seen = 0

    @property
    def latency_s(self) -> float:
        """Pure delay of the estimate [s]."""
        return self._state_latency

    @property
    def _state_latency(self) -> float:
        return self.estimator.design(self.fs).latency_s

    def push_arrays(self, current_ref, motor_angle, table_position) -> np.ndarray:
        """Process one chunk given as arrays (SI) and return ``force_x`` [N] for it (fast path)."""
        out = run_kernel(self._state, current_ref, motor_angle, table_position)
        self.samples_seen += out.size
        return out

    def push(self, chunk: Recording | Mapping[str, np.ndarray]):
        """Process one chunk.

        Parameters
        ----------
        chunk : Recording or mapping of str to ndarray
            The next samples of the input channels (SI).  A mapping may use the
            canonical names (``x_current_ref`` ...) or the bare ones
            (``current_ref`` ...).

        Returns
        -------
        ndarray or Recording
            The force estimate [N] for the chunk's samples; a Recording (with
            the chunk's time base) when a Recording was pushed.
        """
        if isinstance(chunk, Recording):
            chunk.require(*self._channels)
            force = self.push_arrays(*(chunk[c] for c in self._channels))
            return self.estimator._wrap(chunk, force)
        arrays = []
        for full in self._channels:
            bare = full.split("_", 1)[1]
            if full in chunk:
                arrays.append(chunk[full])
            elif bare in chunk:
                arrays.append(chunk[bare])
            else:
                from drivesense.errors import MissingChannelError

                raise MissingChannelError(f"stream chunk lacks channel '{full}'")
        return self.push_arrays(*arrays)


class LinearForceEstimator:
    """Base of the ball-screw estimators of the first paper.

    Parameters
    ----------
    axis : BallScrewAxis
        Axis parameters.
    signal : SignalParams, optional
        Phase-lag compensation and low-pass (default: the paper's values).
    axis_name : str
        Axis letter of the input and output channels.
    """

    #: Short name used by the CLI and the benchmarks.
    name = "linear"
    #: Discretisation of the derivatives ("central" or "bilinear").
    discretisation = "central"

    def __init__(self, axis: BallScrewAxis, signal: SignalParams | None = None, *, axis_name: str = "x") -> None:
        self.axis = axis
        self.signal = signal or SignalParams()
        self.axis_name = axis_name
        self.friction = FrictionTable.zero()
        self.friction_map = None
        self._designs: dict[float, ObserverDesign] = {}

    # ----------------------------------------------------------------- design
    def combination(self) -> ForceCombination:
        """The estimating equation (overridden by each method)."""
        raise NotImplementedError

    def map_combination(self) -> ForceCombination:
        """Combination used to build friction maps (the method's own by default)."""
        return self.combination()

    def design(self, fs: float) -> ObserverDesign:
        """Discrete observer for sample rate ``fs`` [Hz] (cached)."""
        if fs not in self._designs:
            self._designs[fs] = discretise(self.combination(), self.axis, self.signal, fs, self.discretisation)
        return self._designs[fs]

    @property
    def channel_names(self) -> tuple[str, str, str]:
        """Input channel names for this axis."""
        return tuple(f"{self.axis_name}_{c}" for c in INPUT_CHANNELS)  # type: ignore[return-value]

    @property
    def output_channel(self) -> str:
        """Name of the output channel (``force_x``...)."""
        return f"force_{self.axis_name}"

    # ------------------------------------------------------------ compensation
    def fit(self, idle_runs: Sequence[Recording], **kwargs) -> "LinearForceEstimator":
        """Build the friction map of this method from idling (air-cut) runs (Sec. 4).

        Parameters
        ----------
        idle_runs : sequence of Recording
            Runs over the same trajectory as the cuts, with no cutting.
        **kwargs
            Passed to :func:`drivesense.identify.friction.build_friction_map`
            (e.g. ``bin_width`` [m]).

        Returns
        -------
        self
        """
        from drivesense.identify.friction import build_friction_map

        fmap = build_friction_map(self, idle_runs, **kwargs)
        self.friction_map = fmap
        self.friction = fmap.table()
        return self

    def tare(self, recording: Recording, start: float, end: float) -> float:
        """Take a constant tare from the uncompensated estimate over ``[start, end)`` [s].

        For an axis that stands (cross-feed): the static friction and offsets
        are whatever they were before the cut; their sum is removed.

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
        """Time the filters need to forget their start [s] (about 10 low-pass time constants)."""
        return max(10.0 / self.signal.lpf_hz, 30.0 / fs)

    # ------------------------------------------------------------- estimation
    def _new_state(self, fs: float) -> KernelState:
        return KernelState(self.design(fs), self.friction)

    def _inputs(self, recording: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        recording.require(*self.channel_names)
        return tuple(recording[c] for c in self.channel_names)  # type: ignore[return-value]

    def _wrap(self, recording: Recording, force: np.ndarray) -> Recording:
        design = self.design(recording.fs)
        meta = {"name": f"{recording.meta.get('name', 'trace')}:{self.name}", "method": self.name,
                "latency_s": design.latency_s, "source": recording.meta.get("name", ""),
                "provenance": list(recording.meta.get("provenance", []))
                + [f"estimate {self.name}: latency {design.latency_s * 1e3:.3f} ms, "
                   f"low-pass {self.signal.lpf_order}th order {self.signal.lpf_hz:g} Hz"]}
        # a linear filter of validated (finite) inputs is finite: no copy, no re-validation on this hot path
        return Recording._from_trusted({self.output_channel: force}, {self.output_channel: "N"},
                                       fs=recording.fs, t0=recording.t0, meta=meta)

    def check_length(self, recording: Recording) -> None:
        """Raise :class:`SignalTooShortError` if the trace is shorter than the filters' start-up."""
        need = int(np.ceil(3 * self.settle_time(recording.fs) * recording.fs))
        if recording.n_samples < need:
            raise SignalTooShortError(
                f"trace '{recording.meta.get('name', 'trace')}' has {recording.n_samples} samples; "
                f"{self.name} needs at least {need} ({need / recording.fs * 1e3:.1f} ms at "
                f"{recording.fs:g} Hz) for its {self.signal.lpf_hz:g} Hz low-pass to settle")

    def estimate(self, recording: Recording) -> Recording:
        """Estimate the process force on the table.

        Parameters
        ----------
        recording : Recording
            Trace with ``{ax}_current_ref`` [A], ``{ax}_motor_angle`` [rad] and
            ``{ax}_table_position`` [m].

        Returns
        -------
        Recording
            One channel ``force_{ax}`` [N] (force on the table along +axis),
            ``meta["latency_s"]`` the pure delay of the estimate [s].
        """
        self.check_length(recording)
        inputs = self._inputs(recording)
        if self.friction_map is not None:
            self.friction_map.check_coverage(inputs[2], recording.meta.get("name", "trace"))
        state = self._new_state(recording.fs)
        force = run_kernel(state, *inputs)
        return self._wrap(recording, force)

    def stream(self, fs: float = 10_000.0) -> EstimatorStream:
        """A streaming estimator for signals at ``fs`` [Hz] with the current compensation."""
        return EstimatorStream(self, fs)

    def __repr__(self) -> str:
        comp = "friction map" if self.friction_map is not None else (
            "tare" if self.friction.values.size == 1 and self.friction.values[0] != 0 else "none")
        return f"{type(self).__name__}(axis={self.axis_name!r}, compensation={comp})"
