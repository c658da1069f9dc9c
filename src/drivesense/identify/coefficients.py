"""Tangential cutting coefficients K_tc and K_te from average spindle power (second paper, Sec. 2, Fig. 4).

For each calibration cut the average cutting power (spindle power in the cut minus the air-cut
power just before it) gives the average tangential force per axial depth ``F_t/a = P / A_c``
(Eq. 5); a straight line through ``(h_avg, F_t/a)`` over cuts at several feeds and immersions has
slope K_tc [N/m^2] and intercept K_te [N/m] (Eq. 1). The fit reports standard errors and the
correlation of the two estimates. For ordinary least squares that correlation is
``-mean(h) / rms(h)``: it depends only on the spread of h_avg, not on the noise, and when the cuts
span little h_avg it tends to -1 — a small change of slope is then offset by a large change of
intercept (the paper's "see-saw" effect). :class:`SeeSawWarning` is issued in that case.

Calibration cuts are exchanged as CSV tables (one row per cut, ``name [unit]`` headers, units
converted to SI on reading); see :func:`read_cut_table`.
"""

from __future__ import annotations

import csv as _csv
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivesense import units as _units
from drivesense.errors import ConfigError, IdentificationError, InvalidSignalError, UnitError
from drivesense.io.csv import read_csv_text
from drivesense.machine.cutting_power import CutConditions, CutTable, finite_vector, force_per_depth

__all__ = ["SeeSawWarning", "TangentialFit", "CutTable", "fit_tangential_coefficients", "calibrate_from_power",
           "average_power", "read_cut_table", "fit_cut_table"]

_HEADER_RE = re.compile(r"^(.*?)\s*\[([^\[\]]*)\]\s*$")


class SeeSawWarning(UserWarning):
    """The calibration cuts span too little h_avg to separate K_tc from K_te."""


# ---------------------------------------------------------------------------- the fit
@dataclass(frozen=True, eq=False)
class TangentialFit:
    """A straight-line fit ``F_t/a = K_tc h_avg + K_te`` with its uncertainty.

    Attributes
    ----------
    Ktc, Kte : float
        Cutting coefficient [N/m^2] and edge coefficient [N/m].
    Ktc_se, Kte_se : float
        Standard errors [N/m^2], [N/m] (0 for an exact fit; NaN with only two cuts).
    correlation : float
        Correlation of the two estimates, in [-1, 1] (about -1: see-saw).
    r2 : float
        Coefficient of determination of the line [-].
    rmse : float
        Residual standard deviation of F_t/a [N/m].
    h_avg, force_per_depth : ndarray
        The data: average chip thickness [m] and F_t/a [N/m] per cut.
    see_saw : bool
        True when the cuts span too little h_avg (``|correlation| > max_correlation``).
    warnings : tuple of str
        Human-readable warnings (see-saw, poorly determined coefficient).
    """

    Ktc: float
    Kte: float
    Ktc_se: float
    Kte_se: float
    correlation: float
    r2: float
    rmse: float
    h_avg: np.ndarray = field(repr=False)
    force_per_depth: np.ndarray = field(repr=False)
    see_saw: bool = False
    warnings: tuple = ()

    @property
    def n(self) -> int:
        """Number of cuts."""
        return int(self.h_avg.size)

    def predict(self, h_avg):
        """F_t/a [N/m] the line gives at chip thickness `h_avg` [m].

        Parameters
        ----------
        h_avg : float or array_like
            Average chip thickness [m].

        Returns
        -------
        float or ndarray
        """
        h = np.asarray(h_avg, dtype=float)
        out = self.Ktc * h + self.Kte
        return float(out) if out.ndim == 0 else out

    def predict_power(self, cuts):
        """Average cutting power ``K_tc Q + K_te A_c`` [W] of cut(s) (Eq. 2).

        Parameters
        ----------
        cuts : CutConditions or sequence of CutConditions
            The cut(s).

        Returns
        -------
        float or ndarray
        """
        from drivesense.machine.cutting_power import cutting_power

        return cutting_power(self.Ktc, self.Kte, cuts)

    def to_dict(self) -> dict:
        """JSON-ready summary: SI values plus N/mm^2 and N/mm for reading.

        Returns
        -------
        dict
        """
        num = (lambda x: None if not math.isfinite(x) else float(x))  # noqa: E731
        return {"Ktc_n_m2": self.Ktc, "Kte_n_m": self.Kte, "Ktc_se_n_m2": num(self.Ktc_se),
                "Kte_se_n_m": num(self.Kte_se), "Ktc_n_mm2": self.Ktc * 1e-6, "Kte_n_mm": self.Kte * 1e-3,
                "correlation": num(self.correlation), "r2": num(self.r2), "rmse_n_m": num(self.rmse),
                "cuts": self.n, "h_avg_range_m": [float(self.h_avg.min()), float(self.h_avg.max())],
                "see_saw": self.see_saw, "warnings": list(self.warnings)}


def fit_tangential_coefficients(h_avg, force_per_depth, *, weights=None, max_correlation: float = 0.99,
                                max_relative_se: float = 0.25, warn: bool = True) -> TangentialFit:
    """Fit ``F_t/a = K_tc h_avg + K_te`` by (weighted) least squares (the paper's Fig. 4).

    Parameters
    ----------
    h_avg : array_like
        Average chip thickness of each cut [m], >= 0, at least two distinct values.
    force_per_depth : array_like
        Average tangential force per axial depth of each cut [N/m] (Eq. 5).
    weights : array_like, optional
        Relative weights [-] (e.g. proportional to 1 / variance); default equal.
    max_correlation : float
        See-saw threshold on ``|corr(K_tc, K_te)|`` [-] (default 0.99, i.e. the h_avg values vary by
        less than about 14 % of their mean).
    max_relative_se : float
        A coefficient whose standard error exceeds this fraction of its value [-] is reported as
        poorly determined.
    warn : bool
        Issue :class:`SeeSawWarning` (Python warning) as well as filling ``warnings``.

    Returns
    -------
    TangentialFit

    Raises
    ------
    IdentificationError
        Fewer than two cuts, or all at the same h_avg (K_tc and K_te cannot be separated).
    InvalidSignalError
        Non-finite or mismatched inputs, negative h_avg or weights.
    """
    h = finite_vector(h_avg, "h_avg")
    y = finite_vector(force_per_depth, "force_per_depth")
    if h.size != y.size:
        raise InvalidSignalError(f"'h_avg' has {h.size} values, 'force_per_depth' {y.size}")
    if h.size == 0:
        raise IdentificationError("no calibration cuts: K_tc and K_te need cuts at two or more chip thicknesses")
    if np.any(h < 0):
        raise InvalidSignalError(f"'h_avg' must be >= 0, got min {h.min()!r} m")
    w = np.ones_like(h) if weights is None else finite_vector(weights, "weights")
    if w.size != h.size or np.any(w <= 0):
        raise InvalidSignalError("'weights' must be positive, one per cut")
    if h.size < 2 or np.ptp(h) <= 1e-9 * max(h.max(), 1e-300):
        raise IdentificationError(f"K_tc and K_te: the {h.size} cut(s) all have h_avg = {h[0] * 1e3:.4g} mm; "
                                  "calibrate at two or more chip thicknesses (feeds or immersions)")
    sw = np.sqrt(w)
    X = np.column_stack([h, np.ones_like(h)]) * sw[:, None]
    (ktc, kte), *_ = np.linalg.lstsq(X, y * sw, rcond=None)
    inv = np.linalg.inv(X.T @ X)
    resid = y - (ktc * h + kte)
    dof = h.size - 2
    if dof > 0:
        s2 = float(np.sum(w * resid ** 2) / dof)
        se_tc, se_te = math.sqrt(s2 * inv[0, 0]), math.sqrt(s2 * inv[1, 1])
        rmse = math.sqrt(float(np.mean(resid ** 2)) * h.size / dof)
    else:
        se_tc = se_te = rmse = float("nan")
    corr = float(inv[0, 1] / math.sqrt(inv[0, 0] * inv[1, 1]))
    ss = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum(resid ** 2)) / ss if ss > 0 else float("nan")
    notes = []
    see_saw = abs(corr) > max_correlation
    if see_saw:
        notes.append(f"see-saw: the {h.size} cuts span h_avg {h.min() * 1e3:.4g}-{h.max() * 1e3:.4g} mm only "
                     f"(std {np.std(h) / np.mean(h) * 100:.0f} % of the mean), so K_tc and K_te are correlated at "
                     f"{corr:+.3f}: a small change of slope is offset by a large change of intercept; "
                     "spread the feeds or immersions (h_avg varying by a factor of 2 or more)")
    for name, value, se, unit, scale in (("K_tc", ktc, se_tc, "N/mm^2", 1e-6), ("K_te", kte, se_te, "N/mm", 1e-3)):
        if math.isfinite(se) and se > max_relative_se * abs(value):
            notes.append(f"{name} = {value * scale:.4g} +/- {se * scale:.2g} {unit} is poorly determined "
                         f"(standard error above {max_relative_se * 100:.0f} % of the value)")
    if warn:
        for note in notes:
            warnings.warn(note, SeeSawWarning, stacklevel=2)
    return TangentialFit(float(ktc), float(kte), se_tc, se_te, corr, r2, rmse, h.copy(), y.copy(),
                         see_saw, tuple(notes))


def calibrate_from_power(cuts, cutting_power, *, warn: bool = True, runout=None, **kw) -> TangentialFit:
    """K_tc and K_te from the average cutting power of calibration cuts (Eq. 4, 5 and 1).

    Parameters
    ----------
    cuts : sequence of CutConditions
        The calibration cuts.
    cutting_power : array_like
        Average cutting power of each cut [W]: spindle power in the cut minus the air-cut power.
    warn : bool
        Issue :class:`SeeSawWarning` when the cuts cannot separate the coefficients.
    runout : ToolRunout, optional
        The tool's measured runout (:mod:`drivesense.machine.tool_runout`): the chip thickness
        and force per depth of each cut then come from the mechanistic model with that runout
        (flutes that lose contact no longer rub) instead of Eq. 4-5.
    **kw
        Passed to :func:`fit_tangential_coefficients` (``weights``, ``max_correlation``...).

    Returns
    -------
    TangentialFit
    """
    cuts = list(cuts)
    if not cuts:
        raise IdentificationError("no calibration cuts: K_tc and K_te need cuts at two or more chip thicknesses")
    if runout is not None:
        from drivesense.machine.tool_runout import power_bases

        b_c, b_e = power_bases(cuts, runout)
        return fit_tangential_coefficients(b_c / b_e, finite_vector(cutting_power, "cutting_power") / b_e, warn=warn, **kw)
    h = np.array([c.average_chip_thickness for c in cuts])
    return fit_tangential_coefficients(h, force_per_depth(cutting_power, cuts), warn=warn, **kw)


def average_power(recording, start: float, end: float, channel: str = "spindle_power") -> float:
    """Mean of a power channel over a time window (a cut, or the air cut before it).

    Parameters
    ----------
    recording : Recording
        Trace with the power channel [W].
    start, end : float
        Window [s] on the recording's time axis, ``start < end``.
    channel : str
        Channel name (default ``spindle_power``).

    Returns
    -------
    float
        Mean power [W].

    Raises
    ------
    ConfigError
        An empty or reversed window.
    """
    if not end > start:
        raise ConfigError(f"power window [{start!r}, {end!r}] s: end must be after start")
    t = recording.time
    sel = (t >= start) & (t < end)
    if not np.any(sel):
        raise ConfigError(f"power window [{start:g}, {end:g}] s holds no sample of {recording.name!r} "
                          f"(t = {t[0]:g}..{t[-1]:g} s)")
    return float(np.mean(recording[channel][sel]))


# ---------------------------------------------------------------------------- tables
def read_unit_table(path, spec: dict[str, str | None]) -> tuple[dict[str, np.ndarray], dict[str, list[str]], int]:
    """Read a one-row-per-item CSV with ``name [unit]`` headers.

    ``spec`` maps known column names to their quantity (None: a plain number, unit ``1``). A known
    column of a physical quantity without a unit in its header is refused (never read as SI).
    Returns (SI columns, other columns as text, rows). Errors name the file, line and column.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"table {path} not found")
    lines = [(i + 1, ln) for i, ln in enumerate(read_csv_text(path).splitlines())
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InvalidSignalError(f"{path.name}: empty file (no header line)")
    head_no, head = lines[0]
    delim = max([",", ";", "\t"], key=head.count)
    cells = [c.strip() for c in next(_csv.reader([head], delimiter=delim))]
    cols: list[tuple[str, str, float | None]] = []
    for cell in cells:
        m = _HEADER_RE.match(cell)
        name, unit = (m.group(1).strip(), m.group(2).strip()) if m else (cell, None)
        if not name:
            raise ConfigError(f"{path.name}, line {head_no}: a column has no name ({cell!r})")
        if any(name == c[0] for c in cols):
            raise ConfigError(f"{path.name}: column {name!r} appears twice")
        factor = None
        if name in spec:
            quantity = spec[name] or _units.DIMENSIONLESS
            if unit is None and quantity != _units.DIMENSIONLESS:
                raise UnitError(f"{path.name}, line {head_no}: column {name!r} has no unit; write it in the "
                                f"header, e.g. '{name} [{_units.si_unit(quantity)}]' (a number read in the wrong "
                                "unit would give a silently wrong answer)")
            if unit is None:
                unit = _units.si_unit(quantity)
            try:
                factor = _units.unit_info(unit, quantity=quantity, name=name).factor
            except UnitError as exc:
                raise UnitError(f"{path.name}, column {cell!r}: {exc}") from None
        cols.append((name, cell, factor))
    rows = lines[1:]
    if not rows:
        raise InvalidSignalError(f"{path.name}: no data rows after the header (line {head_no})")
    values: dict[str, list[float]] = {c[0]: [] for c in cols if c[2] is not None}
    text: dict[str, list[str]] = {c[0]: [] for c in cols if c[2] is None}
    for lineno, line in rows:
        row = [c.strip() for c in next(_csv.reader([line.split("#", 1)[0]], delimiter=delim))]
        if len(row) != len(cols):
            raise InvalidSignalError(f"{path.name}, line {lineno}: {len(row)} cells, the header has {len(cols)}")
        for (name, cell, factor), v in zip(cols, row):
            if factor is None:
                text[name].append(v)
                continue
            try:
                x = float(v)
            except ValueError:
                raise InvalidSignalError(f"{path.name}, line {lineno}, column {cell!r}: {v!r} is not a number") \
                    from None
            if not math.isfinite(x):
                raise InvalidSignalError(f"{path.name}, line {lineno}, column {cell!r}: {v!r} is not finite")
            values[name].append(x * factor)
    return {k: np.array(v) for k, v in values.items()}, text, len(rows)


_CUT_COLUMNS = {"diameter": _units.LENGTH, "flutes": None, "axial_depth": _units.LENGTH,
                "spindle_speed": _units.ANGULAR_SPEED, "feed_per_tooth": _units.LENGTH,
                "feed_speed": _units.VELOCITY, "radial_depth": _units.LENGTH, "entry_angle": _units.ANGLE,
                "exit_angle": _units.ANGLE, "spindle_power": _units.POWER, "air_power": _units.POWER,
                "cutting_power": _units.POWER, "calibration": None, "distance": _units.LENGTH}


def fit_cut_table(table: CutTable, idx=None, *, warn: bool = True, **kw) -> TangentialFit:
    """Calibrate K_tc and K_te from all cuts of a cut table or the cuts `idx`.

    Parameters
    ----------
    table : CutTable
        Calibration cuts with their cutting power.
    idx : array_like of int, optional
        Indices of the cuts to use (default all).
    warn : bool
        Issue :class:`SeeSawWarning` where due.
    **kw
        Passed to :func:`fit_tangential_coefficients` (e.g. ``runout``).

    Returns
    -------
    TangentialFit
    """
    idx = np.arange(len(table.cuts)) if idx is None else np.asarray(idx, dtype=int)
    return calibrate_from_power([table.cuts[i] for i in idx], table.cutting_power[idx], warn=warn, **kw)


def read_cut_table(path, *, diameter: float | None = None, flutes: int | None = None,
                   mode: str = "down") -> CutTable:
    """Read calibration cuts (one per row) from a CSV with ``name [unit]`` headers.

    Columns (units converted to SI; e.g. ``mm``, ``in``, ``rpm``, ``deg``, ``W``, ``hp``):

    * ``spindle_speed``, ``axial_depth``; ``feed_per_tooth`` or ``feed_speed``;
    * ``radial_depth`` (with `mode`) or ``entry_angle`` and ``exit_angle``;
    * ``cutting_power``, or ``spindle_power`` and ``air_power`` (cutting = spindle - air, Eq. 5);
    * ``diameter`` and ``flutes``, unless given as arguments;
    * optional ``calibration`` (number) and ``distance`` (cut length so far) for a tool's life.

    Other columns are ignored.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    diameter : float, optional
        Tool diameter [m] when the table has no ``diameter`` column.
    flutes : int, optional
        Number of flutes when the table has no ``flutes`` column.
    mode : {"up", "down"}
        Milling mode of ``radial_depth`` rows.

    Returns
    -------
    CutTable

    Raises
    ------
    ConfigError
        A missing column or bad value, naming it and the line (negative feed, immersion above
        the diameter...).
    InvalidSignalError, UnitError
        No rows, a non-number, or a unit that does not fit the column.
    """
    path = Path(path)
    cols, _, n = read_unit_table(path, _CUT_COLUMNS)

    def column(name, default=None, label=None):
        if name in cols:
            return cols[name]
        if default is not None:
            return np.full(n, float(default))
        raise ConfigError(f"{path.name}: no {name!r} column{label or ''} (columns: {', '.join(cols)})")

    d = column("diameter", diameter, " and no diameter given")
    z = column("flutes", flutes, " and no flutes given")
    a = column("axial_depth")
    w = column("spindle_speed")
    if "feed_per_tooth" in cols:
        ft = cols["feed_per_tooth"]
    elif "feed_speed" in cols:
        ft = 2 * math.pi * cols["feed_speed"] / (z * np.where(w > 0, w, np.nan))
    else:
        raise ConfigError(f"{path.name}: give a 'feed_per_tooth' or a 'feed_speed' column")
    if "cutting_power" in cols:
        p = cols["cutting_power"]
    elif "spindle_power" in cols and "air_power" in cols:
        p = cols["spindle_power"] - cols["air_power"]
    else:
        raise ConfigError(f"{path.name}: give 'cutting_power', or 'spindle_power' and 'air_power' "
                          "(the air-cut power is subtracted, Eq. 5)")
    cuts = []
    for i in range(n):
        try:
            if not float(z[i]).is_integer():
                raise ConfigError(f"'flutes' must be a whole number, got {z[i]!r}")
            args = (d[i], int(z[i]), a[i], w[i], ft[i])
            if "radial_depth" in cols:
                cut = CutConditions.from_radial_depth(*args, radial_depth=cols["radial_depth"][i], mode=mode)
            elif "entry_angle" in cols and "exit_angle" in cols:
                cut = CutConditions(*args, cols["entry_angle"][i], cols["exit_angle"][i])
            else:
                raise ConfigError("give a 'radial_depth' column, or 'entry_angle' and 'exit_angle'")
        except ConfigError as exc:
            raise ConfigError(f"{path.name}, row {i + 1}: {exc}") from None
        cuts.append(cut)
    return CutTable(tuple(cuts), p, cols.get("calibration"), cols.get("distance"), name=path.stem)
