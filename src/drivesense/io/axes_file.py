"""AXES.toml: the machine model of ``estimate --method model``, in SI.

Two kinds.  The three linear-motor axes of Eq. 2 (``identify linear``),
cogging table included; or, with a top-level ``model = "controller"``, the
controller-rate model of any machine (``identify nc``, see
:mod:`drivesense.machine.controller_model`)::

    # drivesense controller-rate machine model (SI units)
    model = "controller"
    rate_hz = 50.0        # Hz, trace rate it was identified at
    window_s = 0.02       # s, logging window of the drive channels
    delay_s = 0.01        # s, delay of the drive channels behind the process force

    [x]
    K_m = -520.0          # N/A, force constant as logged (sign included)
    K_m_ci95 = 4.1        # N/A, 95 % half-width
    v_eps = 2e-05         # m/s, standstill noise of the logged velocity
    v_s = 0.005           # m/s, Stribeck velocity (0: none)
    period = 0.01         # m, period of the ripple terms (0: none)
    x_pre = 5e-06         # m, presliding distance (0: window-mean sign of v)
    hold_time = 3.0       # s, relaxation of the friction held at standstill (0: none)
    force_sign = 1        # -1: the force reference reads the load against the drive

    [x.terms]             # F = K_m I - sum(value * feature); name = [value, 95 % half-width]
    offset = [12.0, 3.0]  # N
    inertia_x = [610.0, 20.0]  # kg
    ...

    [x.dropped]           # terms the data did not determine, and why
    position = "left out by held-out error: ..."

    [regression]          # identify nc's regression (estimate --method regression), and per axis
    features = [...]      # the estimate --per-axis auto takes in [choice]: "model", "sliding" or
    [regression.weights]  # "regression"
    x = [...]
    [choice]
    x = "model"

The linear-motor kind::

::

    # drivesense linear-motor axes (SI units)
    [x]
    K_m = 180.0         # N/A, motor constant (catalogue)
    k = 200.0           # N/m, restoring constant
    s_r = 0.14          # m, rest point
    m = 160.0           # kg, the axis's own moving mass (X carries Z; Y carries X and Z)
    F_C = 38.0          # N, Coulomb friction
    F_br = 55.0         # N, breakaway friction
    v_s = 0.004         # m/s, Stribeck velocity
    sigma = 700.0       # N s/m, viscous friction
    delta = 2.0         # Stribeck shape factor
    pole_pitch = 0.023  # m
    x_pre = 1.5e-05     # m, presliding distance (optional; 0 or absent: the paper's sgn(v))
    cogging = [0.0, 2.3, ...]  # N, uniform grid over one pole pitch (periodic)
    undetermined = ["F_br", "v_s"]  # optional: what the identification could not determine (fallback values)

    [y]
    ...
    [z]
    ...
"""

from __future__ import annotations

from pathlib import Path

import json

from drivesense.errors import ConfigError
from drivesense.machine.controller_model import ControllerAxis, ControllerModel, term_unit
from drivesense.machine.regression_model import RegressionModel
from drivesense.machine.linear_motor import AXES, LinearMotorAxis, ThreeAxisModel

__all__ = ["read_axes_file", "write_axes_file"]

_COMMENTS = {"K_m": "N/A, motor constant (catalogue)", "k": "N/m, restoring constant", "s_r": "m, rest point",
             "m": "kg, the axis's own moving mass (X carries Z; Y carries X and Z)", "F_C": "N, Coulomb friction",
             "F_br": "N, breakaway friction", "v_s": "m/s, Stribeck velocity", "sigma": "N s/m, viscous friction",
             "delta": "Stribeck shape factor", "pole_pitch": "m",
             "x_pre": "m, presliding distance of the Dahl friction state (0: the paper's sgn(v))",
             "cogging": "N, uniform grid over one pole pitch (periodic)",
             "undetermined": "the air moves did not determine these: F_br = F_C, v_s without effect (Coulomb + "
                             "viscous friction)"}


def read_axes_file(path) -> ThreeAxisModel | ControllerModel:
    """Read an AXES.toml (either kind).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    ThreeAxisModel or ControllerModel
        The latter for a file with ``model = "controller"``.

    Raises
    ------
    ConfigError
        Unreadable TOML, unknown or missing tables, unknown or missing keys,
        bad values -- naming the file, the table and the key.
    FileNotFoundError
        The file does not exist.
    """
    from drivesense.io import read_toml

    path = Path(path)
    data = read_toml(path, "axes file")
    if "model" in data:
        return _read_controller(path, data)
    unknown = [k for k in data if k not in AXES]
    if unknown:
        raise ConfigError(f"axes file '{path}': unknown table(s) or key(s) {', '.join(unknown)} "
                          "(expected tables [x], [y], [z])")
    missing = [a for a in AXES if a not in data]
    if missing:
        raise ConfigError(f"axes file '{path}': missing table(s) {', '.join(f'[{a}]' for a in missing)}")
    axes = {}
    for a in AXES:
        if not isinstance(data[a], dict):
            raise ConfigError(f"axes file '{path}': '{a}' must be a table [{a}]")
        axes[a] = LinearMotorAxis.from_dict(data[a], source=f"axes file '{path}' [{a}]")
    return ThreeAxisModel(**axes)


def _read_controller(path: Path, data: dict) -> ControllerModel:
    if data["model"] != "controller":
        raise ConfigError(f"axes file '{path}': model = {data['model']!r} is unknown (expected \"controller\", "
                          "or no 'model' key for the linear-motor axes)")
    scalars = ("rate_hz", "window_s", "delay_s")
    missing = [k for k in scalars if k not in data]
    if missing:
        raise ConfigError(f"axes file '{path}': missing key(s) {', '.join(missing)}")
    for k in scalars:
        if isinstance(data[k], bool) or not isinstance(data[k], (int, float)):
            raise ConfigError(f"axes file '{path}': {k} must be a number, got {data[k]!r}")
    special = ("regression", "choice")
    tables = {k: v for k, v in data.items() if k not in (*scalars, "model", *special)}
    if not tables:
        raise ConfigError(f"axes file '{path}': no axis table (e.g. [x])")
    axes = {}
    for name, table in tables.items():
        if not isinstance(table, dict):
            raise ConfigError(f"axes file '{path}': unknown key {name!r} (axes are tables, e.g. [x])")
        axes[name] = ControllerAxis.from_dict(table, source=f"axes file '{path}' [{name}]")
    regression = (RegressionModel.from_dict(data["regression"], source=f"axes file '{path}' [regression]")
                  if "regression" in data else None)
    choice = data.get("choice", {})
    if not isinstance(choice, dict):
        raise ConfigError(f"axes file '{path}': 'choice' must be a table of axis = \"model\" | \"regression\"")
    try:
        return ControllerModel(axes=axes, window_s=float(data["window_s"]), delay_s=float(data["delay_s"]),
                               rate_hz=float(data["rate_hz"]), regression=regression, choice=dict(choice))
    except ConfigError as exc:
        raise ConfigError(f"axes file '{path}': {exc}") from None


def _controller_lines(model: ControllerModel) -> list[str]:
    lines = ["# drivesense controller-rate machine model (SI units)", 'model = "controller"',
             f"rate_hz = {model.rate_hz!r}  # Hz, trace rate it was identified at",
             f"window_s = {model.window_s!r}  # s, logging window of the drive channels (0: point samples)",
             f"delay_s = {model.delay_s!r}  # s, delay of the drive channels behind the process force (latency)"]
    notes = {"K_m": "N/A, force constant as logged (sign included)", "K_m_ci95": "N/A, 95 % half-width",
             "v_eps": "m/s, standstill noise of the logged velocity", "v_s": "m/s, Stribeck velocity (0: none)",
             "period": "m, period of the ripple terms (0: none)",
             "x_pre": "m, presliding distance of the friction direction's Dahl state (0: window-mean sign)",
             "hold_time": "s, relaxation time of the friction held at standstill (0: none)",
             "force_sign": "-1: the force reference reads the load against the drive (estimate follows it)"}
    for name, ax in model.axes.items():
        d = ax.to_dict()
        lines += ["", f"[{name}]"] + [f"{k} = {d[k] if k == 'force_sign' else float(d[k])!r}  # {note}"
                                      for k, note in notes.items()]
        lines += ["", f"[{name}.terms]  # F = K_m I - sum(value * feature); name = [value, 95 % half-width]"]
        lines += [f"{t.name} = [{t.value!r}, {t.ci95!r}]  # {term_unit(t.name)}" for t in ax.terms]
        if ax.dropped:
            lines += ["", f"[{name}.dropped]  # terms the data did not determine, and why"]
            lines += [f"{k} = {json.dumps(str(v), ensure_ascii=False)}" for k, v in ax.dropped.items()]
    if model.regression is not None:
        reg = model.regression
        lines += ["", "[regression]  # least squares of each force on these regressors, fitted on the same "
                      "calibration cuts (estimate --method regression)",
                  "features = [" + ", ".join(json.dumps(f) for f in reg.features) + "]",
                  "", "[regression.weights]  # N per unit of each regressor (SI)"]
        lines += [f"{a} = [" + ", ".join(repr(float(w)) for w in ws) + "]" for a, ws in reg.weights.items()]
    if model.choice:
        lines += ["", "[choice]  # per axis, the smaller held-out error (estimate --per-axis auto)"]
        lines += [f"{a} = {json.dumps(how)}" for a, how in model.choice.items()]
    return lines


def write_axes_file(path, model: ThreeAxisModel | ControllerModel, *, header: str | None = None) -> Path:
    """Write an AXES.toml atomically (temporary file, then rename).

    Parameters
    ----------
    path : str or Path
        Destination (its directory is created).
    model : ThreeAxisModel or ControllerModel
        The axes.
    header : str, optional
        Extra comment line(s) at the top (e.g. where the values come from).

    Returns
    -------
    Path
    """
    from drivesense.io import write_text_file

    comments = [f"# {line}" for line in header.splitlines()] if header else []
    if isinstance(model, ControllerModel):
        lines = _controller_lines(model)
        return write_text_file(path, "\n".join(lines[:1] + comments + lines[1:]) + "\n")
    if not isinstance(model, ThreeAxisModel):
        raise ConfigError(f"write_axes_file needs a ThreeAxisModel or ControllerModel, got {type(model).__name__}")
    lines = ["# drivesense linear-motor axes (SI units)"] + comments
    for a in AXES:
        lines += ["", f"[{a}]"]
        for key, value in model.axis(a).to_dict().items():
            if key == "cogging":
                text = "[" + ", ".join(repr(float(v)) for v in value) + "]"
            elif key == "undetermined":
                text = "[" + ", ".join(f'"{v}"' for v in value) + "]"
            else:
                text = repr(float(value))
            lines.append(f"{key} = {text}  # {_COMMENTS[key]}")
    return write_text_file(path, "\n".join(lines) + "\n")
