"""Model-based reconstruction of the process force on a linear-motor machine (third paper, Eq. 2).

::

    est = ds.estimate.ModelBased(model)          # ThreeAxisModel, e.g. from read_axes_file
    est.fit(air_moves)                           # or: the four-step identification from air moves
    forces = est.estimate(nc_trace)              # Recording with force_x, force_y, force_z
    state = est.stream(); state.push(chunk)      # the same numbers, chunk by chunk

For each axis ``F = K_m I - k (s - s_r) - M a - F_co(s) - F_fr(v)`` with the
stacked masses of Eq. 2, sample by sample from the NC trace's current,
position, velocity and acceleration.  It adds no delay; its declared latency
is the delay the trace itself declares (``meta["nc_delay_s"]``, e.g. a
logger's anti-alias filter), 0 when it declares none.

Friction direction.  ``sgn(v)`` of Eq. 4 cannot be used as it stands: at
standstill the NC velocity is noise around zero and the sign would flip the
friction by twice the breakaway force from sample to sample.

* Axes whose model has a presliding distance ``x_pre > 0`` (identified from
  the air moves, step 5 of :mod:`drivesense.identify.linear_axis`) use the
  Dahl state of :func:`~drivesense.machine.linear_motor.presliding_direction`
  instead: it follows the measured position, so a standing axis whose guides
  hold the process force by presliding is credited with the spring force of
  its micro-motion, and a reversal turns the friction over ``x_pre`` of travel.
  The state is the only memory of the method; the stream carries it, so
  streaming equals batch to the bit.  It starts at 0 (no friction held),
  which is right for an axis that has not moved since power-on and otherwise
  settles after ``x_pre`` of travel.
* Axes with ``x_pre = 0`` (or ``presliding=False``) use the paper's sign,
  as a linear ramp over ``|v| < v_eps`` (default 0.2 mm/s).  A standing axis
  is then credited with no friction at all and the ramp acts as a huge
  damper on its micro-motion: the paper's errors on the standing axis.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError, MissingChannelError
from drivesense.machine.linear_motor import AXES, ThreeAxisModel, carried_presliding_direction
from drivesense.recording import Recording

__all__ = ["ModelBased", "ModelBasedStream", "MODEL_INPUTS"]

#: Channels read per axis letter.
MODEL_INPUTS = ("current", "position", "velocity", "acceleration")


class ModelBased:
    """Eq. 2 under the common estimator protocol.

    Parameters
    ----------
    model : ThreeAxisModel, optional
        Identified axes (e.g. :func:`drivesense.io.axes_file.read_axes_file`);
        None until :meth:`fit`.
    axes : sequence of str
        Axes to estimate (default x, y, z); each needs its four input channels.
    v_eps : float
        Half-width of the ramp replacing ``sgn(v)`` in the friction [m/s]
        (axes without presliding).
    presliding : bool
        Use the Dahl presliding state on axes whose model has ``x_pre > 0``
        (default); False: the paper's ramped sign on every axis.
    """

    #: Short name used by the CLI and the benchmarks.
    name = "model"

    def __init__(self, model: ThreeAxisModel | None = None, *, axes: Sequence[str] = AXES,
                 v_eps: float = 2.0e-4, presliding: bool = True) -> None:
        if model is not None and not isinstance(model, ThreeAxisModel):
            raise ConfigError(f"ModelBased needs a ThreeAxisModel, got {type(model).__name__}")
        axes = tuple(axes)
        bad = [a for a in axes if a not in AXES]
        if bad or not axes:
            raise ConfigError(f"ModelBased axes must be some of x, y, z, got {list(axes)!r}")
        if not (isinstance(v_eps, (int, float)) and v_eps >= 0):
            raise ConfigError(f"ModelBased 'v_eps' must be a speed >= 0 [m/s], got {v_eps!r}")
        self.model = model
        self.axes = axes
        self.v_eps = float(v_eps)
        self.presliding = bool(presliding)
        self.report = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Input channels, ``{ax}_current, {ax}_position, {ax}_velocity, {ax}_acceleration`` per axis."""
        return tuple(f"{a}_{c}" for a in self.axes for c in MODEL_INPUTS)

    @property
    def output_channels(self) -> tuple[str, ...]:
        """Output channels ``force_{ax}``."""
        return tuple(f"force_{a}" for a in self.axes)

    def fit(self, idle_runs: Sequence[Recording], **kwargs) -> "ModelBased":
        """Identify the model from air moves by the four-step method.

        Parameters
        ----------
        idle_runs : sequence of Recording
            Air moves (no cutting) of all three axes.
        **kwargs
            Passed to :func:`drivesense.identify.linear_axis.run_identification`;
            the motor constants default to the current model's, if any.

        Returns
        -------
        self
        """
        from drivesense.identify.linear_axis import run_identification

        if self.model is not None and "motor_constants" not in kwargs:
            kwargs["motor_constants"] = {a: self.model.axis(a).K_m for a in AXES}
        self.report = run_identification(idle_runs, **kwargs)
        self.model = self.report.model
        return self

    def _require_model(self) -> ThreeAxisModel:
        if self.model is None:
            from drivesense.errors import NotFittedError

            raise NotFittedError("ModelBased has no model: give a ThreeAxisModel (AXES.toml) or call fit(air_moves)")
        return self.model

    def uses_presliding(self, axis: str) -> bool:
        """True when ``axis`` is estimated with the presliding state (``x_pre > 0`` and ``presliding``)."""
        return self.presliding and self._require_model().axis(axis).x_pre > 0

    def forces(self, arrays: Mapping[str, np.ndarray], state: dict | None = None) -> dict[str, np.ndarray]:
        """Eq. 2 on arrays: ``{force_ax: F}`` [N] from ``{ax}_current`` [A], ``_position`` [m], ... (SI).

        Parameters
        ----------
        arrays : mapping of str to ndarray
            The input channels (see :attr:`channel_names`), equally long.
        state : dict, optional
            Presliding state carried between calls (streaming): ``{ax:
            (last position [m], direction [-])}``, updated in place; None: a
            fresh start.
        """
        model = self._require_model()
        out = {}
        for a in self.axes:
            i, s, v, acc = (arrays[f"{a}_{c}"] for c in MODEL_INPUTS)
            direction = None
            if self.uses_presliding(a) and len(s):
                direction = carried_presliding_direction(s, model.axis(a).x_pre, state, a)
            out[f"force_{a}"] = model.process_force(a, i, s, v, acc, v_eps=self.v_eps, direction=direction)
        return out

    def latency(self, recording: Recording | None = None) -> float:
        """Declared latency [s]: none of its own, plus the trace's ``meta["nc_delay_s"]``.

        Parameters
        ----------
        recording : Recording, optional
            The trace (its declared delay); None: 0.
        """
        if recording is None:
            return 0.0
        delay = recording.meta.get("nc_delay_s", 0.0)
        if not isinstance(delay, (int, float)) or not np.isfinite(delay) or delay < 0:
            raise ConfigError(f"recording meta 'nc_delay_s' must be a delay >= 0 [s], got {delay!r}")
        return float(delay)

    def _friction_label(self) -> str:
        pre = [a for a in self.axes if self.uses_presliding(a)]
        return f"presliding (Dahl) on {''.join(pre)}" if pre else f"sgn(v) ramped over {self.v_eps * 1e3:g} mm/s"

    def _wrap(self, recording: Recording, forces: dict[str, np.ndarray], latency: float) -> Recording:
        name = recording.meta.get("name", "trace")
        meta = {"name": f"{name}:{self.name}", "method": self.name, "latency_s": latency, "source": name,
                "provenance": list(recording.meta.get("provenance", []))
                + [f"estimate {self.name}: Eq. 2 with stacked masses, friction direction "
                   f"{self._friction_label()}; latency "
                   f"{latency * 1e3:.3f} ms (the trace's declared delay)"]}
        return Recording._from_trusted(forces, {k: "N" for k in forces}, fs=recording.fs, t0=recording.t0,
                                       meta=meta)

    def estimate(self, recording: Recording) -> Recording:
        """Reconstruct the process force.

        Parameters
        ----------
        recording : Recording
            NC trace with the input channels of every estimated axis (SI).

        Returns
        -------
        Recording
            ``force_{ax}`` [N] (force on the workpiece along +axis) on the
            trace's time base; ``meta["latency_s"]`` the declared latency [s].

        Raises
        ------
        MissingChannelError
            Naming the missing input channels.
        NotFittedError
            Without a model.
        """
        self._require_model()
        recording.require(*self.channel_names)
        forces = self.forces({c: recording[c] for c in self.channel_names})
        return self._wrap(recording, forces, self.latency(recording))

    def stream(self, fs: float = 250.0, *, latency_s: float = 0.0) -> "ModelBasedStream":
        """A streaming estimator (the same numbers as :meth:`estimate`, chunk by chunk).

        Parameters
        ----------
        fs : float
            Sample rate of the chunks [Hz].
        latency_s : float
            Delay the incoming signals carry [s] (reported as the latency).
        """
        self._require_model()
        return ModelBasedStream(self, fs, latency_s)

    def __repr__(self) -> str:
        state = "identified" if self.model is not None else "no model"
        return f"ModelBased(axes={''.join(self.axes)!r}, {state})"


class ModelBasedStream:
    """Chunk-by-chunk :class:`ModelBased` estimation (carries the presliding state, if any).

    Parameters
    ----------
    estimator : ModelBased
        The estimator (its model and axes).
    fs : float
        Sample rate of the chunks [Hz].
    latency_s : float
        Declared latency of the estimate [s].
    """

    def __init__(self, estimator: ModelBased, fs: float, latency_s: float = 0.0) -> None:
        self.estimator = estimator
        self.fs = float(fs)
        self.latency_s = float(latency_s)
        self.samples_seen = 0
        #: Presliding state per axis, ``(last position [m], direction [-])``.
        self.state: dict = {}

    def push(self, chunk: Recording | Mapping[str, np.ndarray]):
        """Process the next samples.

        Parameters
        ----------
        chunk : Recording or mapping of str to array_like
            Input channels (canonical names, SI), equally long.

        Returns
        -------
        dict of str to ndarray or Recording
            ``{force_ax: F}`` [N] for the chunk's samples; a Recording (with
            the chunk's time base) when a Recording was pushed.
        """
        est = self.estimator
        if isinstance(chunk, Recording):
            chunk.require(*est.channel_names)
            forces = est.forces({c: chunk[c] for c in est.channel_names}, self.state)
            self.samples_seen += chunk.n_samples
            return est._wrap(chunk, forces, self.latency_s)
        if not isinstance(chunk, Mapping):
            raise InvalidSignalError(f"push() takes a Recording or a mapping of channel arrays, got "
                                     f"{type(chunk).__name__}")
        missing = [c for c in est.channel_names if c not in chunk]
        if missing:
            raise MissingChannelError(f"stream chunk lacks channel(s) {', '.join(repr(m) for m in missing)}")
        arrays, n = {}, None
        for c in est.channel_names:
            arr = np.asarray(chunk[c], dtype=np.float64)
            if arr.ndim != 1:
                raise InvalidSignalError(f"stream chunk channel {c!r} must be 1-D, got shape {arr.shape}")
            if n is not None and arr.size != n:
                raise InvalidSignalError(f"stream chunk channel {c!r} has {arr.size} samples, others {n}")
            if not np.all(np.isfinite(arr)):
                raise InvalidSignalError(f"stream chunk channel {c!r} holds NaN or inf")
            arrays[c], n = arr, arr.size
        self.samples_seen += n or 0
        return est.forces(arrays, self.state)
