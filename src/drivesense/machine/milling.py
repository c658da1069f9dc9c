"""Mechanistic end-milling force model (Altintas, *Manufacturing Automation*, ch. 2).

Geometry and sign conventions (Altintas 2000, Fig. 2.11 and Eq. 2.9-2.18):

* the tool feeds along ``+x``; ``y`` is normal to the feed in the cutting plane,
  ``z`` is the tool axis;
* the tool rotates clockwise seen from the spindle, and the immersion angle
  ``phi`` is measured clockwise from ``+y``: the edge point at ``phi`` sits at
  ``(x, y) = (D/2) (sin phi, cos phi)`` relative to the tool centre and the
  uncut chip is ``h = c sin(phi)`` (``c`` the feed per tooth);
* up milling cuts over ``[0, arccos(1 - 2 a_e/D)]``, down milling over
  ``[arccos(2 a_e/D - 1), pi]``; a slot (``a_e == D``) over ``[0, pi]``;
* flute ``j`` at height ``z`` above the tool tip is at
  ``phi_j(z) = theta + j 2 pi/N - z tan(helix) / (D/2)`` (``theta`` the
  spindle angle), its radius is ``r_j = D/2 + e cos(runout_phase - j 2 pi/N)``
  (``e`` the runout) and its chip ``h = c sin(phi) + r_j - r_{j-1}``, >= 0;
* the linear edge-force model gives, per axial slice ``dz``,
  ``dF_t = (K_tc h + K_te) dz``, ``dF_r = (K_rc h + K_re) dz``,
  ``dF_a = (K_ac h + K_ae) dz`` and the force **on the tool** is
  ``F_x = sum(-dF_t cos phi - dF_r sin phi)``,
  ``F_y = sum(dF_t sin phi - dF_r cos phi)``, ``F_z = sum(dF_a)``; the
  torque the cut loads the spindle with is ``T = sum(dF_t r_j)`` [N*m] and the
  cutting power ``P = T omega`` [W].

The mean forces over a tooth period do not depend on the helix angle; for a
zero-runout cut they are Altintas' Eq. 2.18, and the mean power equals
``K_tc Q + K_te A_c`` (material-removal rate ``Q``, contact-area rate ``A_c``),
the tangential force model of the second paper (Eq. 1-5).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

import numpy as np
from numba import njit, prange

from drivesense.errors import ConfigError, InvalidSignalError

__all__ = [
    "CuttingCoefficients",
    "EndMill",
    "MillingCut",
    "MillingForces",
    "engagement_angles",
    "milling_forces",
    "tooth_passing_frequency",
    "feed_per_tooth",
    "average_chip_thickness",
    "material_removal_rate",
]

_TWO_PI = 2.0 * math.pi
_MODES = ("up", "down")


def check_number(value, name: str, *, positive: bool = False, nonneg: bool = False) -> float:
    """Return ``value`` as a finite float or raise :class:`ConfigError` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ConfigError(f"'{name}' must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(f"'{name}' must be finite, got {value!r}")
    if positive and value <= 0.0:
        raise ConfigError(f"'{name}' must be > 0, got {value!r}")
    if nonneg and value < 0.0:
        raise ConfigError(f"'{name}' must be >= 0, got {value!r}")
    return value


def check_int(value, name: str, minimum: int = 1) -> int:
    """Return ``value`` as an int >= ``minimum`` or raise :class:`ConfigError`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ConfigError(f"'{name}' must be an integer, got {value!r}")
    if value < minimum:
        raise ConfigError(f"'{name}' must be >= {minimum}, got {value!r}")
    return int(value)


def _as_signal(value, name: str, *, nonneg: bool = False, positive: bool = False) -> np.ndarray:
    """Convert array input to a float ndarray, or raise :class:`InvalidSignalError` naming it."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"'{name}' must be numeric: {exc}") from None
    if arr.ndim > 1:
        raise InvalidSignalError(f"'{name}' must be a scalar or 1-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidSignalError(f"'{name}' holds non-finite values (NaN or inf)")
    if positive and np.any(arr <= 0.0):
        raise InvalidSignalError(f"'{name}' must be > 0, got min {arr.min()!r}")
    if nonneg and np.any(arr < 0.0):
        raise InvalidSignalError(f"'{name}' must be >= 0, got min {arr.min()!r}")
    return arr


@dataclass(frozen=True)
class CuttingCoefficients:
    """Linear edge-force model coefficients (Altintas Eq. 2.9).

    Parameters
    ----------
    Ktc, Krc, Kac : float
        Tangential, radial and axial cutting (shearing) coefficients [N/m^2].
    Kte, Kre, Kae : float
        Tangential, radial and axial edge (rubbing) coefficients [N/m].
    """

    Ktc: float
    Krc: float
    Kac: float
    Kte: float
    Kre: float
    Kae: float

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, check_number(getattr(self, f.name), f.name))

    @classmethod
    def aluminium(cls) -> "CuttingCoefficients":
        """Al7075-T6 with a carbide end mill, Altintas (2000), Table 2.1 / Example 2.1.

        ``Ktc = 796 N/mm^2``, ``Krc = 168``, ``Kac = 222``, ``Kte = 27.7 N/mm``,
        ``Kre = 15.4``, ``Kae = 1.0``, here in SI units ([N/m^2], [N/m]).

        Returns
        -------
        CuttingCoefficients
        """
        return cls(Ktc=796e6, Krc=168e6, Kac=222e6, Kte=27.7e3, Kre=15.4e3, Kae=1.0e3)


@dataclass(frozen=True)
class EndMill:
    """A helical flat end mill.

    Parameters
    ----------
    diameter : float
        Tool diameter D [m], > 0.
    flutes : int
        Number of flutes N, >= 1.
    helix_deg : float
        Helix angle [deg], in [0, 90).
    runout : float
        Radial runout amplitude e [m] (offset of the tool axis from the spindle
        axis), in [0, D/2). Flute ``j`` has radius
        ``D/2 + e cos(runout_phase - j 2 pi/N)``.
    runout_phase : float
        Direction of the runout offset relative to flute 0 [rad].
    """

    diameter: float
    flutes: int
    helix_deg: float = 30.0
    runout: float = 0.0
    runout_phase: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "diameter", check_number(self.diameter, "diameter", positive=True))
        object.__setattr__(self, "flutes", check_int(self.flutes, "flutes"))
        helix = check_number(self.helix_deg, "helix_deg", nonneg=True)
        if helix >= 90.0:
            raise ConfigError(f"'helix_deg' must be < 90 deg, got {helix!r}")
        object.__setattr__(self, "helix_deg", helix)
        runout = check_number(self.runout, "runout", nonneg=True)
        if runout >= 0.5 * self.diameter:
            raise ConfigError(f"'runout' must be smaller than the tool radius {0.5 * self.diameter!r} m, got {runout!r}")
        object.__setattr__(self, "runout", runout)
        object.__setattr__(self, "runout_phase", check_number(self.runout_phase, "runout_phase"))

    @property
    def flute_radii(self) -> np.ndarray:
        """Radius of each flute r_j [m], shape (N,)."""
        j = np.arange(self.flutes)
        return 0.5 * self.diameter + self.runout * np.cos(self.runout_phase - j * _TWO_PI / self.flutes)


@dataclass(frozen=True)
class MillingCut:
    """Cut geometry.

    Parameters
    ----------
    radial_depth : float
        Radial depth (width) of cut a_e [m], 0 < a_e <= D.
    axial_depth : float
        Axial depth of cut a_p [m], > 0.
    mode : {"up", "down"}
        Up (conventional) or down (climb) milling; ``a_e == D`` is a slot
        whatever the mode.
    axial_slices : int
        Number of axial slices dz = a_p / axial_slices for the helix, >= 1.
    """

    radial_depth: float
    axial_depth: float
    mode: str = "down"
    axial_slices: int = 20

    def __post_init__(self) -> None:
        object.__setattr__(self, "radial_depth", check_number(self.radial_depth, "radial_depth", positive=True))
        object.__setattr__(self, "axial_depth", check_number(self.axial_depth, "axial_depth", positive=True))
        if self.mode not in _MODES:
            raise ConfigError(f"'mode' must be 'up' or 'down', got {self.mode!r}")
        object.__setattr__(self, "axial_slices", check_int(self.axial_slices, "axial_slices"))


@dataclass(frozen=True, eq=False)
class MillingForces:
    """Cutting force on the tool, tool frame (x = feed, y = normal to feed, z = axis).

    Attributes
    ----------
    feed : ndarray
        F_x, force along the feed direction [N].
    normal : ndarray
        F_y, force normal to the feed [N].
    axial : ndarray
        F_z, force along the tool axis [N].
    torque : ndarray
        Torque the cut loads the spindle with [N*m] (>= 0 for a normal cut).
    """

    feed: np.ndarray
    normal: np.ndarray
    axial: np.ndarray
    torque: np.ndarray

    def power(self, spindle_speed) -> np.ndarray:
        """Cutting power at the spindle, ``torque * omega``.

        Parameters
        ----------
        spindle_speed : float or array_like
            Spindle angular speed omega [rad/s], scalar or one value per sample.

        Returns
        -------
        ndarray
            Power [W].
        """
        omega = _as_signal(spindle_speed, "spindle_speed")
        if omega.ndim == 1 and omega.shape != self.torque.shape:
            raise InvalidSignalError(
                f"'spindle_speed' has {omega.size} samples, the forces have {self.torque.size}")
        return self.torque * omega


def engagement_angles(diameter, radial_depth, mode) -> tuple[float, float]:
    """Start and exit immersion angles of a cut (Altintas Eq. 2.10 convention).

    Parameters
    ----------
    diameter : float
        Tool diameter D [m].
    radial_depth : float
        Radial depth of cut a_e [m], 0 < a_e <= D.
    mode : {"up", "down"}
        Up milling starts at 0, down milling ends at pi; a_e == D is a slot.

    Returns
    -------
    phi_st, phi_ex : float
        Start and exit angles [rad], measured clockwise from +y (normal to feed).
    """
    d = check_number(diameter, "diameter", positive=True)
    ae = check_number(radial_depth, "radial_depth", positive=True)
    if ae > d:
        raise ConfigError(f"'radial_depth' {ae!r} m exceeds the tool diameter {d!r} m")
    if mode not in _MODES:
        raise ConfigError(f"'mode' must be 'up' or 'down', got {mode!r}")
    ratio = min(ae / d, 1.0)
    if ratio == 1.0:
        return 0.0, math.pi
    if mode == "up":
        return 0.0, math.acos(1.0 - 2.0 * ratio)
    return math.acos(2.0 * ratio - 1.0), math.pi


def tooth_passing_frequency(spindle_speed_rpm, flutes):
    """Tooth-passing frequency ``N n / 60``.

    Parameters
    ----------
    spindle_speed_rpm : float or array_like
        Spindle speed n [rev/min], >= 0.
    flutes : int
        Number of flutes N.

    Returns
    -------
    float or ndarray
        Tooth-passing frequency [Hz].
    """
    n = _as_signal(spindle_speed_rpm, "spindle_speed_rpm", nonneg=True)
    f = n * check_int(flutes, "flutes") / 60.0
    return float(f) if f.ndim == 0 else f


def feed_per_tooth(feed_speed, spindle_speed, flutes):
    """Feed per tooth ``c = v_f / (N n) = 2 pi v_f / (N omega)``.

    Parameters
    ----------
    feed_speed : float or array_like
        Feed speed v_f [m/s], >= 0.
    spindle_speed : float or array_like
        Spindle angular speed omega [rad/s], > 0.
    flutes : int
        Number of flutes N.

    Returns
    -------
    float or ndarray
        Feed per tooth c [m].
    """
    vf = _as_signal(feed_speed, "feed_speed", nonneg=True)
    omega = _as_signal(spindle_speed, "spindle_speed", positive=True)
    c = _TWO_PI * vf / (check_int(flutes, "flutes") * omega)
    return float(c) if c.ndim == 0 else c


def average_chip_thickness(feed_per_tooth, diameter, radial_depth, mode) -> float:
    """Mean uncut chip thickness over the engagement (second paper, Eq. 4).

    ``h_avg = c (cos phi_st - cos phi_ex) / (phi_ex - phi_st)``.

    Parameters
    ----------
    feed_per_tooth : float
        Feed per tooth c [m], >= 0.
    diameter : float
        Tool diameter D [m].
    radial_depth : float
        Radial depth of cut a_e [m].
    mode : {"up", "down"}
        Milling mode.

    Returns
    -------
    float
        Average chip thickness [m].
    """
    c = check_number(feed_per_tooth, "feed_per_tooth", nonneg=True)
    st, ex = engagement_angles(diameter, radial_depth, mode)
    return c * (math.cos(st) - math.cos(ex)) / (ex - st)


def material_removal_rate(cut, feed_speed):
    """Material-removal rate ``Q = a_e a_p v_f``.

    Parameters
    ----------
    cut : MillingCut
        Cut geometry (a_e, a_p [m]).
    feed_speed : float or array_like
        Feed speed v_f [m/s], >= 0.

    Returns
    -------
    float or ndarray
        Q [m^3/s].
    """
    vf = _as_signal(feed_speed, "feed_speed", nonneg=True)
    q = cut.radial_depth * cut.axial_depth * vf
    return float(q) if q.ndim == 0 else q


@njit(cache=True, inline="always")
def edge_immersion(a_mod, sa, ca, off, cos_off, sin_off):  # pragma: no cover - numba
    """Immersion angle [rad] of an edge point at offset ``off`` behind flute 0 (spindle angle ``a_mod`` in
    [0, 2 pi), its sine ``sa`` and cosine ``ca``), and the sine and cosine of that immersion."""
    two_pi = 2.0 * math.pi
    phi = a_mod + off
    while phi >= two_pi:
        phi -= two_pi
    return phi, sa * cos_off + ca * sin_off, ca * cos_off - sa * sin_off


def _forces_loop(angle, c, fp, use_fp, off, cos_off, sin_off, radius, drad,
                 phi_st, phi_ex, half_d, k, dz, fx, fy, fz, tq):  # pragma: no cover - numba
    """Accumulate the slice forces of every flute into fx, fy, fz, tq (in place)."""
    two_pi = 2.0 * math.pi
    ktc, krc, kac, kte, kre, kae = k[0], k[1], k[2], k[3], k[4], k[5]
    nf, ns = off.shape
    for i in prange(angle.size):
        a = angle[i]
        sa = math.sin(a)
        ca = math.cos(a)
        a_mod = a - two_pi * math.floor(a / two_pi)
        ci = c[i]
        sx = 0.0
        sy = 0.0
        sz = 0.0
        st = 0.0
        for j in range(nf):
            for m in range(ns):
                phi, s, co = edge_immersion(a_mod, sa, ca, off[j, m], cos_off[j, m], sin_off[j, m])
                if phi < phi_st or phi > phi_ex:
                    continue
                if use_fp and fp[i] + half_d * s < 0.0:
                    continue
                h = ci * s + drad[j]
                if h <= 0.0:
                    continue
                dft = (ktc * h + kte) * dz
                dfr = (krc * h + kre) * dz
                sx += -dft * co - dfr * s
                sy += dft * s - dfr * co
                sz += (kac * h + kae) * dz
                st += dft * radius[j]
        fx[i] = sx
        fy[i] = sy
        fz[i] = sz
        tq[i] = st



# one loop, compiled twice: threads pay off only for long inputs (a short call would wait on thread start-up)
_forces_serial = njit(cache=True, nogil=True)(_forces_loop)
_forces_parallel = njit(cache=True, nogil=True, parallel=True)(_forces_loop)
_PARALLEL_MIN_SAMPLES = 50_000


def milling_forces(tool, coefficients, cut, spindle_angle, feed_per_tooth, *,
                   feed_progress=None) -> MillingForces:
    """Cutting force and spindle torque of a helical end mill, sample by sample.

    Parameters
    ----------
    tool : EndMill
        The tool (diameter [m], flutes, helix [deg], runout [m]).
    coefficients : CuttingCoefficients
        Cutting [N/m^2] and edge [N/m] coefficients.
    cut : MillingCut
        Radial and axial depth [m], mode, number of axial slices.
    spindle_angle : array_like, shape (n,)
        Spindle rotation angle theta [rad] at each sample (non-decreasing; the
        caller integrates the spindle speed); flute 0's tip is at immersion
        ``theta`` (mod 2 pi).
    feed_per_tooth : float or array_like, shape (n,)
        Instantaneous feed per tooth c = v_f / (N n) [m], >= 0.
    feed_progress : float or array_like, shape (n,), optional
        How far the tool centre has travelled past the workpiece's entry edge
        along the feed [m] (negative before it). An edge point at immersion
        phi cuts only where ``feed_progress + (D/2) sin(phi) >= 0``, which
        gives the entry transient. None (default): fully entered.

    Returns
    -------
    MillingForces
        F_x, F_y, F_z on the tool [N] and the spindle torque [N*m].

    Raises
    ------
    ConfigError
        If ``radial_depth`` exceeds the tool diameter or an argument has the wrong type.
    InvalidSignalError
        If a signal is non-finite, of the wrong shape, decreasing
        (``spindle_angle``) or negative (``feed_per_tooth``).
    """
    if not isinstance(tool, EndMill):
        raise ConfigError(f"'tool' must be an EndMill, got {type(tool).__name__}")
    if not isinstance(coefficients, CuttingCoefficients):
        raise ConfigError(f"'coefficients' must be CuttingCoefficients, got {type(coefficients).__name__}")
    if not isinstance(cut, MillingCut):
        raise ConfigError(f"'cut' must be a MillingCut, got {type(cut).__name__}")
    phi_st, phi_ex = engagement_angles(tool.diameter, cut.radial_depth, cut.mode)

    angle = _as_signal(spindle_angle, "spindle_angle")
    if angle.ndim != 1:
        raise InvalidSignalError("'spindle_angle' must be a 1-D array of samples")
    n = angle.size
    if n > 1 and np.any(np.diff(angle) < 0.0):
        raise InvalidSignalError("'spindle_angle' must be non-decreasing (clockwise rotation)")

    def per_sample(value, name, **kw):
        arr = _as_signal(value, name, **kw)
        if arr.ndim == 1 and arr.size != n:
            raise InvalidSignalError(f"'{name}' has {arr.size} samples, 'spindle_angle' has {n}")
        return np.ascontiguousarray(np.broadcast_to(arr, (n,)), dtype=float)

    c = per_sample(feed_per_tooth, "feed_per_tooth", nonneg=True)
    use_fp = feed_progress is not None
    fp = per_sample(feed_progress, "feed_progress") if use_fp else np.zeros(1)

    nf, ns = tool.flutes, cut.axial_slices
    half_d = 0.5 * tool.diameter
    dz = cut.axial_depth / ns
    z = (np.arange(ns) + 0.5) * dz                       # slice mid-heights [m]
    lag = z * math.tan(math.radians(tool.helix_deg)) / half_d
    off = np.mod(np.arange(nf)[:, None] * (_TWO_PI / nf) - lag[None, :], _TWO_PI)
    off = np.where(off >= _TWO_PI, 0.0, off)            # guard mod rounding
    radius = tool.flute_radii
    drad = radius - np.roll(radius, 1)                   # r_j - r_{j-1}
    k = np.array([coefficients.Ktc, coefficients.Krc, coefficients.Kac,
                  coefficients.Kte, coefficients.Kre, coefficients.Kae])

    out = [np.empty(n) for _ in range(4)]
    kernel = _forces_parallel if angle.size >= _PARALLEL_MIN_SAMPLES else _forces_serial
    kernel(np.ascontiguousarray(angle), c, fp, use_fp, off, np.cos(off), np.sin(off),
                   radius, drad, phi_st, phi_ex, half_d, k, dz, *out)
    return MillingForces(feed=out[0], normal=out[1], axial=out[2], torque=out[3])
