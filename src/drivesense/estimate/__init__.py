"""Force estimators: one protocol for all (see :mod:`drivesense.estimate.base`).

``CurrentOnly`` (baseline), ``RigidBody`` (Eq. 5), ``MEDOB`` (Appendix, observer
form) and ``VibrationMode`` (Eq. 6) of the first paper.
"""

from drivesense.estimate.base import EstimatorStream, ForceEstimator, LinearForceEstimator
from drivesense.estimate.current_only import CurrentOnly
from drivesense.estimate.medob import MEDOB
from drivesense.estimate.model_based import ModelBased, ModelBasedStream
from drivesense.estimate.rigid import RigidBody
from drivesense.estimate.signal import SignalParams
from drivesense.estimate.vibration import VibrationMode

__all__ = ["ForceEstimator", "LinearForceEstimator", "EstimatorStream", "CurrentOnly", "RigidBody",
           "MEDOB", "VibrationMode", "SignalParams", "METHODS", "make_estimator"]
__all__ += ["ModelBased", "ModelBasedStream"]   # linear-motor machine (third paper, Eq. 2)

#: CLI / benchmark names of the ball-screw estimators.
METHODS = {"current": CurrentOnly, "rigid": RigidBody, "medob": MEDOB, "vibration": VibrationMode}


def make_estimator(method: str, axis, signal=None, *, axis_name: str = "x") -> LinearForceEstimator:
    """Build an estimator by its short name (``current``, ``rigid``, ``medob``, ``vibration``)."""
    try:
        cls = METHODS[method]
    except KeyError:
        from drivesense.errors import ConfigError

        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}") from None
    return cls(axis, signal, axis_name=axis_name)
