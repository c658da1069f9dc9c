"""AXES.toml: the three linear-motor axes of Eq. 2, in SI, cogging table included.

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

from drivesense.errors import ConfigError
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


def read_axes_file(path) -> ThreeAxisModel:
    """Read an AXES.toml.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    ThreeAxisModel

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


def write_axes_file(path, model: ThreeAxisModel, *, header: str | None = None) -> Path:
    """Write an AXES.toml atomically (temporary file, then rename).

    Parameters
    ----------
    path : str or Path
        Destination (its directory is created).
    model : ThreeAxisModel
        The axes.
    header : str, optional
        Extra comment line(s) at the top (e.g. where the values come from).

    Returns
    -------
    Path
    """
    from drivesense.io import write_text_file

    if not isinstance(model, ThreeAxisModel):
        raise ConfigError(f"write_axes_file needs a ThreeAxisModel, got {type(model).__name__}")
    lines = ["# drivesense linear-motor axes (SI units)"]
    if header:
        lines += [f"# {line}" for line in header.splitlines()]
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
