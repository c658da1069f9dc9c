"""AXIS.toml: a ball-screw axis and its signal chain, in SI, keys as in the first paper.

::

    [axis]
    J_r = 5.18e-05     # kg m^2
    M_t = 6.55         # kg
    C_t = 821.0        # N s/m
    C_k = 1760.0       # N s/m
    D_r = 0.0065       # N m s/rad
    K_r = 40500000.0   # N/m
    lead = 0.005       # m/rev
    K_t = 0.45         # N m/A

    [signal]
    T_a = 0.0002       # s
    T_b = 0.0002       # s
    T_comp = 0.0004    # s
    omega_cc = 5000.0  # rad/s
    lpf_hz = 1000.0    # Hz
    lpf_order = 4
"""

from __future__ import annotations

from pathlib import Path

from drivesense.errors import ConfigError
from drivesense.machine.signal_chain import SignalParams
from drivesense.machine.ballscrew import BallScrewAxis

__all__ = ["read_axis_file", "write_axis_file"]

_UNITS = {"J_r": "kg m^2", "M_t": "kg", "C_t": "N s/m", "C_k": "N s/m", "D_r": "N m s/rad", "K_r": "N/m",
          "lead": "m/rev", "K_t": "N m/A", "T_a": "s", "T_b": "s", "T_comp": "s", "omega_cc": "rad/s",
          "lpf_hz": "Hz", "lpf_order": "",
          "encoder_signal_periods": "signal periods per motor revolution, 0: not known"}


def read_axis_file(path) -> tuple[BallScrewAxis, SignalParams]:
    """Read an AXIS.toml.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    axis : BallScrewAxis
    signal : SignalParams
        Defaults (the first paper's values) for a missing ``[signal]`` table
        or missing keys in it.

    Raises
    ------
    ConfigError
        Unreadable TOML, missing ``[axis]``, missing/unknown keys or bad values,
        naming the file and the key.
    FileNotFoundError
        The file does not exist.
    """
    from drivesense.io import read_toml

    path = Path(path)
    data = read_toml(path, "axis file")
    unknown = [k for k in data if k not in ("axis", "signal")]
    if unknown:
        raise ConfigError(f"axis file '{path}': unknown table(s) {', '.join(unknown)} (expected [axis], [signal])")
    if "axis" not in data or not isinstance(data["axis"], dict):
        raise ConfigError(f"axis file '{path}': missing table [axis] with J_r, M_t, C_t, C_k, D_r, K_r, lead, K_t")
    axis = BallScrewAxis.from_dict(data["axis"], source=f"axis file '{path}' [axis]")
    sig = data.get("signal", {})
    if not isinstance(sig, dict):
        raise ConfigError(f"axis file '{path}': [signal] must be a table")
    signal = SignalParams.from_dict(sig, source=f"axis file '{path}' [signal]")
    return axis, signal


def write_axis_file(path, axis: BallScrewAxis, signal: SignalParams | None = None) -> Path:
    """Write an AXIS.toml atomically (temporary file, then rename).

    Parameters
    ----------
    path : str or Path
        Destination.
    axis : BallScrewAxis
        Axis parameters.
    signal : SignalParams, optional
        Signal chain (default: the paper's values).

    Returns
    -------
    Path
    """
    from drivesense.io import write_text_file

    signal = signal or SignalParams()
    lines = ["# drivesense axis file (SI units)", "[axis]"]
    for k, v in axis.to_dict().items():
        lines.append(f"{k} = {v!r}  # {_UNITS[k]}")
    lines += ["", "[signal]"]
    for k, v in signal.to_dict().items():
        lines.append(f"{k} = {v!r}" + (f"  # {_UNITS[k]}" if _UNITS[k] else ""))
    return write_text_file(path, "\n".join(lines) + "\n")
