"""Model-based reconstruction of the process force (third paper, Eq. 2, and the controller-rate model).

::

    est = ds.estimate.ModelBased(model)          # ThreeAxisModel, e.g. from read_axes_file
    est.fit(air_moves)                           # or: the four-step identification from air moves
    forces = est.estimate(nc_trace)              # Recording with force_x, force_y, force_z
    stream = est.stream(250.0); stream.push(chunk)   # the same numbers, chunk by chunk

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
  Dahl state of :func:`~drivesense.machine.presliding.presliding_direction`
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

With a :class:`~drivesense.machine.controller_model.ControllerModel` (any
drive type, from ``identify nc``: :func:`drivesense.identify.controller.identify_controller`)
the force of each axis is ``K_m I - sum_j p_j phi_j`` with the terms the
identification kept; its state is the presliding state of the axes with
``x_pre > 0`` (carried by streams) and its latency is the model's
``delay_s`` (the drive channels' logging delay behind the process force).
``fit(traces)`` then identifies that model from air and calibration cuts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import ConfigError, NotFittedError
from drivesense.estimate.base import ForceEstimator
from drivesense.identify.controller import identify_controller
from drivesense.identify.linear_axis import run_identification
from drivesense.machine.controller_model import STANDING_SPEED, ControllerModel
from drivesense.machine.linear_motor import AXES, ThreeAxisModel
from drivesense.machine.presliding import carried_presliding_direction
from drivesense.recording import Recording

__all__ = ["ModelBased", "MODEL_INPUTS"]

#: Channels read per axis letter.
MODEL_INPUTS = ("current", "position", "velocity", "acceleration")


class ModelBased(ForceEstimator):
    """Eq. 2 under the common estimator protocol.

    Parameters
    ----------
    model : ThreeAxisModel or ControllerModel, optional
        Identified axes (e.g. :func:`drivesense.io.axes_file.read_axes_file`);
        None until :meth:`fit`.
    axes : sequence of str, optional
        Axes to estimate (default: x, y, z, or every axis of a ControllerModel).
    kind : {"linear", "controller"}, optional
        Which model :meth:`fit` identifies: the four-step linear-motor model
        from dedicated air moves, or the controller-rate model from ordinary
        air cuts and calibration cuts (default: the kind of ``model``, else "linear").
    v_eps : float
        Half-width of the ramp replacing ``sgn(v)`` in the friction [m/s]
        (axes without presliding).
    presliding : bool
        Use the Dahl presliding state on axes whose model has ``x_pre > 0``
        (default); False: the paper's ramped sign on every axis.
    per_axis : {"model", "auto"}
        ``"auto"`` (``--per-axis auto``): on each axis where ``identify nc``
        found the regression better on held-out data (the model's ``choice``),
        take the regression it stored beside the model; ``"model"``: the
        physical model on every axis (default).
    """

    name = "model"
    drive = "linear"

    def __init__(self, model: ThreeAxisModel | ControllerModel | None = None, *, axes: Sequence[str] | None = None,
                 v_eps: float = 2.0e-4, presliding: bool = True, kind: str | None = None,
                 per_axis: str = "model") -> None:
        if model is not None and not isinstance(model, (ThreeAxisModel, ControllerModel)):
            raise ConfigError(f"ModelBased needs a ThreeAxisModel or ControllerModel, got {type(model).__name__}")
        if kind is None:
            kind = "controller" if isinstance(model, ControllerModel) else "linear"
        if kind not in ("linear", "controller") or (model is not None and
                                                    isinstance(model, ControllerModel) != (kind == "controller")):
            raise ConfigError(f"ModelBased kind must be 'linear' or 'controller' and match the model, got {kind!r}")
        self.kind = kind
        known = tuple(model.axes) if isinstance(model, ControllerModel) else AXES
        if isinstance(model, ControllerModel) and per_axis == "auto":     # and where only the regression could
            known = (*known, *(a for a, how in model.choice.items() if how == "regression" and a not in known))
        axes = tuple(axes) if axes is not None else (known if kind == "controller" or model is not None else AXES)
        bad = [a for a in axes if a not in known]
        if bad or not axes:
            raise ConfigError(f"ModelBased axes must be some of {', '.join(known)}, got {list(axes)!r}")
        if not (isinstance(v_eps, (int, float)) and v_eps >= 0):
            raise ConfigError(f"ModelBased 'v_eps' must be a speed >= 0 [m/s], got {v_eps!r}")
        if per_axis not in ("model", "auto"):
            raise ConfigError(f"--per-axis must be 'model' or 'auto', got {per_axis!r}")
        if per_axis == "auto" and not (isinstance(model, ControllerModel) and model.regression is not None):
            raise ConfigError("--per-axis auto needs a controller model identified with a calibration cut "
                              "('drivesense identify nc' stores the regression and its per-axis choice in AXES.toml)")
        self.per_axis = per_axis
        self.model = model
        self.axes = axes
        self.v_eps = float(v_eps)
        self.presliding = bool(presliding)
        self.report = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Input channels, ``{ax}_current, {ax}_position, {ax}_velocity, {ax}_acceleration`` per axis.

        A controller model reads only what its kept terms need.
        """
        if isinstance(self.model, ControllerModel):
            physical = [a for a in self.axes if a not in self.regression_axes]
            extra = self.model.regression.input_channels if self.regression_axes or self.sliding_axes else ()
            return tuple(dict.fromkeys((*self.model.input_channels(physical), *extra))) if physical else extra
        return tuple(f"{a}_{c}" for a in self.axes for c in MODEL_INPUTS)

    @property
    def output_channels(self) -> tuple[str, ...]:
        """Output channels ``force_{ax}``."""
        return tuple(f"force_{a}" for a in self.axes)

    @property
    def regression_axes(self) -> tuple[str, ...]:
        """Axes estimated by the stored regression (``per_axis="auto"`` where the model lost on held-out data)."""
        return self._chosen("regression")

    @property
    def sliding_axes(self) -> tuple[str, ...]:
        """Axes estimated by the model while they slide and by the regression while they stand (``per_axis="auto"``)."""
        return self._chosen("sliding")

    def _chosen(self, how: str) -> tuple[str, ...]:
        if self.per_axis != "auto" or not isinstance(self.model, ControllerModel):
            return ()
        return tuple(a for a in self.axes if self.model.choice.get(a) == how)

    def fit(self, runs: Sequence[Recording], **kwargs) -> "ModelBased":
        """Identify the model: four-step from air moves, or the controller-rate model.

        Parameters
        ----------
        runs : sequence of Recording
            ``kind="linear"``: air moves (no cutting) of all three axes;
            ``kind="controller"``: ordinary air cuts and calibration cuts
            (with ``force_*`` channels) of one trace rate.
        **kwargs
            Passed to :func:`drivesense.identify.linear_axis.run_identification`
            (the motor constants default to the current model's, if any) or
            :func:`drivesense.identify.controller.identify_controller`.

        Returns
        -------
        self
        """
        if self.kind == "controller":
            self.report = identify_controller(runs, **kwargs)
            self.model = self.report.model
            return self
        if self.model is not None and "motor_constants" not in kwargs:
            kwargs["motor_constants"] = {a: self.model.axis(a).K_m for a in AXES}
        self.report = run_identification(runs, **kwargs)
        self.model = self.report.model
        return self

    def _require_model(self) -> ThreeAxisModel | ControllerModel:
        if self.model is None:
            raise NotFittedError("ModelBased has no model: give a ThreeAxisModel (AXES.toml) or call fit(air_moves)")
        return self.model

    def uses_presliding(self, axis: str) -> bool:
        """True when ``axis`` is estimated with the presliding state (``x_pre > 0`` and ``presliding``).

        Parameters
        ----------
        axis : {"x", "y", "z"}
            Axis letter.
        """
        model = self._require_model()
        return self.presliding and isinstance(model, ThreeAxisModel) and model.axis(axis).x_pre > 0

    def forces(self, arrays: Mapping[str, np.ndarray], state: dict | None = None) -> dict[str, np.ndarray]:
        """Eq. 2 on arrays: ``{force_ax: F}`` [N] from ``{ax}_current`` [A], ``_position`` [m], ... (SI).

        Parameters
        ----------
        arrays : mapping of str to ndarray
            The input channels (see :attr:`channel_names`) [A, m, m/s, m/s^2], equally long.
        state : dict, optional
            Presliding state carried between calls (streaming): ``{ax:
            (last position [m], direction [-])}``, updated in place; None: a
            fresh start.
        """
        model = self._require_model()
        if isinstance(model, ControllerModel):
            fallback, sliding = self.regression_axes, self.sliding_axes
            out = {}
            for a in self.axes:
                if a in fallback:
                    out[f"force_{a}"] = model.regression.predict(a, arrays)
                    continue
                out[f"force_{a}"] = model.process_force(a, arrays, state)
                if a in sliding:        # a standing axis's guides hold the force its current cannot see
                    standing = np.abs(np.asarray(arrays[f"{a}_velocity"], dtype=float)) <= STANDING_SPEED
                    out[f"force_{a}"] = np.where(standing, model.regression.predict(a, arrays), out[f"force_{a}"])
            return out
        out = {}
        for a in self.axes:
            i, s, v, acc = (arrays[f"{a}_{c}"] for c in MODEL_INPUTS)
            direction = None
            if self.uses_presliding(a) and len(s):
                direction = carried_presliding_direction(s, model.axis(a).x_pre, state, a)
            out[f"force_{a}"] = model.process_force(a, i, s, v, acc, v_eps=self.v_eps, direction=direction)
        return out

    def latency_s(self, fs: float) -> float:
        """A controller model's ``delay_s``; else none: 0 s at any ``fs`` [Hz] (a trace's ``nc_delay_s`` adds to it).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return self.model.delay_s if isinstance(self.model, ControllerModel) else 0.0

    def new_state(self, fs: float) -> dict:
        """The presliding state per axis, ``{ax: (last position [m], direction [-])}``, empty at the start.

        Parameters
        ----------
        fs : float
            Sample rate [Hz] (the model works at any rate).
        """
        self._require_model()
        return {}

    def process(self, state: dict, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``{force_ax: F}`` [N] for the next samples, carrying the presliding state.

        Parameters
        ----------
        state : dict
            From :meth:`new_state`.
        arrays : mapping of str to ndarray
            The input channels (:attr:`channel_names`) [A, m, m/s, m/s^2].
        """
        return self.forces(arrays, state)

    def describe(self) -> str:
        """Eq. 2 and the friction direction used (or the controller model's terms), for the provenance."""
        if isinstance(self.model, ControllerModel):
            kept = {a: "the regression (--per-axis auto)" if a in self.regression_axes
                    else f"{len(self.model.axis(a).terms)} terms" + (", the regression while it stands (--per-axis auto)"
                                                                      if a in self.sliding_axes else "")
                    for a in self.axes}
            return (f"controller-rate model K_m I - sum p phi identified at {self.model.rate_hz:g} Hz "
                    f"({', '.join(f'{a}: {n}' for a, n in kept.items())})")
        pre = [a for a in self.axes if self.uses_presliding(a)]
        label = f"presliding (Dahl) on {''.join(pre)}" if pre else f"sgn(v) ramped over {self.v_eps * 1e3:g} mm/s"
        return f"Eq. 2 with stacked masses, friction direction {label}"

    def __repr__(self) -> str:
        state = "identified" if self.model is not None else "no model"
        return f"ModelBased(axes={''.join(self.axes)!r}, {state})"
