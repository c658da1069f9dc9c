"""Cut geometry and the average-power form of the tangential force model (second paper, Eq. 1-5).

The average tangential force on an engaged flute is ``F_t = K_tc h_avg a + K_te a`` (Eq. 1) and
the average spindle cutting power is ``P = K_tc Q + K_te A_c`` (Eq. 2), with

* ``Q = a_e a v_f``, the material-removal rate [m^3/s] (``a_e = r (cos phi_st - cos phi_ex)``),
* ``A_c = a r phi_eng N omega / (2 pi)``, the contact-area rate [m^2/s]: the area of cutting edge
  (axial length ``a`` times the arc ``r phi_eng``) swept per second by the ``N`` flutes,
* ``h_avg = f_t (cos phi_st - cos phi_ex) / phi_eng`` (Eq. 4), so that ``Q / A_c = h_avg`` and
  ``F_t / a = P / A_c = K_tc h_avg + K_te`` (Eq. 5).

Eq. 3, ``F_t = P / (omega r) * 2 pi / phi_eng``, is written in the paper for one flute; with ``N``
flutes the per-flute average over the engagement is ``P / (omega r) * 2 pi / (N phi_eng)``, which
is what :func:`average_tangential_force` returns (identical for ``N = 1``).

Angles follow :mod:`drivesense.machine.milling` (Altintas' convention, immersion measured from
the normal to the feed): a slot is 0..pi, down milling ends at pi, up milling starts at 0. The
paper's Table 1 "entrance/exit" 60/180, 90/180, 120/180 are down-milling cuts at 75 %, 50 % and
25 % radial immersion. Everything here is SI; this module does no I/O.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.machine.milling import (EndMill, MillingCut, check_int, check_number, average_chip_thickness,
                                        engagement_angles, material_removal_rate)

__all__ = [
    "CutConditions",
    "engagement_angle",
    "chip_thickness_from_angles",
    "cutting_power",
    "average_tangential_force",
    "force_per_depth",
    "CutTable",
    "finite_vector",
]

_TWO_PI = 2.0 * math.pi
_ANGLE_TOL = 1e-9  # rad: an angle this close to 0 or pi counts as exactly 0 or pi


def engagement_angle(diameter, radial_depth, mode="down") -> float:
    """Angle of engagement ``phi_eng = phi_ex - phi_st`` of a cut.

    Parameters
    ----------
    diameter : float
        Tool diameter D [m].
    radial_depth : float
        Radial depth of cut a_e [m], 0 < a_e <= D.
    mode : {"up", "down"}
        Milling mode; a_e == D is a slot whatever the mode.

    Returns
    -------
    float
        phi_eng [rad], in (0, pi].

    Raises
    ------
    ConfigError
        a_e above the diameter, non-positive sizes, unknown mode.
    """
    st, ex = engagement_angles(diameter, radial_depth, mode)
    return ex - st


def chip_thickness_from_angles(feed_per_tooth, entry_angle, exit_angle) -> float:
    """Average chip thickness from the entry and exit angles (Eq. 4).

    ``h_avg = (1 / phi_eng) int_{phi_st}^{phi_ex} f_t sin(phi) dphi
    = f_t (cos phi_st - cos phi_ex) / (phi_ex - phi_st)``; a slot gives ``2 f_t / pi``.

    Parameters
    ----------
    feed_per_tooth : float
        Feed per tooth f_t [m], >= 0.
    entry_angle, exit_angle : float
        phi_st < phi_ex [rad], both in [0, pi].

    Returns
    -------
    float
        h_avg [m].

    Raises
    ------
    ConfigError
        Negative feed or angles out of order / outside [0, pi].
    """
    c = check_number(feed_per_tooth, "feed_per_tooth", nonneg=True)
    st, ex = _check_angles(entry_angle, exit_angle)
    return c * (math.cos(st) - math.cos(ex)) / (ex - st)


def _check_angles(entry, exit_) -> tuple[float, float]:
    st = check_number(entry, "entry_angle")
    ex = check_number(exit_, "exit_angle")
    if not (-_ANGLE_TOL <= st < math.pi):
        raise ConfigError(f"'entry_angle' must be in [0, pi) rad, got {st!r}")
    if not (0.0 < ex <= math.pi + _ANGLE_TOL):
        raise ConfigError(f"'exit_angle' must be in (0, pi] rad, got {ex!r}")
    if ex <= st:
        raise ConfigError(f"'exit_angle' ({ex!r} rad) must be greater than 'entry_angle' ({st!r} rad)")
    return max(st, 0.0), min(ex, math.pi)


@dataclass(frozen=True)
class CutConditions:
    """One end-milling cut: tool, engagement and feed, with the rates of Eq. 2-5.

    Parameters
    ----------
    diameter : float
        Tool diameter D [m], > 0.
    flutes : int
        Number of flutes N, >= 1.
    axial_depth : float
        Axial depth of cut a [m], > 0.
    spindle_speed : float
        Spindle angular speed omega [rad/s], > 0.
    feed_per_tooth : float
        Feed per tooth f_t [m], >= 0.
    entry_angle : float
        phi_st [rad]; 0 for a slot or up milling.
    exit_angle : float
        phi_ex [rad]; pi for a slot or down milling. Either the entry is 0 or the exit is pi
        (a straight cut from one side of the tool).

    Raises
    ------
    ConfigError
        A bad value, naming the field (negative feed, angles out of order...).

    Examples
    --------
    >>> cut = CutConditions.from_radial_depth(12.7e-3, 1, 2.54e-3, 111.8, 0.04e-3, radial_depth=12.7e-3)
    >>> round(cut.average_chip_thickness / 0.04e-3, 6)        # slot: 2 / pi
    0.63662
    """

    diameter: float
    flutes: int
    axial_depth: float
    spindle_speed: float
    feed_per_tooth: float
    entry_angle: float = 0.0
    exit_angle: float = math.pi

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "diameter", check_number(self.diameter, "diameter", positive=True))
        set_(self, "flutes", check_int(self.flutes, "flutes"))
        set_(self, "axial_depth", check_number(self.axial_depth, "axial_depth", positive=True))
        set_(self, "spindle_speed", check_number(self.spindle_speed, "spindle_speed", positive=True))
        set_(self, "feed_per_tooth", check_number(self.feed_per_tooth, "feed_per_tooth", nonneg=True))
        st, ex = _check_angles(self.entry_angle, self.exit_angle)
        if st > _ANGLE_TOL and ex < math.pi - _ANGLE_TOL:
            raise ConfigError(f"'entry_angle' {st!r} rad and 'exit_angle' {ex!r} rad: a straight end-milling cut "
                              "starts at 0 (up milling) or ends at pi (down milling)")
        set_(self, "entry_angle", st)
        set_(self, "exit_angle", ex)

    @classmethod
    def from_radial_depth(cls, diameter, flutes, axial_depth, spindle_speed, feed_per_tooth, *,
                          radial_depth, mode="down") -> "CutConditions":
        """Build a cut from the radial depth a_e and the milling mode.

        Parameters
        ----------
        diameter : float
            Tool diameter D [m].
        flutes : int
            Number of flutes N.
        axial_depth : float
            Axial depth a [m].
        spindle_speed : float
            omega [rad/s].
        feed_per_tooth : float
            f_t [m].
        radial_depth : float
            a_e [m], 0 < a_e <= D (ConfigError above the diameter).
        mode : {"up", "down"}
            Milling mode.

        Returns
        -------
        CutConditions
        """
        st, ex = engagement_angles(diameter, radial_depth, mode)
        return cls(diameter, flutes, axial_depth, spindle_speed, feed_per_tooth, st, ex)

    # ------------------------------------------------------------------ geometry
    @property
    def radius(self) -> float:
        """Tool radius r [m]."""
        return 0.5 * self.diameter

    @property
    def mode(self) -> str:
        """``"down"`` when the cut ends at pi (slots included), else ``"up"``."""
        return "down" if self.exit_angle >= math.pi - _ANGLE_TOL else "up"

    @property
    def radial_depth(self) -> float:
        """Radial depth a_e = r (cos phi_st - cos phi_ex) [m]."""
        return min(self.radius * (math.cos(self.entry_angle) - math.cos(self.exit_angle)), self.diameter)

    @property
    def engagement_angle(self) -> float:
        """phi_eng = phi_ex - phi_st [rad]."""
        return self.exit_angle - self.entry_angle

    @property
    def feed_speed(self) -> float:
        """Feed speed v_f = f_t N omega / (2 pi) [m/s]."""
        return self.feed_per_tooth * self.flutes * self.spindle_speed / _TWO_PI

    @property
    def cutting_speed(self) -> float:
        """Peripheral cutting speed V = omega r [m/s]."""
        return self.spindle_speed * self.radius

    def milling_cut(self, axial_slices: int = 20) -> MillingCut:
        """The equivalent :class:`~drivesense.machine.milling.MillingCut` (a_e, a, mode).

        Parameters
        ----------
        axial_slices : int
            Axial slices for the helix, >= 1.

        Returns
        -------
        MillingCut
        """
        return MillingCut(self.radial_depth, self.axial_depth, self.mode, axial_slices)

    def end_mill(self, helix_deg: float = 30.0, runout: float = 0.0, runout_phase: float = 0.0) -> EndMill:
        """The tool as an :class:`~drivesense.machine.milling.EndMill`.

        Parameters
        ----------
        helix_deg : float
            Helix angle [deg].
        runout : float
            Radial runout e [m].
        runout_phase : float
            Direction of the runout offset [rad].

        Returns
        -------
        EndMill
        """
        return EndMill(self.diameter, self.flutes, helix_deg, runout, runout_phase)

    # ------------------------------------------------------------------ rates
    @property
    def average_chip_thickness(self) -> float:
        """h_avg [m] (Eq. 4), via :func:`drivesense.machine.milling.average_chip_thickness`."""
        return average_chip_thickness(self.feed_per_tooth, self.diameter, self.radial_depth, self.mode)

    @property
    def material_removal_rate(self) -> float:
        """Q = a_e a v_f [m^3/s], via :func:`drivesense.machine.milling.material_removal_rate`."""
        return material_removal_rate(self.milling_cut(1), self.feed_speed)

    @property
    def contact_area_rate(self) -> float:
        """A_c = a r phi_eng N omega / (2 pi) [m^2/s]: cutting-edge area swept per second."""
        return self.axial_depth * self.radius * self.engagement_angle * self.flutes * self.spindle_speed / _TWO_PI

    def to_dict(self) -> dict:
        """The cut as plain SI numbers (JSON-ready), with its derived rates.

        Returns
        -------
        dict
        """
        return {"diameter_m": self.diameter, "flutes": self.flutes, "axial_depth_m": self.axial_depth,
                "spindle_speed_rad_s": self.spindle_speed, "feed_per_tooth_m": self.feed_per_tooth,
                "entry_angle_rad": self.entry_angle, "exit_angle_rad": self.exit_angle,
                "h_avg_m": self.average_chip_thickness, "mrr_m3_s": self.material_removal_rate,
                "contact_area_rate_m2_s": self.contact_area_rate}


def _cuts(cuts) -> list[CutConditions]:
    items = [cuts] if isinstance(cuts, CutConditions) else list(cuts)
    for i, c in enumerate(items):
        if not isinstance(c, CutConditions):
            raise ConfigError(f"cut {i} must be CutConditions, got {type(c).__name__}")
    return items


def _scalar_or_array(values: np.ndarray, single: bool):
    return float(values[0]) if single else values


def cutting_power(Ktc, Kte, cuts):
    """Average spindle cutting power ``P = K_tc Q + K_te A_c`` (Eq. 2).

    Parameters
    ----------
    Ktc : float
        Tangential cutting coefficient [N/m^2].
    Kte : float
        Tangential edge coefficient [N/m].
    cuts : CutConditions or sequence of CutConditions
        The cut(s).

    Returns
    -------
    float or ndarray
        Power [W] (one value per cut for a sequence).
    """
    ktc = check_number(Ktc, "Ktc")
    kte = check_number(Kte, "Kte")
    items = _cuts(cuts)
    p = np.array([ktc * c.material_removal_rate + kte * c.contact_area_rate for c in items], dtype=float)
    return _scalar_or_array(p, isinstance(cuts, CutConditions))


def _power(power, n: int, name: str = "power") -> np.ndarray:
    if isinstance(power, bool) or (isinstance(power, numbers.Number) and not isinstance(power, numbers.Real)):
        raise InvalidSignalError(f"'{name}' must be real, got {power!r}")
    try:
        p = np.asarray(power, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"'{name}' must be numeric: {exc}") from None
    p = np.broadcast_to(p, (n,)) if p.ndim == 0 else p
    if p.shape != (n,):
        raise InvalidSignalError(f"'{name}' has {p.size} values for {n} cut(s)")
    if not np.all(np.isfinite(p)):
        raise InvalidSignalError(f"'{name}' holds non-finite values (NaN or inf)")
    return p


def average_tangential_force(power, cuts):
    """Average tangential force on an engaged flute from the cutting power (Eq. 3).

    ``F_t = P / (omega r) * 2 pi / (N phi_eng)`` (the paper's Eq. 3 for N = 1).

    Parameters
    ----------
    power : float or array_like
        Average cutting power [W] (spindle power minus air-cut power), one per cut.
    cuts : CutConditions or sequence of CutConditions
        The cut(s).

    Returns
    -------
    float or ndarray
        F_t [N].
    """
    items = _cuts(cuts)
    p = _power(power, len(items))
    f = np.array([pk * _TWO_PI / (c.spindle_speed * c.radius * c.flutes * c.engagement_angle)
                  for pk, c in zip(p, items)], dtype=float)
    return _scalar_or_array(f, isinstance(cuts, CutConditions))


def force_per_depth(power, cuts):
    """Average tangential force per axial depth ``F_t / a = P / A_c`` (Eq. 5).

    Parameters
    ----------
    power : float or array_like
        Average cutting power [W] (spindle power minus air-cut power), one per cut.
    cuts : CutConditions or sequence of CutConditions
        The cut(s).

    Returns
    -------
    float or ndarray
        F_t / a [N/m], which the linear model says is ``K_tc h_avg + K_te``.
    """
    items = _cuts(cuts)
    p = _power(power, len(items))
    f = np.array([pk / c.contact_area_rate for pk, c in zip(p, items)], dtype=float)
    return _scalar_or_array(f, isinstance(cuts, CutConditions))


def finite_vector(values, name: str) -> np.ndarray:
    """``values`` as a 1-D float array, refusing non-numeric or non-finite entries (naming ``name``).

    Parameters
    ----------
    values : array_like
        The numbers [any unit; returned unchanged].
    name : str
        Field name for the message.
    """
    try:
        arr = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"'{name}' must be numeric: {exc}") from None
    if not np.all(np.isfinite(arr)):
        raise InvalidSignalError(f"'{name}' holds non-finite values (NaN or inf)")
    return arr


@dataclass(frozen=True, eq=False)
class CutTable:
    """Calibration cuts with their measured power, optionally grouped into calibrations along a tool's life.

    The data only; :func:`drivesense.identify.coefficients.fit_cut_table` calibrates K_tc/K_te from it.

    Parameters
    ----------
    cuts : tuple of CutConditions
        The cuts (SI).
    cutting_power : ndarray
        Average cutting power of each cut [W] (spindle power minus air-cut power).
    calibration : ndarray of int, optional
        Calibration number of each cut (cuts of one calibration are fitted together).
    distance : ndarray, optional
        Distance the tool had cut when each cut was made [m] (the wear clock).
    name : str
        A label (the file stem when read).
    """

    cuts: tuple
    cutting_power: np.ndarray
    calibration: np.ndarray | None = None
    distance: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "cuts", tuple(self.cuts))
        n = len(self.cuts)
        if n == 0:
            raise InvalidSignalError(f"cut table {self.name!r} holds no cuts")
        p = finite_vector(self.cutting_power, "cutting_power")
        if p.size != n:
            raise InvalidSignalError(f"'cutting_power' has {p.size} values for {n} cuts")
        object.__setattr__(self, "cutting_power", p)
        for attr in ("calibration", "distance"):
            v = getattr(self, attr)
            if v is not None:
                v = finite_vector(v, attr)
                if v.size != n:
                    raise InvalidSignalError(f"'{attr}' has {v.size} values for {n} cuts")
                if attr == "distance" and np.any(v < 0):
                    raise InvalidSignalError(f"'distance' must be >= 0 m, got min {v.min()!r}")
                object.__setattr__(self, attr, v.astype(int) if attr == "calibration" else v)

    def __len__(self) -> int:
        return len(self.cuts)

    def groups(self) -> list[tuple[float, np.ndarray]]:
        """Cut indices of each calibration, in order of distance.

        Returns
        -------
        list of (distance [m], index array)
            One entry per calibration (by ``calibration`` number, else by ``distance``, else one for all);
            the distance is the mean distance of its cuts (0 without a distance column).
        """
        n = len(self.cuts)
        key = self.calibration if self.calibration is not None else self.distance
        if key is None:
            return [(0.0, np.arange(n))]
        out = []
        for k in np.unique(key):
            idx = np.flatnonzero(key == k)
            d = float(np.mean(self.distance[idx])) if self.distance is not None else float(k)
            out.append((d, idx))
        return sorted(out, key=lambda g: g[0])
