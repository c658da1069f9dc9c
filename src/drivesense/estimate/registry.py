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

__all__ = ["MethodInfo", "register", "available", "make", "make_from_files", "describe_methods", "is_path"]


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


#: CLI option of each kind of method configuration, and the :func:`make` keyword it fills.
FILE_OPTIONS = {"--axis": "axis", "--axes": "axes", "--model": "model"}


def make_from_files(method: str, *, axis_file: Any = None, axes_file: Any = None, model_dir: Any = None,
                    axis_name: str = "x", labels: dict | None = None) -> ForceEstimator:
    """Any registered method from its configuration files (the CLI's ``--axis``, ``--axes`` or ``--model``).

    Refuses, naming the options, a method given another method's configuration or without its own.

    Parameters
    ----------
    method : str
        Method name (``--method``).
    axis_file : str or Path, optional
        AXIS.toml of a ball-screw axis (``--axis``).
    axes_file : str or Path, optional
        AXES.toml of a linear-motor machine (``--axes``).
    model_dir : str or Path, optional
        Trained model folder (``--model``).
    axis_name : str
        Axis letter of a ball-screw method's channels.
    labels : dict, optional
        What to call ``--method``, ``--axis``, ``--axes`` and ``--model`` in messages (a config file's keys).
    """
    names = {k: (labels or {}).get(k, k) for k in ("--method", *FILE_OPTIONS)}
    methods = describe_methods()
    if method not in methods:
        raise ConfigError(f"unknown method {method!r} ({names['--method']}); choose one of {', '.join(methods)}")
    info = methods[method]
    given = {"--axis": axis_file, "--axes": axes_file, "--model": model_dir}
    needed = info.needs.split()[0]
    needs = info.needs.replace(needed, names[needed], 1)
    wrong = [names[opt] for opt, value in given.items() if value is not None and opt != needed]
    if wrong:
        raise ConfigError(f"{names['--method']} {method} takes {needs}, not {', '.join(wrong)}")
    if given[needed] is None:
        raise ConfigError(f"{names['--method']} {method} needs {needs}")
    config: dict[str, Any] = {FILE_OPTIONS[needed]: given[needed]}
    if info.drive == "ballscrew":
        config["axis_name"] = axis_name
    return make(method, **config)


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
