"""A machine model at the controller's trace rate, linear in its parameters (any drive type).

A controller trace (25-500 Hz: position, velocity, acceleration and current
of each axis, as an edge device logs them) shows an axis as a rigid body:
the structure's modes lie above the trace's Nyquist frequency.  Per axis

::

    F = K_m I - sum_j p_j phi_j(s, v, a)

with the process force ``F`` on the workpiece along +axis [N], the logged
current ``I`` [A], the force constant ``K_m`` *as logged* [N/A] (its sign is
the controller's convention: a drive that logs currents opposing the motion
has ``K_m < 0``; for a ball screw ``K_m = K_t 2 pi / lead``) and the terms

=================  ==================================  ===========
term               feature ``phi``                      ``p`` unit
=================  ==================================  ===========
``offset``         1 (weight of a vertical axis,        N
                   current-sensor offset)
``position``       s (cable chain, a spring)            N/m
``inertia_<b>``    acceleration of axis b (own axis:    kg
                   the moved mass, whatever the
                   kinematics; others: coupling)
``coulomb_pos``    max(sigma, 0)                        N
``coulomb_neg``    min(sigma, 0)  (asymmetric friction  N
                   of a vertical or counterweighted
                   axis)
``viscous``        v                                    N s/m
``stribeck``       sigma exp(-(v / v_s)^2)              N
``ripple<h>_sin``  sin(2 pi h s / period) w_h(v)        N
``ripple<h>_cos``  cos(2 pi h s / period) w_h(v)        N
=================  ==================================  ===========

The controller's filter and decimation.  A logged sample is the mean of the
drive's values over the logging window ``T`` (0: point samples), so the
features are the window means of the physics, not the physics of the window
means:

* the friction direction ``sigma`` is the mean of ``sgn(v)`` over the window:
  ``clip(v / max(|a| T / 2, v_eps), -1, 1)`` (a reversal inside the window
  averages the friction out in proportion to the time spent on each side);
  ``v_eps`` is the standstill noise level of the logged velocity.  An axis
  with a presliding distance ``x_pre > 0`` uses instead the Dahl state of its
  logged position (:func:`~drivesense.machine.presliding.presliding_direction`):
  a standing axis keeps the friction its last motion left in the guides and
  the screw nut -- on a ball-screw axis the largest force at standstill --
  and a force on a standing axis is credited with what its presliding
  spring holds.  The state is the model's only memory; streams carry it;
* a position-periodic term (ball-screw torque ripple and lead error at the
  screw lead, linear-motor cogging at the pole pitch) travels ``v T`` in the
  window: its mean is the term at the logged position times
  ``w_h(v) = sinc(h v T / period)``.

Everything else is linear in the logged values, so it commutes with the
window.  Streaming equals batch: the presliding state is carried.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from drivesense.errors import ConfigError, MissingChannelError
from drivesense.machine.presliding import carried_presliding_direction
from drivesense.machine.regression_model import RegressionModel

__all__ = ["ControllerTerm", "ControllerAxis", "ControllerModel", "TERM_UNITS", "STANDING_SPEED", "CHOICES", "term_unit",
           "friction_direction", "axis_direction", "feature_column", "features_needed"]

#: Speed below which an axis counts as standing for a ``"sliding"`` choice [m/s].
STANDING_SPEED = 1e-3
#: What ``--per-axis auto`` can take on an axis: the model, the regression, or the model while the axis slides and
#: the regression while it stands (its guides hold the force its current cannot see).
CHOICES = ("model", "sliding", "regression")
#: Unit of each term's coefficient, by name prefix.
TERM_UNITS = {"offset": "N", "position": "N/m", "inertia": "kg", "coulomb": "N", "viscous": "N s/m",
              "stribeck": "N", "ripple": "N"}


def term_unit(name: str) -> str:
    """Unit of the coefficient of term ``name`` (see the module table).

    Parameters
    ----------
    name : str
        Term name, e.g. ``"inertia_x"``, ``"ripple2_sin"``.
    """
    for prefix, unit in TERM_UNITS.items():
        if name.startswith(prefix):
            return unit
    raise ConfigError(f"unknown controller-model term {name!r}; known kinds: {', '.join(TERM_UNITS)}")


def friction_direction(velocity: np.ndarray, acceleration: np.ndarray, window_s: float, v_eps: float) -> np.ndarray:
    """Window mean of ``sgn(v)`` in [-1, 1]: ``clip(v / max(|a| T / 2, v_eps), -1, 1)``.

    Parameters
    ----------
    velocity : ndarray
        Logged velocity [m/s] (the window mean).
    acceleration : ndarray
        Logged acceleration [m/s^2].
    window_s : float
        Logging window ``T`` [s] (0: point samples).
    v_eps : float
        Standstill noise level of the logged velocity [m/s] (> 0).
    """
    scale = np.maximum(np.abs(acceleration) * (0.5 * window_s), v_eps)
    return np.clip(velocity / scale, -1.0, 1.0)


def axis_direction(axis: str, arrays: Mapping[str, np.ndarray], *, window_s: float, v_eps: float,
                   x_pre: float = 0.0, hold_decay: float = 1.0, state: dict | None = None) -> np.ndarray:
    """Friction direction of axis ``axis`` in [-1, 1]: the Dahl state (``x_pre > 0``) or :func:`friction_direction`.

    Parameters
    ----------
    axis : str
        Axis letter.
    arrays : mapping of str to ndarray
        Logged channels in SI: ``{axis}_position`` [m] (Dahl), ``{axis}_velocity`` [m/s], ``{axis}_acceleration`` [m/s^2].
    window_s : float
        Logging window [s].
    v_eps : float
        Standstill velocity noise [m/s].
    x_pre : float
        Presliding distance [m] (0: the window-mean sign).
    hold_decay : float
        Per-sample relaxation factor of the presliding state [-] (1: none).
    state : dict, optional
        Presliding state carried between stream chunks (updated in place).
    """
    if x_pre > 0:
        return carried_presliding_direction(np.asarray(arrays[f"{axis}_position"], dtype=float), x_pre, state, axis,
                                            hold_decay)
    return friction_direction(np.asarray(arrays[f"{axis}_velocity"], dtype=float),
                              np.asarray(arrays[f"{axis}_acceleration"], dtype=float), window_s, v_eps)


def _ripple_parts(name: str) -> tuple[int, str]:
    body = name[len("ripple"):]
    harmonic, _, part = body.partition("_")
    if not harmonic.isdigit() or part not in ("sin", "cos"):
        raise ConfigError(f"ripple term {name!r}: expected ripple<h>_sin or ripple<h>_cos")
    return int(harmonic), part


def features_needed(axis: str, names: Sequence[str], x_pre: float = 0.0) -> tuple[str, ...]:
    """Channels the terms ``names`` of axis ``axis`` read (its current and velocity always).

    Parameters
    ----------
    axis : str
        Axis letter.
    names : sequence of str
        Term names.
    x_pre : float
        Presliding distance [m] (> 0: the position is read for the Dahl state).
    """
    need = [f"{axis}_current", f"{axis}_velocity", f"{axis}_acceleration"] + [f"{axis}_position"] * (x_pre > 0)
    for n in names:
        if n == "position" or n.startswith("ripple"):
            need.append(f"{axis}_position")
        elif n.startswith("inertia_"):
            need.append(f"{n[len('inertia_'):]}_acceleration")
    return tuple(dict.fromkeys(need))


def feature_column(name: str, axis: str, arrays: Mapping[str, np.ndarray], *, window_s: float, v_eps: float,
                   v_s: float = 0.0, period: float = 0.0, direction: np.ndarray | None = None) -> np.ndarray:
    """The feature ``phi`` of term ``name`` of axis ``axis`` (module table), sample by sample.

    Parameters
    ----------
    name : str
        Term name.
    axis : str
        Axis letter.
    arrays : mapping of str to ndarray
        Logged channels in SI (``{axis}_velocity`` [m/s], ...).
    window_s : float
        Logging window [s].
    v_eps : float
        Standstill velocity noise [m/s].
    v_s : float
        Stribeck velocity [m/s] (``stribeck`` only).
    period : float
        Period of the position-periodic terms [m] (``ripple`` only).
    direction : ndarray, optional
        Precomputed :func:`friction_direction` of the axis [-].
    """
    v = arrays[f"{axis}_velocity"]
    if name == "offset":
        return np.ones_like(v)
    if name == "position":
        return np.asarray(arrays[f"{axis}_position"], dtype=float)
    if name.startswith("inertia_"):
        return np.asarray(arrays[f"{name[len('inertia_'):]}_acceleration"], dtype=float)
    if name == "viscous":
        return np.asarray(v, dtype=float)
    if direction is None and (name.startswith("coulomb") or name == "stribeck"):
        direction = friction_direction(v, arrays[f"{axis}_acceleration"], window_s, v_eps)
    if name == "coulomb_pos":
        return np.maximum(direction, 0.0)
    if name == "coulomb_neg":
        return np.minimum(direction, 0.0)
    if name == "stribeck":
        if not v_s > 0:
            raise ConfigError("the stribeck term needs a Stribeck velocity v_s > 0 [m/s]")
        return direction * np.exp(-(v / v_s) ** 2)
    if name.startswith("ripple"):
        if not period > 0:
            raise ConfigError("the ripple terms need a period > 0 [m]")
        h, part = _ripple_parts(name)
        phase = 2.0 * math.pi * h * np.asarray(arrays[f"{axis}_position"], dtype=float) / period
        weight = np.sinc(h * v * window_s / period)
        return (np.sin(phase) if part == "sin" else np.cos(phase)) * weight
    term_unit(name)     # raises for an unknown kind
    raise ConfigError(f"unknown controller-model term {name!r}")


@dataclass(frozen=True)
class ControllerTerm:
    """One identified term: its coefficient ``p`` and the 95 % confidence half-width.

    Parameters
    ----------
    name : str
        Term name (module table).
    value : float
        Coefficient ``p`` [unit of the term, :data:`TERM_UNITS`].
    ci95 : float
        Half-width of its 95 % confidence interval [same unit].
    """

    name: str
    value: float
    ci95: float = 0.0

    def __post_init__(self) -> None:
        term_unit(self.name)
        if not (math.isfinite(self.value) and math.isfinite(self.ci95) and self.ci95 >= 0):
            raise ConfigError(f"term {self.name!r}: value and ci95 must be finite (ci95 >= 0), "
                              f"got {self.value!r}, {self.ci95!r}")

    @property
    def unit(self) -> str:
        """Unit of the coefficient."""
        return term_unit(self.name)


@dataclass(frozen=True, eq=False)
class ControllerAxis:
    """One axis of the controller-rate model.

    Parameters
    ----------
    K_m : float
        Force constant as logged, sign included [N/A] (nonzero).
    terms : tuple of ControllerTerm
        The kept terms.
    v_eps : float
        Standstill noise of the logged velocity, the friction direction's ramp [m/s].
    K_m_ci95 : float
        95 % half-width of ``K_m`` [N/A] (0 when it was given, not identified).
    v_s : float
        Stribeck velocity [m/s] (0: no ``stribeck`` term).
    period : float
        Period of the ``ripple`` terms [m] (0: none).
    x_pre : float
        Presliding distance of the friction direction's Dahl state [m] (0: the window-mean sign).
    hold_time : float
        Relaxation time of the friction held at standstill [s] (0: it does not relax).
    dropped : dict of str to str
        Candidate terms the data did not determine, with the reason.
    force_sign : int
        +1, or -1 where the force reference of the identification reads the
        process load against the drive (a dynamometer turned against the
        machine's axis): the estimate is ``force_sign (K_m I - sum p phi)``,
        so it follows the reference while ``K_m`` and the terms stay the
        drive's (masses and friction >= 0).
    """

    K_m: float
    terms: tuple[ControllerTerm, ...]
    v_eps: float
    K_m_ci95: float = 0.0
    v_s: float = 0.0
    period: float = 0.0
    x_pre: float = 0.0
    hold_time: float = 0.0
    dropped: dict = field(default_factory=dict)
    force_sign: int = 1

    def __post_init__(self) -> None:
        if self.force_sign not in (1, -1) or isinstance(self.force_sign, bool):
            raise ConfigError(f"force_sign must be 1 or -1, got {self.force_sign!r}")
        if not (math.isfinite(self.K_m) and self.K_m != 0):
            raise ConfigError(f"K_m must be a finite nonzero force constant [N/A], got {self.K_m!r}")
        if not (math.isfinite(self.v_eps) and self.v_eps > 0):
            raise ConfigError(f"v_eps must be > 0 [m/s], got {self.v_eps!r}")
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names):
            raise ConfigError(f"duplicate terms in {names}")
        if "stribeck" in names and not self.v_s > 0:
            raise ConfigError("a stribeck term needs v_s > 0 [m/s]")
        if any(n.startswith("ripple") for n in names) and not self.period > 0:
            raise ConfigError("ripple terms need a period > 0 [m]")
        if not (math.isfinite(self.x_pre) and self.x_pre >= 0):
            raise ConfigError(f"x_pre must be a distance >= 0 [m], got {self.x_pre!r}")
        if not (math.isfinite(self.hold_time) and self.hold_time >= 0):
            raise ConfigError(f"hold_time must be a time >= 0 [s], got {self.hold_time!r}")

    def hold_decay(self, fs: float) -> float:
        """Per-sample factor [-] of the held friction's relaxation at rate ``fs`` [Hz] (1: none).

        Parameters
        ----------
        fs : float
            Trace rate [Hz].
        """
        return math.exp(-1.0 / (fs * self.hold_time)) if self.hold_time > 0 else 1.0

    def term(self, name: str) -> ControllerTerm | None:
        """The kept term ``name``, or None.

        Parameters
        ----------
        name : str
            Term name.
        """
        return next((t for t in self.terms if t.name == name), None)

    def value(self, name: str) -> float:
        """Coefficient of term ``name`` [its unit], 0 when the term was not kept.

        Parameters
        ----------
        name : str
            Term name.
        """
        t = self.term(name)
        return t.value if t is not None else 0.0

    def to_dict(self) -> dict:
        """Plain types (SI): ``K_m``, ``K_m_ci95``, ``v_eps``, ``v_s``, ``period``, ``x_pre``, ``hold_time``,
        ``terms``, ``dropped``."""
        return {"K_m": float(self.K_m), "K_m_ci95": float(self.K_m_ci95), "v_eps": float(self.v_eps),
                "v_s": float(self.v_s), "period": float(self.period), "x_pre": float(self.x_pre),
                "hold_time": float(self.hold_time), "force_sign": int(self.force_sign),
                "terms": {t.name: [float(t.value), float(t.ci95)] for t in self.terms},
                "dropped": dict(self.dropped)}

    @classmethod
    def from_dict(cls, values: Mapping, *, source: str = "controller axis") -> "ControllerAxis":
        """Inverse of :meth:`to_dict`, naming ``source`` in every error.

        Parameters
        ----------
        values : mapping
            As :meth:`to_dict` writes it.
        source : str
            Where the values come from (file and table).
        """
        if not isinstance(values, Mapping):
            raise ConfigError(f"{source}: expected a table, got {type(values).__name__}")
        known = {"K_m", "K_m_ci95", "v_eps", "v_s", "period", "x_pre", "hold_time", "terms", "dropped", "force_sign"}
        unknown = sorted(set(values) - known)
        missing = [k for k in ("K_m", "v_eps", "terms") if k not in values]
        if unknown or missing:
            raise ConfigError(f"{source}: " + "; ".join(
                ([f"unknown key(s) {', '.join(unknown)}"] if unknown else [])
                + ([f"missing key(s) {', '.join(missing)}"] if missing else [])))
        terms_in = values["terms"]
        if not isinstance(terms_in, Mapping):
            raise ConfigError(f"{source}: 'terms' must be a table of name = [value, ci95]")
        terms = []
        for name, pair in terms_in.items():
            if not (isinstance(pair, (list, tuple)) and len(pair) == 2
                    and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in pair)):
                raise ConfigError(f"{source}: term {name!r} must be [value, ci95] (numbers), got {pair!r}")
            try:
                terms.append(ControllerTerm(str(name), float(pair[0]), float(pair[1])))
            except ConfigError as exc:
                raise ConfigError(f"{source}: {exc}") from None
        try:
            return cls(K_m=float(values["K_m"]), terms=tuple(terms), v_eps=float(values["v_eps"]),
                       K_m_ci95=float(values.get("K_m_ci95", 0.0)), v_s=float(values.get("v_s", 0.0)),
                       period=float(values.get("period", 0.0)), x_pre=float(values.get("x_pre", 0.0)),
                       hold_time=float(values.get("hold_time", 0.0)),
                       dropped=dict(values.get("dropped", {})), force_sign=_sign(values.get("force_sign", 1), source))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: {exc}") from None


def _sign(value, source: str) -> int:
    if isinstance(value, bool) or value not in (1, -1):
        raise ConfigError(f"{source}: force_sign must be 1 or -1, got {value!r}")
    return int(value)


@dataclass(frozen=True, eq=False)
class ControllerModel:
    """The axes of a machine at its controller's trace rate (see the module docstring).

    Parameters
    ----------
    axes : dict of str to ControllerAxis
        Model per axis letter.
    window_s : float
        Logging window the drive channels are means over [s] (0: point samples).
    delay_s : float
        Delay of the logged drive channels behind the process force [s]
        (the estimate's latency).
    rate_hz : float
        Trace rate the model was identified at [Hz].
    regression : RegressionModel, optional
        The regression fitted on the same calibration cuts (``identify nc``'s
        built-in check; ``estimate --method regression`` and ``--per-axis auto``).
    choice : dict of str to str
        Per axis ``"model"``, ``"sliding"`` (the model while the axis moves
        faster than :data:`STANDING_SPEED`, the regression while it stands) or
        ``"regression"``: the smallest held-out error (what ``--per-axis auto``
        takes; empty: the model everywhere).
    """

    axes: dict
    window_s: float
    delay_s: float
    rate_hz: float
    regression: RegressionModel | None = None
    choice: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.axes or not all(isinstance(a, ControllerAxis) for a in self.axes.values()):
            raise ConfigError("a ControllerModel needs at least one ControllerAxis")
        for key, val, low in (("window_s", self.window_s, 0.0), ("delay_s", self.delay_s, 0.0),
                              ("rate_hz", self.rate_hz, 1e-9)):
            if not (math.isfinite(val) and val >= low):
                raise ConfigError(f"ControllerModel {key} must be >= {low:g}, got {val!r}")
        for a, how in self.choice.items():
            if how not in CHOICES or (how != "regression" and a not in self.axes):
                raise ConfigError(f"ControllerModel choice {a} = {how!r}: expected 'model' or 'sliding' (for an axis "
                                  "of the model) or 'regression'")
            if how != "model" and (self.regression is None or a not in self.regression.weights):
                raise ConfigError(f"ControllerModel choice {a} = {how!r} but the model holds no regression "
                                  f"of axis {a}")

    def axis(self, name: str) -> ControllerAxis:
        """The model of axis ``name``.

        Parameters
        ----------
        name : str
            Axis letter.
        """
        if name not in self.axes:
            raise ConfigError(f"the controller model has no axis {name!r} (it has {', '.join(self.axes)})")
        return self.axes[name]

    def input_channels(self, axes: Sequence[str] | None = None) -> tuple[str, ...]:
        """Channels the force of ``axes`` (default: all) needs.

        Parameters
        ----------
        axes : sequence of str, optional
            Axis letters.
        """
        out: list[str] = []
        for a in axes or tuple(self.axes):
            out.extend(features_needed(a, [t.name for t in self.axis(a).terms], self.axis(a).x_pre))
        return tuple(dict.fromkeys(out))

    def resisting_force(self, name: str, arrays: Mapping[str, np.ndarray], state: dict | None = None) -> np.ndarray:
        """``sum_j p_j phi_j``: what the drive spends on the machine itself [N] (no process force).

        Parameters
        ----------
        name : str
            Axis letter.
        arrays : mapping of str to ndarray
            Logged channels in SI (current [A], position [m], velocity [m/s], acceleration [m/s^2]).
        state : dict, optional
            Presliding state carried between stream chunks (updated in place); None: a fresh start.
        """
        ax = self.axis(name)
        v = np.asarray(arrays[f"{name}_velocity"], dtype=float)
        if ax.x_pre > 0 and v.size and (state is None or name not in state) and f"{name}_current" in arrays:
            state = self._primed(name, arrays, {} if state is None else state)
        direction = axis_direction(name, arrays, window_s=self.window_s, v_eps=ax.v_eps, x_pre=ax.x_pre,
                                   hold_decay=ax.hold_decay(self.rate_hz), state=state)
        total = np.zeros_like(v)
        for t in ax.terms:
            total += t.value * feature_column(t.name, name, arrays, window_s=self.window_s, v_eps=ax.v_eps,
                                              v_s=ax.v_s, period=ax.period, direction=direction)
        return total

    def _primed(self, name: str, arrays: Mapping[str, np.ndarray], state: dict) -> dict:
        """The presliding state before the first sample, from that sample: the friction its current holds.

        A trace (or a stream) starts with the axis holding an unknown friction
        from its last move; starting the state at 0 would read that friction as
        process force until the axis travels a few ``x_pre``.  Assuming no process
        force on the first sample, ``d0 = clip((K_m I - other terms) / friction level, -1, 1)``.
        """
        ax = self.axis(name)
        first = {k: np.asarray(v)[:1] for k, v in arrays.items()}
        held = ax.K_m * float(first[f"{name}_current"][0])
        friction_terms = ("coulomb_pos", "coulomb_neg", "stribeck")
        for t in ax.terms:
            if t.name not in friction_terms:
                held -= t.value * float(feature_column(t.name, name, first, window_s=self.window_s, v_eps=ax.v_eps,
                                                       v_s=ax.v_s, period=ax.period)[0])
        level = ax.value("coulomb_pos" if held >= 0 else "coulomb_neg") + ax.value("stribeck")
        d0 = float(np.clip(held / level, -1.0, 1.0)) if level > 0 else 0.0
        state[name] = (float(first[f"{name}_position"][0]), d0)
        return state

    def process_force(self, name: str, arrays: Mapping[str, np.ndarray], state: dict | None = None) -> np.ndarray:
        """Process force on the workpiece along +axis [N]: ``K_m I - sum_j p_j phi_j``.

        Parameters
        ----------
        name : str
            Axis letter.
        arrays : mapping of str to ndarray
            Logged channels (:meth:`input_channels`) in SI: current [A], position [m], velocity [m/s],
            acceleration [m/s^2].
        state : dict, optional
            Presliding state carried between stream chunks (updated in place); None: a fresh start.
        """
        ax = self.axis(name)
        missing = [c for c in features_needed(name, [t.name for t in ax.terms], ax.x_pre) if c not in arrays]
        if missing:
            raise MissingChannelError(f"axis {name}: the controller model needs channel(s) {', '.join(missing)}")
        current = np.asarray(arrays[f"{name}_current"], dtype=float)
        load = ax.K_m * current - self.resisting_force(name, arrays, state)
        return load if ax.force_sign == 1 else -load

    def to_dict(self) -> dict:
        """Plain types (SI): ``window_s``, ``delay_s``, ``rate_hz``, one table per axis, and the regression
        and per-axis choice where there are."""
        return {"window_s": float(self.window_s), "delay_s": float(self.delay_s), "rate_hz": float(self.rate_hz),
                "axes": {a: ax.to_dict() for a, ax in self.axes.items()},
                **({"regression": self.regression.to_dict()} if self.regression is not None else {}),
                **({"choice": dict(self.choice)} if self.choice else {})}
