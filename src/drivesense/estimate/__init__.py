"""Force estimators: one contract for all (:mod:`drivesense.estimate.base`), one registry.

Ball screw (first paper): ``CurrentOnly`` (baseline), ``RigidBody`` (Eq. 5),
``MEDOB`` (Appendix, observer form), ``VibrationMode`` (Eq. 6).  Linear motor
(third paper): ``ModelBased`` (Eq. 2); the learned ``LSTM`` and ``Hybrid``
live in :mod:`drivesense.learn` and register here when it is imported.

>>> import drivesense as ds
>>> ds.estimate.available()
('current', 'rigid', 'medob', 'vibration', 'model', 'regression', 'lstm', 'hybrid')
"""

from __future__ import annotations

from drivesense.errors import ConfigError
from drivesense.estimate.ballscrew import BallScrewEstimator
from drivesense.estimate.base import ForceEstimator, ForceStream
from drivesense.estimate.current_only import CurrentOnly
from drivesense.estimate.friction_map import FrictionMap, build_friction_map
from drivesense.estimate.medob import MEDOB
from drivesense.estimate.model_based import ModelBased
from drivesense.estimate.registry import MethodInfo, available, describe_methods, is_path, make, register
from drivesense.estimate.regression import Regression
from drivesense.estimate.rigid import RigidBody
from drivesense.estimate.vibration import VibrationMode
from drivesense.io.axes_file import read_axes_file
from drivesense.io.axis_file import read_axis_file
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.controller_model import ControllerModel
from drivesense.machine.linear_motor import ThreeAxisModel
from drivesense.machine.regression_model import RegressionModel
from drivesense.machine.signal_chain import SignalParams

__all__ = ["ForceEstimator", "ForceStream", "BallScrewEstimator", "CurrentOnly", "RigidBody", "MEDOB",
           "VibrationMode", "ModelBased", "Regression", "SignalParams", "FrictionMap", "build_friction_map",
           "MethodInfo", "available", "make", "register", "describe_methods"]


def _ballscrew_factory(cls: type[BallScrewEstimator]):
    def factory(*, axis, signal: SignalParams | None = None, axis_name: str = "x") -> BallScrewEstimator:
        if is_path(axis):
            axis, file_signal = read_axis_file(axis)
            signal = signal or file_signal
        if not isinstance(axis, BallScrewAxis):
            raise ConfigError(f"method {cls.name!r} needs a ball-screw axis (--axis AXIS.toml), "
                              f"got {type(axis).__name__}")
        return cls(axis, signal, axis_name=axis_name)

    factory.__doc__ = f"{cls.__name__} from ``axis`` (BallScrewAxis or AXIS.toml path), ``signal``, ``axis_name``."
    return factory


def _model_factory(*, axes, presliding: bool = True, v_eps: float = 2.0e-4, per_axis: str = "model") -> ModelBased:
    if is_path(axes):
        axes = read_axes_file(axes)
    if not isinstance(axes, (ThreeAxisModel, ControllerModel)):
        raise ConfigError(f"method 'model' needs identified axes (--axes AXES.toml), got {type(axes).__name__}")
    return ModelBased(axes, presliding=presliding, v_eps=v_eps, per_axis=per_axis)


def _regression_factory(*, axes) -> Regression:
    if is_path(axes):
        axes = read_axes_file(axes)
    if not isinstance(axes, (RegressionModel, ControllerModel)):
        raise ConfigError(f"method 'regression' needs the AXES.toml of 'identify nc' (--axes), got {type(axes).__name__}")
    return Regression(axes)


_SUMMARIES = {
    CurrentOnly: "K_t I / R minus friction: the classical current-based baseline",
    RigidBody: "rigid-body mode, Eq. 5 of the first paper",
    MEDOB: "multi-encoder disturbance observer (observer form), the first paper's Appendix",
    VibrationMode: "vibration mode, Eq. 6 of the first paper",
}
for _cls, _summary in _SUMMARIES.items():
    register(_cls.name, _ballscrew_factory(_cls), drive="ballscrew", summary=_summary, needs="--axis AXIS.toml (the ball-screw axis file: drivesense axis or identify frf)")
register(ModelBased.name, _model_factory, drive="linear",
         needs="--axes AXES.toml (write one with 'drivesense identify linear' or 'drivesense identify nc')",
         summary="linear-motor axis model (Eq. 2 of the third paper, presliding friction) or the controller-rate "
                 "model of any machine")
register(Regression.name, _regression_factory, drive="linear",
         needs="--axes AXES.toml (written by 'drivesense identify nc' from a calibration cut)",
         summary="least squares of each force on all currents, sgn(v), v and a: the baseline identify nc "
                 "fits beside the model")
