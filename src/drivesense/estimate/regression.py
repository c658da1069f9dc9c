"""``regression``: least squares of each force on the drive signals, as an estimator.

::

    est = ds.estimate.make("regression", axes="AXES.toml")   # the regression identify nc fitted beside the model
    est = ds.estimate.Regression().fit(calibration_cuts)      # or fitted here, on cuts with force_x/y/z

The baseline every user could write (:mod:`drivesense.machine.regression_model`):
no physics, no state, no latency of its own.  ``identify nc`` fits it on the
same calibration cuts as the physical model and stores it in AXES.toml, so
``estimate --method regression`` scores the bar the model must clear, and
``estimate --method model --per-axis auto`` can take it on an axis where the
model lost on held-out data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from drivesense.errors import ConfigError, NotFittedError
from drivesense.estimate.base import ForceEstimator
from drivesense.machine.controller_model import ControllerModel
from drivesense.machine.regression_model import RegressionModel
from drivesense.recording import Recording

__all__ = ["Regression"]


class Regression(ForceEstimator):
    """The least-squares regression under the common estimator protocol.

    Parameters
    ----------
    model : RegressionModel or ControllerModel, optional
        The fitted regression, or a controller model that holds one (``identify nc``'s AXES.toml);
        None until :meth:`fit`.
    axes : sequence of str, optional
        Axes to estimate (default: every axis of the regression; x, y, z before :meth:`fit`).
    """

    name = "regression"
    drive = "linear"

    def __init__(self, model: RegressionModel | ControllerModel | None = None, *,
                 axes: Sequence[str] | None = None) -> None:
        if isinstance(model, ControllerModel):
            if model.regression is None:
                raise ConfigError("this AXES.toml holds no regression: identify the model again with "
                                  "'drivesense identify nc' and a calibration cut (it fits the regression beside it)")
            model = model.regression
        if model is not None and not isinstance(model, RegressionModel):
            raise ConfigError(f"Regression needs a RegressionModel or ControllerModel, got {type(model).__name__}")
        known = tuple(model.weights) if model is not None else ("x", "y", "z")
        axes = tuple(axes) if axes is not None else known
        bad = [a for a in axes if a not in known]
        if bad or not axes:
            raise ConfigError(f"Regression axes must be some of {', '.join(known)}, got {list(axes)!r}")
        self.model = model
        self.axes = axes

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Currents, velocities and accelerations the regressors read."""
        if self.model is None:
            raise NotFittedError("Regression has no weights: give AXES.toml from identify nc or call fit(cuts)")
        return self.model.input_channels

    @property
    def output_channels(self) -> tuple[str, ...]:
        """``force_{ax}``."""
        return tuple(f"force_{a}" for a in self.axes)

    def fit(self, runs: Sequence[Recording], **kwargs) -> "Regression":
        """Least squares on calibration cuts with ``force_<ax>`` [N].

        Parameters
        ----------
        runs : sequence of Recording
            Calibration cuts.
        **kwargs
            ``features``: regressor names (default: every axis's current, the spindle current, sgn(v), v, a).
        """
        self.model = RegressionModel.fit(list(runs), self.axes, **kwargs)
        return self

    def latency_s(self, fs: float) -> float:
        """None of its own: 0 s at any ``fs`` [Hz].

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        return 0.0

    def new_state(self, fs: float) -> dict:
        """No state (the regression has no memory).

        Parameters
        ----------
        fs : float
            Sample rate [Hz].
        """
        if self.model is None:
            raise NotFittedError("Regression has no weights: give AXES.toml from identify nc or call fit(cuts)")
        return {}

    def process(self, state: dict, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``{force_ax: F}`` [N] for the next samples.

        Parameters
        ----------
        state : dict
            From :meth:`new_state`.
        arrays : mapping of str to ndarray
            The input channels (:attr:`channel_names`) [A, m/s, m/s^2].
        """
        return {f"force_{a}": self.model.predict(a, arrays) for a in self.axes}

    def describe(self) -> str:
        """What the weights are, for the provenance."""
        return f"least squares of each force on {len(self.model.features)} regressors ({', '.join(self.model.features)})"

    def __repr__(self) -> str:
        return f"Regression(axes={''.join(self.axes)!r}, {'fitted' if self.model is not None else 'not fitted'})"
