"""The registry of force-estimation methods: every method by name, built the same way.

::

    ds.estimate.available()                                   # the seven names
    ds.estimate.make("vibration", axis=AXIS, signal=SIGNAL)   # ball screw: current, rigid, medob, vibration
    ds.estimate.make("model", axes=AXES)                      # linear motor, Eq. 2
    ds.estimate.make("lstm", model=PATH)                      # learned: lstm, hybrid

A method registers a factory with :func:`register`; the layers above
``estimate`` (e.g. :mod:`drivesense.learn`) register theirs when imported,
which ``import drivesense`` does, so the registry never imports upwards.
The CLI, the benchmarks and the monitor build estimators through
:func:`make` and nothing else.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from drivesense.errors import ConfigError
from drivesense.estimate.base import ForceEstimator

__all__ = ["MethodInfo", "register", "available", "make", "describe_methods", "is_path"]


@dataclass(frozen=True)
class MethodInfo:
    """One registered method.

    Attributes
    ----------
    name : str
        Short name (``--method``).
    factory : callable
        ``factory(**config) -> ForceEstimator``.
    drive : str
        ``"ballscrew"`` or ``"linear"``.
    summary : str
        One line for ``--help`` and listings.
    needs : str
        What the method must be given, in CLI terms (for messages).
    """

    name: str
    factory: Callable[..., ForceEstimator]
    drive: str
    summary: str
    needs: str


_METHODS: dict[str, MethodInfo] = {}


def register(name: str, factory: Callable[..., ForceEstimator], *, drive: str, summary: str,
             needs: str = "") -> None:
    """Add a method to the registry (replacing one of the same name).

    Parameters
    ----------
    name : str
        Short name.
    factory : callable
        Builds the estimator from keyword configuration.
    drive : {"ballscrew", "linear"}
        Drive type of the signals it reads.
    summary : str
        One line describing the method.
    needs : str
        What must be given, in CLI terms (e.g. ``"--axis AXIS.toml"``).
    """
    if drive not in ("ballscrew", "linear"):
        raise ConfigError(f"method {name!r}: drive must be 'ballscrew' or 'linear', got {drive!r}")
    _METHODS[name] = MethodInfo(name, factory, drive, summary, needs)


def available(drive: str | None = None) -> tuple[str, ...]:
    """Names of the registered methods, in registration order.

    Parameters
    ----------
    drive : {"ballscrew", "linear"}, optional
        Only the methods for this drive type.
    """
    return tuple(n for n, m in _METHODS.items() if drive is None or m.drive == drive)


def describe_methods() -> dict[str, MethodInfo]:
    """Every registered method with its description."""
    return dict(_METHODS)


def make(name: str, **config: Any) -> ForceEstimator:
    """Build any registered estimator by name.

    Parameters
    ----------
    name : str
        One of :func:`available`.
    **config
        The method's configuration: ``axis`` (a ``BallScrewAxis`` or an
        AXIS.toml path), ``signal`` and ``axis_name`` for the ball-screw methods;
        ``axes`` (a ``ThreeAxisModel`` or an AXES.toml path) for ``model``;
        ``model`` (a trained model or its folder) for ``lstm`` / ``hybrid``.

    Returns
    -------
    ForceEstimator

    Raises
    ------
    ConfigError
        An unknown name, or configuration the method does not take or lacks.
    """
    try:
        info = _METHODS[name]
    except KeyError:
        raise ConfigError(f"unknown method {name!r}; choose one of {', '.join(_METHODS)}") from None
    try:
        inspect.signature(info.factory).bind(**config)
    except TypeError as exc:
        raise ConfigError(f"method {name!r}: {exc} (it needs {info.needs or 'no configuration'})") from None
    return info.factory(**config)


def is_path(value: Any) -> bool:
    """True for a str or Path (a file or folder to read a configuration from).

    Parameters
    ----------
    value : object
        A configuration value.

    Returns
    -------
    bool
    """
    return isinstance(value, (str, Path))
