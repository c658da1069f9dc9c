"""Average x-force from feed-drive motor power (second paper, Sec. 6, Eq. 6-7, Tables 2-3, Fig. 14).

The feed motor's power overcomes friction and the cutting force, ``eta_e P_e = P_cut + P_f`` (Eq. 6);
friction is measured as the tare power ``P_t`` (the slide moving without cutting), so the average
force along the feed is ``F_x = -eta (P_e - P_t) / v`` (Eq. 7). Fig. 14 shows one straight line per
slide speed, with a slope set by an efficiency that depends on the speed. Fitted here (linear least
squares over every cut with a reference force)::

    F_x = (a0 + a1 v) (P_total - P_tare) / v + F0

``eta(v) = |a0 + a1 v|`` is the efficiency versus slide speed (the sign of ``a0 + a1 v`` is the force
direction: negative opposes a +x feed, as in Table 3); ``F0`` [N] is an offset the power cannot see
(about -8 lbf on Table 3: the lines of Fig. 14 miss the origin). ``eta`` absorbs the power sensor's
scale too: with Table 3's 0.01875 HP/V it comes out at 32-36, not a motor efficiency, so that printed
sensitivity is not the sensor's true watts per volt (the force fit does not depend on it).
Predictions are refused outside the calibrated slide speeds (and positions, when given: the tare
jumps where a slide cover extends), or left NaN cut by cut (``predict(cuts, skip_out_of_range=True)``).
``per_speed_fits`` gives each speed's own line (Fig. 14's R^2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from drivesense import units as _units
from drivesense.errors import ConfigError, CoverageError, IdentificationError, InvalidSignalError, MissingChannelError
from drivesense.identify.coefficients import read_unit_table
from drivesense.io import JsonFileMixin

__all__ = ["FeedCuts", "FeedPowerModel", "SpeedFit", "read_feed_cuts", "fit_feed_power", "per_speed_fits",
           "cross_validate"]

_COLUMNS = {"slide_speed": _units.VELOCITY, "total_power": _units.POWER, "tare_power": _units.POWER,
            "cutting_power": _units.POWER, "force_x": _units.FORCE, "slide_position": _units.LENGTH}
_SPEED_TOL = 0.01   # relative: cuts within 1 % of a speed share its group
_MODEL_VERSION = 1


def _col(values, name: str, n: int | None = None, *, nonneg: bool = False) -> np.ndarray:
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError) as exc:
        raise InvalidSignalError(f"'{name}' must be numeric: {exc}") from None
    if arr.ndim != 1:
        raise InvalidSignalError(f"'{name}' must be 1-D, got shape {arr.shape}")
    if n is not None and arr.size != n:
        raise InvalidSignalError(f"'{name}' has {arr.size} values for {n} cuts")
    if not np.all(np.isfinite(arr)):
        raise InvalidSignalError(f"'{name}' holds non-finite values (NaN or inf)")
    if nonneg and np.any(arr < 0):
        i = int(np.argmax(arr < 0))
        raise ConfigError(f"'{name}' must be >= 0; cut {i + 1} has {arr[i]!r} (SI) — give the speed as a "
                          "magnitude, the force sign carries the direction")
    return arr


@dataclass(frozen=True, eq=False)
class FeedCuts:
    """Cuts with their average feed-drive power, for fitting or prediction (SI).

    Parameters
    ----------
    slide_speed : array_like
        Slide (feed) speed of each cut [m/s], > 0.
    total_power : array_like, optional
        Average feed-motor power during the cut [W].
    tare_power : array_like, optional
        Average power with the slide moving without cutting [W].
    cutting_power : array_like, optional
        ``total - tare`` [W] when measured directly (takes precedence over the difference).
    force_x : array_like, optional
        Reference average x-force [N] (dynamometer), needed to fit.
    slide_position : array_like, optional
        Slide position during the cut [m] (tare depends on it).
    labels : tuple of str, optional
        A label per cut (e.g. the cut number).
    name : str
        A label for the set.
    """

    slide_speed: np.ndarray
    total_power: np.ndarray | None = None
    tare_power: np.ndarray | None = None
    cutting_power: np.ndarray | None = None
    force_x: np.ndarray | None = None
    slide_position: np.ndarray | None = None
    labels: tuple = ()
    name: str = ""

    def __post_init__(self) -> None:
        v = _col(self.slide_speed, "slide_speed", nonneg=True)
        n = v.size
        if n == 0:
            raise InvalidSignalError(f"cut set {self.name!r} holds no cuts")
        if np.any(v == 0):
            raise ConfigError(f"'slide_speed' must be > 0: cut {int(np.argmin(v)) + 1} stands still, so its "
                              "feed power says nothing about the force")
        object.__setattr__(self, "slide_speed", v)
        for name in ("total_power", "tare_power", "cutting_power", "force_x", "slide_position"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _col(value, name, n))
        if self.cutting_power is None and (self.total_power is None or self.tare_power is None):
            if self.total_power is None:
                raise ConfigError("give 'total_power' (with 'tare_power') or 'cutting_power' for each cut")
        labels = tuple(str(x) for x in self.labels) or tuple(str(i + 1) for i in range(n))
        if len(labels) != n:
            raise InvalidSignalError(f"'labels' has {len(labels)} entries for {n} cuts")
        object.__setattr__(self, "labels", labels)

    def __len__(self) -> int:
        return int(self.slide_speed.size)

    def power(self, tare=None) -> np.ndarray:
        """Cutting power ``P_total - P_tare`` [W] (or the measured ``cutting_power``).

        Parameters
        ----------
        tare : array_like, optional
            Tare power [W] to use where the cuts have none (e.g. from a model).

        Returns
        -------
        ndarray
        """
        if self.cutting_power is not None:
            return self.cutting_power
        t = self.tare_power if self.tare_power is not None else tare
        if t is None:
            raise MissingChannelError("no 'tare_power' for the cuts and no tare model to take it from")
        return self.total_power - np.asarray(t, dtype=float)

    def speed_groups(self) -> list[np.ndarray]:
        """Indices of the cuts at each slide speed (speeds within 1 % share a group), by increasing speed.

        Returns
        -------
        list of ndarray of int
        """
        return _groups(self.slide_speed)

    def subset(self, idx) -> "FeedCuts":
        """The cuts at indices `idx`.

        Parameters
        ----------
        idx : array_like of int or bool
            Which cuts.

        Returns
        -------
        FeedCuts
        """
        idx = np.flatnonzero(np.asarray(idx)) if np.asarray(idx).dtype == bool else np.asarray(idx, dtype=int)
        pick = {k: (None if getattr(self, k) is None else getattr(self, k)[idx])
                for k in ("total_power", "tare_power", "cutting_power", "force_x", "slide_position")}
        return FeedCuts(self.slide_speed[idx], labels=tuple(self.labels[i] for i in idx), name=self.name, **pick)


def read_feed_cuts(path) -> FeedCuts:
    """Read cuts from a CSV with ``name [unit]`` headers (one cut per row).

    Columns: ``slide_speed`` (e.g. ``[mm/min]``, ``[in/min]``), ``total_power`` and ``tare_power``
    (``[W]``, ``[hp]``...) or ``cutting_power``; ``force_x`` (``[N]``, ``[lbf]``) to fit; optional
    ``slide_position``. A ``cut`` column labels the rows; other columns are ignored.

    Parameters
    ----------
    path : str or Path
        The CSV file.

    Returns
    -------
    FeedCuts

    Raises
    ------
    ConfigError
        Missing columns, negative or zero speeds (naming the cut).
    InvalidSignalError, UnitError
        No rows, a non-number, a unit that does not fit the column.
    """
    path = Path(path)
    cols, text, n = read_unit_table(path, _COLUMNS)
    if "slide_speed" not in cols:
        raise ConfigError(f"{path.name}: no 'slide_speed' column (e.g. 'slide_speed [mm/min]')")
    labels = tuple(text.get("cut", ())) or tuple(str(i + 1) for i in range(n))
    try:
        return FeedCuts(cols["slide_speed"], cols.get("total_power"), cols.get("tare_power"),
                        cols.get("cutting_power"), cols.get("force_x"), cols.get("slide_position"), labels,
                        path.stem)
    except ConfigError as exc:
        raise ConfigError(f"{path.name}: {exc}") from None


@dataclass(frozen=True)
class SpeedFit:
    """Straight line ``F_x = slope P_cut + intercept`` of the cuts at one slide speed (Fig. 14).

    Attributes
    ----------
    speed : float
        Slide speed [m/s].
    slope : float
        [N/W].
    intercept : float
        [N].
    r2 : float
        Coefficient of determination [-] (NaN with fewer than 3 cuts).
    cuts : int
        Number of cuts.
    """

    speed: float
    slope: float
    intercept: float
    r2: float
    cuts: int


def _groups(v: np.ndarray) -> list[np.ndarray]:
    order = np.argsort(v)
    groups, current = [], [order[0]]
    for i in order[1:]:
        if v[i] - v[current[0]] <= _SPEED_TOL * v[current[0]]:
            current.append(i)
        else:
            groups.append(np.array(current))
            current = [i]
    groups.append(np.array(current))
    return groups


def per_speed_fits(cuts: FeedCuts) -> list[SpeedFit]:
    """One straight line of force against cutting power per slide speed (the paper's Fig. 14).

    Parameters
    ----------
    cuts : FeedCuts
        Cuts with ``force_x``.

    Returns
    -------
    list of SpeedFit
        By increasing speed; speeds with a single cut are left out.
    """
    if cuts.force_x is None:
        raise MissingChannelError("per-speed fits need a reference 'force_x' for each cut")
    p, f = cuts.power(), cuts.force_x
    out = []
    for g in _groups(cuts.slide_speed):
        if g.size < 2 or np.ptp(p[g]) == 0:
            continue
        slope, icpt = np.polyfit(p[g], f[g], 1)
        ss = float(np.sum((f[g] - f[g].mean()) ** 2))
        r2 = 1 - float(np.sum((f[g] - slope * p[g] - icpt) ** 2)) / ss if g.size > 2 and ss > 0 else float("nan")
        out.append(SpeedFit(float(np.mean(cuts.slide_speed[g])), float(slope), float(icpt), r2, int(g.size)))
    return out


@dataclass(frozen=True)
class FeedPowerModel(JsonFileMixin):
    """``F_x = (a0 + a1 v) P_cut / v + F0`` with its calibrated range.

    Parameters
    ----------
    a0 : float
        Efficiency at zero speed [-] (sign = force direction).
    a1 : float
        Efficiency slope with slide speed [s/m].
    f0 : float
        Force offset [N].
    speed_range : tuple of float
        Calibrated slide speeds (min, max) [m/s].
    tare_speeds, tare_powers : tuple of float
        Mean tare power [W] at each calibrated speed [m/s] (used when a cut to predict has no tare).
    position_range : tuple of float, optional
        Calibrated slide positions (min, max) [m].
    rms_error : float
        Residual rms of the fit [N].
    cuts : int
        Cuts fitted.
    """

    a0: float
    a1: float
    f0: float
    speed_range: tuple
    tare_speeds: tuple = ()
    tare_powers: tuple = ()
    position_range: tuple | None = None
    rms_error: float = float("nan")
    cuts: int = 0

    #: Named in the errors of :meth:`load` (:class:`~drivesense.io.JsonFileMixin`).
    json_what = "model file"

    def efficiency(self, slide_speed):
        """``eta(v) = |a0 + a1 v|`` (the paper's efficiency; includes the power sensor's scale).

        Parameters
        ----------
        slide_speed : float or array_like
            [m/s].

        Returns
        -------
        float or ndarray
        """
        v = np.asarray(slide_speed, dtype=float)
        out = np.abs(self.a0 + self.a1 * v)
        return float(out) if out.ndim == 0 else out

    def coverage_flags(self, cuts: FeedCuts) -> list[str]:
        """Why each cut lies outside the calibrated range, or ``""`` where it lies inside.

        Parameters
        ----------
        cuts : FeedCuts
            Cuts with slide speed (and slide position, if the model has a position range).

        Returns
        -------
        list of str
            Per cut: ``""``, or a sentence naming the slide speed or position and
            the calibrated range.
        """
        v = cuts.slide_speed
        lo, hi = self.speed_range
        tol = _SPEED_TOL * hi
        flags = [f"slide speed {s * 6e4:.4g} mm/min is outside the calibrated range {lo * 6e4:.4g}-{hi * 6e4:.4g} "
                 "mm/min; calibrate at that speed first" if (s < lo - tol or s > hi + tol) else "" for s in v]
        if cuts.slide_position is not None and self.position_range is not None:
            plo, phi = self.position_range
            for i, x in enumerate(cuts.slide_position):
                if not flags[i] and not plo <= x <= phi:
                    flags[i] = (f"slide position {x * 1e3:.4g} mm is outside the calibrated {plo * 1e3:.4g}-"
                                f"{phi * 1e3:.4g} mm (the tare changes there, e.g. where a slide cover extends)")
        return flags

    def predict(self, cuts: FeedCuts, *, skip_out_of_range: bool = False) -> np.ndarray:
        """Average x-force of each cut [N].

        Parameters
        ----------
        cuts : FeedCuts
            Cuts with slide speed and power (tare from the model where they have none).
        skip_out_of_range : bool, optional
            Give NaN for the cuts outside the calibrated range (see
            :meth:`coverage_flags`) instead of refusing the whole set, as long as
            one cut lies inside.

        Returns
        -------
        ndarray

        Raises
        ------
        CoverageError
            A slide speed (or position) outside the calibrated range, naming the cut
            (with `skip_out_of_range`: only when every cut lies outside).
        """
        v = cuts.slide_speed
        flags = self.coverage_flags(cuts)
        bad = [i for i, f in enumerate(flags) if f]
        if bad and (not skip_out_of_range or len(bad) == len(flags)):
            raise CoverageError(f"cut {cuts.labels[bad[0]]}: {flags[bad[0]]}")
        tare = None
        if cuts.cutting_power is None and cuts.tare_power is None:
            if not self.tare_speeds:
                raise MissingChannelError("the cuts have no 'tare_power' and the model holds no tare table")
            tare = np.interp(v, self.tare_speeds, self.tare_powers)
        force = (self.a0 + self.a1 * v) * cuts.power(tare) / v + self.f0
        force[bad] = np.nan
        return force

    def to_dict(self) -> dict:
        """JSON-ready parameters (SI).

        Returns
        -------
        dict
        """
        d = asdict(self)
        d["version"] = _MODEL_VERSION
        d["model"] = "F_x = (a0 + a1 v) (P_total - P_tare) / v + f0, SI (N, W, m/s)"
        d["rms_error"] = None if not math.isfinite(self.rms_error) else self.rms_error
        return d

    @classmethod
    def from_dict(cls, data: dict) -> "FeedPowerModel":
        """Build a model from :meth:`to_dict` output.

        Parameters
        ----------
        data : dict
            Parameters.

        Returns
        -------
        FeedPowerModel
        """
        if not isinstance(data, dict) or data.get("version") != _MODEL_VERSION:
            raise ConfigError(f"not a feed-power model (version {_MODEL_VERSION}) file")
        try:
            return cls(float(data["a0"]), float(data["a1"]), float(data["f0"]), tuple(data["speed_range"]),
                       tuple(data.get("tare_speeds", ())), tuple(data.get("tare_powers", ())),
                       None if data.get("position_range") is None else tuple(data["position_range"]),
                       float(data["rms_error"]) if data.get("rms_error") is not None else float("nan"),
                       int(data.get("cuts", 0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"feed-power model: missing or bad field ({exc})") from None


def fit_feed_power(cuts: FeedCuts) -> FeedPowerModel:
    """Calibrate ``F_x = (a0 + a1 v) P_cut / v + F0`` on cuts with a reference force.

    Parameters
    ----------
    cuts : FeedCuts
        Calibration cuts with ``force_x``, at two or more slide speeds.

    Returns
    -------
    FeedPowerModel

    Raises
    ------
    MissingChannelError
        No ``force_x``.
    IdentificationError
        Fewer than 4 cuts or a single slide speed (efficiency versus speed undetermined).
    """
    if cuts.force_x is None:
        raise MissingChannelError("fitting needs a reference 'force_x' column (dynamometer) for each cut")
    v, p, f = cuts.slide_speed, cuts.power(), cuts.force_x
    speeds = _groups(v)
    if len(cuts) < 4 or len(speeds) < 2:
        raise IdentificationError(f"efficiency versus slide speed: {len(cuts)} cut(s) at {len(speeds)} speed(s); "
                                  "calibrate with 4 or more cuts at 2 or more slide speeds")
    X = np.column_stack([p / v, p, np.ones_like(p)])
    (a0, a1, f0), *_ = np.linalg.lstsq(X, f, rcond=None)
    resid = f - X @ np.array([a0, a1, f0])
    tare_v, tare_p = (), ()
    if cuts.tare_power is not None:
        tare_v = tuple(float(np.mean(v[g])) for g in speeds)
        tare_p = tuple(float(np.mean(cuts.tare_power[g])) for g in speeds)
    pos = None if cuts.slide_position is None else (float(cuts.slide_position.min()),
                                                    float(cuts.slide_position.max()))
    return FeedPowerModel(float(a0), float(a1), float(f0), (float(v.min()), float(v.max())), tare_v, tare_p, pos,
                          float(np.sqrt(np.mean(resid ** 2))), len(cuts))


def cross_validate(cuts: FeedCuts, *, speeds_out=None) -> dict:
    """Leave-one-cut-out and leave-one-speed-out errors of :func:`fit_feed_power`.

    Parameters
    ----------
    cuts : FeedCuts
        Cuts with ``force_x``.
    speeds_out : sequence of float, optional
        Slide speeds [m/s] to leave out in turn (default: every speed strictly inside the range,
        so that the left-out speed is interpolated).

    Returns
    -------
    dict
        ``loco_errors`` (|relative error| per cut), ``loco_mean_error``, ``loso`` (list of
        ``{"speed_m_s", "mean_error", "max_error"}``).
    """
    f = cuts.force_x
    if f is None:
        raise MissingChannelError("cross-validation needs a reference 'force_x' for each cut")
    n = len(cuts)
    loco = []
    for i in range(n):
        keep = np.arange(n) != i
        model = fit_feed_power(cuts.subset(keep))
        try:
            pred = model.predict(cuts.subset([i]))[0]
            loco.append(abs(pred / f[i] - 1))
        except CoverageError:          # an end speed's only cut: nothing to interpolate from
            loco.append(float("nan"))
    groups = _groups(cuts.slide_speed)
    centres = [float(np.mean(cuts.slide_speed[g])) for g in groups]
    if speeds_out is None:
        speeds_out = centres[1:-1]
    loso = []
    for s in speeds_out:
        g = next((g for g, c in zip(groups, centres) if abs(c - s) <= _SPEED_TOL * max(c, s)), None)
        if g is None:
            raise ConfigError(f"no cuts at slide speed {s * 6e4:.4g} mm/min to leave out")
        keep = np.setdiff1d(np.arange(n), g)
        model = fit_feed_power(cuts.subset(keep))
        err = np.abs(model.predict(cuts.subset(g)) / f[g] - 1)
        loso.append({"speed_m_s": s, "mean_error": float(err.mean()), "max_error": float(err.max())})
    loco = np.array(loco)
    return {"loco_errors": [None if not math.isfinite(e) else float(e) for e in loco],
            "loco_mean_error": float(np.nanmean(loco)), "loso": loso}
