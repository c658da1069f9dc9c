"""The baseline every user could write: least squares of each force on the drive signals.

Per axis ``F_a = sum_k w_{a,k} phi_k`` over the regressors of
:func:`regression_features`: the currents of every axis and of the spindle,
and ``sgn(v)``, ``v`` and ``a`` of every axis -- 13 columns on a three-axis
machine, no intercept, fitted by ordinary least squares on the calibration
cuts.  No physics: it uses whatever correlates with the force in the
calibration cut, including the other axes' currents (the process loads every
axis at once).  That is why it is the honest bar for the physical model
(:mod:`drivesense.machine.controller_model`): where the model cannot beat it
on held-out data, the model is not yet the machine.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivesense.errors import ConfigError, MissingChannelError

__all__ = ["RegressionModel", "regression_feature_names", "regression_features"]


def regression_feature_names(axes: Sequence[str], spindle: bool = True) -> tuple[str, ...]:
    """The regressors' names: ``<a>_current`` of each axis (and ``spindle_current``), then ``sgn_<a>``, ``<a>_velocity``
    and ``<a>_acceleration`` of each axis.

    Parameters
    ----------
    axes : sequence of str
        Axis letters.
    spindle : bool
        Include the spindle current.
    """
    return (tuple(f"{a}_current" for a in axes) + ("spindle_current",) * spindle
            + tuple(f"sgn_{a}" for a in axes) + tuple(f"{a}_velocity" for a in axes)
            + tuple(f"{a}_acceleration" for a in axes))


def _column(name: str, arrays: Mapping[str, np.ndarray]) -> np.ndarray:
    if name.startswith("sgn_"):
        return np.sign(np.asarray(arrays[f"{name[4:]}_velocity"], dtype=float))
    return np.asarray(arrays[name], dtype=float)


def _channel(name: str) -> str:
    return f"{name[4:]}_velocity" if name.startswith("sgn_") else name


def regression_features(arrays: Mapping[str, np.ndarray], names: Sequence[str]) -> np.ndarray:
    """The regressor matrix, one column per name of :func:`regression_feature_names` (SI inputs).

    Parameters
    ----------
    arrays : mapping of str to ndarray
        Logged channels: currents [A], velocities [m/s], accelerations [m/s^2].
    names : sequence of str
        Regressor names.
    """
    missing = sorted({_channel(n) for n in names} - set(arrays))
    if missing:
        raise MissingChannelError(f"the regression needs channel(s) {', '.join(missing)}")
    return np.column_stack([_column(n, arrays) for n in names])


@dataclass(frozen=True, eq=False)
class RegressionModel:
    """Least-squares weights per axis on the named regressors.

    Parameters
    ----------
    features : tuple of str
        Regressor names (:func:`regression_feature_names`).
    weights : dict of str to tuple of float
        Per axis letter, one weight per regressor [N per unit of the regressor].
    """

    features: tuple
    weights: dict

    def __post_init__(self) -> None:
        if not self.features or not self.weights:
            raise ConfigError("a RegressionModel needs regressors and at least one axis")
        for a, w in self.weights.items():
            if len(w) != len(self.features) or not all(math.isfinite(x) for x in w):
                raise ConfigError(f"regression axis {a}: needs {len(self.features)} finite weights, got {list(w)!r}")

    @classmethod
    def fit(cls, runs: Sequence[Mapping[str, np.ndarray]], axes: Sequence[str],
            features: Sequence[str] | None = None) -> "RegressionModel":
        """Ordinary least squares of ``force_<a>`` on the regressors, over all runs together.

        Parameters
        ----------
        runs : sequence of mapping
            Calibration cuts (Recordings or channel mappings) with ``force_<a>`` [N].
        axes : sequence of str
            Axes to fit (each needs ``force_<a>`` in every run).
        features : sequence of str, optional
            Regressors (default: :func:`regression_feature_names` of the axes, with the spindle current
            when every run has it).
        """
        if not runs:
            raise ConfigError("the regression needs at least one calibration cut")
        if features is None:
            spindle = all("spindle_current" in r for r in runs)
            features = regression_feature_names(axes, spindle)
        X = np.vstack([regression_features(r, features) for r in runs])
        weights = {}
        for a in axes:
            if not all(f"force_{a}" in r for r in runs):
                raise MissingChannelError(f"the regression of axis {a} needs force_{a} in every calibration cut")
            y = np.concatenate([np.asarray(r[f"force_{a}"], dtype=float) for r in runs])
            w, *_ = np.linalg.lstsq(X, y, rcond=None)
            weights[a] = tuple(float(x) for x in w)
        return cls(features=tuple(features), weights=weights)

    @property
    def input_channels(self) -> tuple[str, ...]:
        """Channels the regressors read."""
        return tuple(dict.fromkeys(_channel(n) for n in self.features))

    def predict(self, axis: str, arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """``force_<axis>`` [N] from the logged channels.

        Parameters
        ----------
        axis : str
            Axis letter.
        arrays : mapping of str to ndarray
            Logged channels [A, m/s, m/s^2].
        """
        if axis not in self.weights:
            raise ConfigError(f"the regression has no axis {axis!r} (it has {', '.join(self.weights)})")
        X = regression_features(arrays, self.features)
        out = np.zeros(X.shape[0])
        for k, w in enumerate(self.weights[axis]):      # column by column: the same bits for any chunking
            out += w * X[:, k]
        return out

    def to_dict(self) -> dict:
        """Plain types: ``features`` and ``weights`` (per axis, one per regressor)."""
        return {"features": list(self.features), "weights": {a: list(w) for a, w in self.weights.items()}}

    @classmethod
    def from_dict(cls, values: Mapping, *, source: str = "regression") -> "RegressionModel":
        """Inverse of :meth:`to_dict`, naming ``source`` in every error.

        Parameters
        ----------
        values : mapping
            As :meth:`to_dict` writes it.
        source : str
            Where the values come from (file and table).
        """
        if not isinstance(values, Mapping) or set(values) != {"features", "weights"}:
            raise ConfigError(f"{source}: expected a table with 'features' and 'weights'")
        feats, weights = values["features"], values["weights"]
        if not (isinstance(feats, list) and all(isinstance(f, str) for f in feats)) or not isinstance(weights, Mapping):
            raise ConfigError(f"{source}: 'features' must be a list of names and 'weights' a table per axis")
        try:
            return cls(features=tuple(feats), weights={str(a): tuple(float(x) for x in w) for a, w in weights.items()})
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: {exc}") from None
