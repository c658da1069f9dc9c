"""Four-step identification of linear-motor axes from air moves (third paper, Sec. 2.2, Eq. 3-10).

Per axis, from NC traces of moves without cutting:

1. **Restoring force and rest point** -- on constant-velocity segments, the
   motor force ``K_m I`` of the positive and negative passes at the same
   speed is averaged over position (friction is odd in the velocity and
   cancels); a first-degree polynomial over position gives ``k`` and ``s_r``.
2. **Cogging** -- the residual of that average, binned over position modulo
   the pole pitch, is the cogging lookup table.  Steps 1 and 2 alternate a
   few times so that a cogging period cut off at the travel ends does not
   leak into the line.
3. **Stribeck friction** -- ``K_m I - F_co(s) - k (s - s_r)`` (Eq. 5) averaged
   over each constant-velocity segment is fitted with Eq. 4 (``delta = 2``)
   by trust-region-reflective least squares (Eq. 6).
4. **Masses** -- on accelerated samples (away from standstill), what is left
   after friction (Eq. 7) is fitted jointly for ``m_x, m_y, m_z`` with the
   stacked masses of Eq. 8-10.
5. **Presliding distance** (beyond the paper) -- with steps 1-4 fixed, the
   distance ``x_pre`` of the Dahl friction state
   (:func:`~drivesense.machine.presliding.presliding_direction`) is the
   bounded scalar minimiser of the Eq. 2 residual over every sample of the
   air moves: the starts and reversals of the slow moves determine it, and
   the standing axis's micro-motion while the others move.  When the moves do
   not determine it (a flat residual), ``x_pre`` stays 0 and the report says so.

The motor constants are catalogue values (air moves cannot separate ``K_m``
from the rest: every term scales with it); they are taken from the
argument or from the traces' ``meta["motor_constants_n_per_a"]``.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import optimize

from drivesense.errors import ConfigError, CoverageError
from drivesense.identify.presliding import fit_presliding
from drivesense.machine.linear_motor import AXES, LinearMotorAxis, ThreeAxisModel
from drivesense.recording import Recording

__all__ = ["IdentificationReport", "IdentificationWarning", "identify_axes", "run_identification", "constant_velocity_segments",
           "direction_averaged", "fit_restoring", "fit_cogging_table", "fit_stribeck", "fit_masses", "fit_presliding",
           "STACKING"]

#: Which own masses each motor moves (Eq. 2 / 8-10): rows x, y, z; columns m_x, m_y, m_z.
STACKING = np.array([[1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 1.0]])


def _rolling(x: np.ndarray, half: int, fn) -> np.ndarray:
    pad = np.pad(x, half, mode="edge")
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1)
    return fn(win, axis=1)


def constant_velocity_segments(velocity, fs: float, *, min_speed: float = 2.5e-4, window: float = 0.15,
                               rel_tol: float = 0.05, abs_tol: float = 1.0e-4,
                               min_duration: float = 0.3) -> list[slice]:
    """Stretches where the axis moves at a steady, non-zero velocity.

    Parameters
    ----------
    velocity : array_like
        Axis velocity [m/s].
    fs : float
        Sample rate [Hz].
    min_speed : float
        Smallest speed that counts as moving [m/s].
    window : float
        Half-width of the steadiness window around each sample [s].
    rel_tol, abs_tol : float
        The velocity may vary by ``rel_tol |v| + abs_tol`` [m/s] within the window.
    min_duration : float
        Shortest segment kept [s].

    Returns
    -------
    list of slice
        Sample ranges of the segments.
    """
    v = np.asarray(velocity, dtype=float)
    half = max(1, int(round(window * fs)))
    if v.size < 2 * half + 2:
        return []
    vmax = _rolling(v, half, np.max)
    vmin = _rolling(v, half, np.min)
    steady = ((vmax - vmin) <= rel_tol * np.abs(v) + abs_tol) & (np.abs(v) >= min_speed) & (vmax * vmin > 0)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], steady.astype(np.int8), [0]))))
    out = []
    for a, b in zip(edges[::2], edges[1::2]):
        if (b - a) / fs >= min_duration:
            out.append(slice(int(a), int(b)))
    return out


def direction_averaged(position_pos, force_pos, position_neg, force_neg) -> tuple[np.ndarray, np.ndarray]:
    """Average the forces of a positive and a negative pass at the same positions (step 1).

    Parameters
    ----------
    position_pos, force_pos : array_like
        Position [m] and motor force [N] of the pass in +direction.
    position_neg, force_neg : array_like
        Position [m] and motor force [N] of the pass in -direction.

    Returns
    -------
    position, force : ndarray
        The +pass positions inside the overlap of both passes [m] and
        ``(F_+(s) + F_-(s)) / 2`` there [N] (the negative pass interpolated).
    """
    sp, fp = np.asarray(position_pos, float), np.asarray(force_pos, float)
    sn, fn = np.asarray(position_neg, float), np.asarray(force_neg, float)
    order = np.argsort(sn)
    sn, fn = sn[order], fn[order]
    keep = (sp >= sn[0]) & (sp <= sn[-1])
    return sp[keep], 0.5 * (fp[keep] + np.interp(sp[keep], sn, fn))


def fit_restoring(position, force) -> dict:
    """Linear regression ``F = k (s - s_r)`` of the direction-averaged force (step 1).

    Parameters
    ----------
    position : array_like
        Position [m].
    force : array_like
        Direction-averaged motor force (cogging removed where known) [N].

    Returns
    -------
    dict
        ``k`` [N/m], ``s_r`` [m], ``r2`` [-], ``rms_n`` [N], ``points``.

    Raises
    ------
    CoverageError
        If the positions span less than 1 mm or the slope is zero.
    """
    s = np.asarray(position, float)
    f = np.asarray(force, float)
    if s.size < 3 or np.ptp(s) < 1e-3:
        raise CoverageError("restoring force: the direction-averaged data span "
                            f"{np.ptp(s) * 1e3 if s.size else 0:.3g} mm of travel; need moves in both "
                            "directions over a stretch of the travel at the same speed")
    A = np.column_stack([s, np.ones_like(s)])
    (k, c0), *_ = np.linalg.lstsq(A, f, rcond=None)
    if k == 0:
        raise CoverageError("restoring force: zero slope, the rest point is undetermined")
    res = f - A @ np.array([k, c0])
    var = np.var(f)
    return {"k": float(k), "s_r": float(-c0 / k), "r2": float(1 - np.var(res) / var) if var > 0 else 1.0,
            "rms_n": float(np.sqrt(np.mean(res ** 2))), "points": int(s.size)}


def fit_cogging_table(position, residual, pole_pitch: float, size: int = 64) -> np.ndarray:
    """Cogging lookup table from a residual binned over position modulo the pole pitch (step 2).

    Parameters
    ----------
    position : array_like
        Position [m].
    residual : array_like
        Direction-averaged force minus the restoring line [N].
    pole_pitch : float
        Pole pitch [m].
    size : int
        Table points over one pitch (bin ``j`` centred on ``j pole_pitch / size``).

    Returns
    -------
    ndarray, shape (size,)
        Cogging force [N], zero mean.

    Raises
    ------
    CoverageError
        If some bin holds no sample (the data cover less than one pole pitch).
    """
    s = np.asarray(position, float)
    r = np.asarray(residual, float)
    j = np.floor(np.mod(s, pole_pitch) / pole_pitch * size + 0.5).astype(np.int64) % size
    count = np.bincount(j, minlength=size)
    if np.any(count == 0):
        raise CoverageError(f"cogging: {int(np.sum(count == 0))} of {size} bins over the {pole_pitch * 1e3:g} mm "
                            "pole pitch hold no data; move over at least one pole pitch in both directions")
    table = np.bincount(j, weights=r, minlength=size) / count
    return table - table.mean()


def _stribeck(p, v, delta):
    fc, fbr, vs, sig = p
    return np.sign(v) * (fc + (fbr - fc) * np.exp(-np.abs(v / vs) ** delta)) + sig * v


def _speed_list(speeds: np.ndarray) -> str:
    return ", ".join(dict.fromkeys(f"{s * 1e3:.3g}" for s in speeds))


def _coulomb_viscous(v: np.ndarray, f: np.ndarray, speeds: np.ndarray, why: str) -> dict:
    """Step 3's fallback: ``sgn(v) F_C + sigma v`` by non-negative least squares, ``F_br = F_C``."""
    A = np.column_stack([np.ones_like(v), np.abs(v)])
    fa = np.sign(v) * f
    x, _ = optimize.nnls(A, fa)
    resid = fa - A @ x
    s2 = float(resid @ resid) / max(v.size - 2, 1)
    try:
        rel = np.sqrt(np.abs(np.diag(np.linalg.inv(A.T @ A) * s2))) / np.maximum(np.abs(x), 1e-12)
    except np.linalg.LinAlgError:
        rel = np.full(2, np.inf)
    if not rel[0] <= 0.5 or not (rel[1] <= 0.5 or x[1] < 1e-6):
        raise CoverageError(f"{why}; nor do they determine Coulomb and viscous friction alone")
    fc, sig = float(x[0]), float(x[1])
    return {"F_C": fc, "F_br": fc, "v_s": 0.5 * float(speeds.min()), "sigma": sig,
            "rms_n": float(np.sqrt(np.mean(resid ** 2))), "points": int(v.size),
            "rel_std": {"F_C": float(rel[0]), "F_br": None, "v_s": None, "sigma": float(rel[1])},
            "undetermined": ["F_br", "v_s"], "fallback": f"{why}: Coulomb + viscous friction, F_br = F_C and v_s "
                                                          "half the slowest speed (no effect while F_br = F_C)"}


def fit_stribeck(velocity, friction, *, delta: float = 2.0, strict: bool = True) -> dict:
    """Stribeck parameters of Eq. 4 by trust-region-reflective least squares (step 3, Eq. 6).

    Parameters
    ----------
    velocity : array_like
        Velocity of each point [m/s] (e.g. segment means), both signs allowed.
    friction : array_like
        Friction force at those velocities (Eq. 5) [N].
    delta : float
        Stribeck shape factor [-].
    strict : bool
        Refuse when the speeds do not determine the Stribeck curve (default).
        False: fall back to Coulomb plus viscous friction (``sgn(v) F_C +
        sigma v`` by non-negative least squares, ``F_br = F_C`` and ``v_s``
        half the slowest speed, where it has no effect) and list ``F_br`` and
        ``v_s`` as ``undetermined``.  Air moves at ordinary speeds (above a
        few mm/s) never reach the Stribeck hump, and the machine's friction
        there is what the fallback fits.

    Returns
    -------
    dict
        ``F_C``, ``F_br`` [N], ``v_s`` [m/s], ``sigma`` [N s/m], ``rms_n`` [N],
        ``points`` and ``rel_std`` (relative standard error of each; None
        where undetermined); after a fallback also ``undetermined`` (the
        names) and ``fallback`` (why and what).

    Raises
    ------
    CoverageError
        Fewer than 4 distinct speeds, or a parameter the speeds do not
        determine (relative standard error above 50 %); not strict: fewer
        than 2 speeds, or speeds that do not even determine ``F_C`` and ``sigma``.
    """
    v = np.asarray(velocity, float)
    f = np.asarray(friction, float)
    speeds = np.unique(np.round(np.abs(v[v != 0]), 6))
    if speeds.size < (4 if strict else 2):
        raise CoverageError(f"Stribeck friction: constant-velocity data at {speeds.size} distinct speed(s); "
                            "need at least 4, some below and some well above the Stribeck velocity")
    if speeds.size < 4:
        return _coulomb_viscous(v, f, speeds, f"Stribeck friction: {speeds.size} distinct speeds "
                                f"({_speed_list(speeds)} mm/s) do not determine F_br, v_s")
    fa = np.sign(v) * f
    hi = np.abs(v) >= np.median(np.abs(v))
    sig0, fc0 = np.polyfit(np.abs(v[hi]), fa[hi], 1) if np.unique(np.abs(v[hi])).size > 1 else (0.0, fa.mean())
    fc0 = max(fc0, 1e-3)
    p0 = [fc0, max(fa.max(), fc0 * 1.01), float(np.median(speeds[: max(2, speeds.size // 3)])), max(sig0, 0.0)]
    res = optimize.least_squares(lambda p: _stribeck(p, v, delta) - f, p0, method="trf",
                                 bounds=([0.0, 0.0, 1e-6, 0.0], [np.inf, np.inf, 10.0, np.inf]),
                                 x_scale=[max(fc0, 1.0), max(fc0, 1.0), p0[2], max(abs(sig0), 1.0)])
    names = ("F_C", "F_br", "v_s", "sigma")
    resid = res.fun
    dof = max(v.size - 4, 1)
    s2 = float(resid @ resid) / dof
    try:
        cov = np.linalg.inv(res.jac.T @ res.jac) * s2
        rel = np.sqrt(np.abs(np.diag(cov))) / np.maximum(np.abs(res.x), 1e-12)
    except np.linalg.LinAlgError:
        rel = np.full(4, np.inf)
    out = {n: float(x) for n, x in zip(names, res.x)}
    out.update(rms_n=float(np.sqrt(np.mean(resid ** 2))), points=int(v.size),
               rel_std={n: float(r) for n, r in zip(names, rel)})
    bad = [n for n, r in zip(names, rel) if not r <= 0.5 and not (n == "sigma" and out[n] < 1e-6)]
    if bad and not strict:
        return _coulomb_viscous(v, f, speeds, f"Stribeck friction: the speeds {_speed_list(speeds)} mm/s do not "
                                f"determine {', '.join(bad)}")
    if bad:
        raise CoverageError(f"Stribeck friction: the speeds {_speed_list(speeds)} mm/s do not determine "
                            f"{', '.join(bad)} (relative standard error > 50 %); add constant-velocity moves "
                            "below and around the Stribeck velocity")
    return out


def fit_masses(accelerations: dict, forces: dict) -> dict:
    """Own masses ``m_x, m_y, m_z`` from accelerated data by joint least squares (step 4, Eq. 7-10).

    Parameters
    ----------
    accelerations : dict of str to array_like
        Axis letter -> acceleration samples [m/s^2].
    forces : dict of str to array_like
        Axis letter -> Eq. 7 residual force at those samples [N].

    Returns
    -------
    dict
        ``m`` (own masses by axis) [kg], ``stacked`` (mass each motor moves)
        [kg], ``rms_n`` and ``r2`` per axis, ``samples`` per axis.

    Raises
    ------
    CoverageError
        If an axis has no accelerated samples (the stacked masses need all three).
    """
    rows, rhs, which = [], [], []
    for i, ax in enumerate(AXES):
        a = np.asarray(accelerations.get(ax, ()), float)
        if a.size < 10 or np.sqrt(np.mean(a ** 2)) < 1e-3:
            raise CoverageError(f"masses: no accelerated moves of axis '{ax}' (Eq. 8-10 solve m_x, m_y, m_z "
                                "jointly and need accelerated moves of all three axes)")
        rows.append(a[:, None] * STACKING[i][None, :])
        rhs.append(np.asarray(forces[ax], float))
        which.append(np.full(a.size, i))
    A, b, w = np.vstack(rows), np.concatenate(rhs), np.concatenate(which)
    scale = np.array([1.0 / np.sqrt(np.sum(w == i)) for i in range(3)])[w]   # each axis weighs the same
    m, *_ = np.linalg.lstsq(A * scale[:, None], b * scale, rcond=None)
    out = {"m": {ax: float(m[i]) for i, ax in enumerate(AXES)},
           "stacked": {ax: float(STACKING[i] @ m) for i, ax in enumerate(AXES)}, "rms_n": {}, "r2": {}, "samples": {}}
    for i, ax in enumerate(AXES):
        sel = w == i
        res = b[sel] - A[sel] @ m
        out["rms_n"][ax] = float(np.sqrt(np.mean(res ** 2)))
        out["r2"][ax] = float(1 - np.var(res) / np.var(b[sel])) if np.var(b[sel]) > 0 else 1.0
        out["samples"][ax] = int(sel.sum())
    return out


# ------------------------------------------------------------------ driver
@dataclass
class IdentificationReport:
    """Result and fit quality of the four-step identification.

    Attributes
    ----------
    model : ThreeAxisModel
        The identified axes.
    steps : dict
        Per axis, per step (``restoring``, ``cogging``, ``friction``,
        ``mass``, ``presliding``), the fitted values and their fit quality (RMS residual [N],
        R^2, number of points).
    seconds : dict
        Wall time of steps 1-3 per axis and of the joint mass step [s].
    """

    model: ThreeAxisModel
    steps: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain dict for JSON: the model, the steps and the timings."""
        return {"model": self.model.to_dict(), "steps": self.steps, "seconds": self.seconds}


class IdentificationWarning(UserWarning):
    """The identification went on with something the user should know: a fallback, or a given value that
    disagrees with the data."""


def _motor_constants(recordings: Sequence[Recording], given) -> dict:
    if given is not None:
        bad = [a for a in AXES if a not in given]
        if bad:
            raise ConfigError(f"motor constants (--km): missing axis/axes {', '.join(bad)} (give --km x=...,y=...,z=... "
                              "in N/A)")
        kms = {a: float(given[a]) for a in AXES}
        for a in AXES:
            carried = [(rec.name, float(rec.meta["motor_constants_n_per_a"][a])) for rec in recordings
                       if isinstance(rec.meta.get("motor_constants_n_per_a"), dict)
                       and isinstance(rec.meta["motor_constants_n_per_a"].get(a), (int, float))]
            other = [(name, km) for name, km in carried if not math.isclose(km, kms[a], rel_tol=1e-6)]
            if other:
                name, km = other[0]
                warnings.warn(f"axis '{a}': the given motor constant --km {a}={kms[a]:g} N/A disagrees with the "
                              f"{km:g} N/A the trace '{name}' carries in its metadata"
                              + (f" (and {len(other) - 1} more trace(s))" if len(other) > 1 else "")
                              + f"; using the given {kms[a]:g} N/A (leave --km out to use the traces' constants)",
                              IdentificationWarning, stacklevel=3)
        return kms
    for rec in recordings:
        km = rec.meta.get("motor_constants_n_per_a")
        if isinstance(km, dict) and all(a in km for a in AXES):
            return {a: float(km[a]) for a in AXES}
    raise ConfigError("motor constants unknown: the traces carry none in their metadata; give --km x=...,y=...,z=... "
                      "[N/A] (catalogue values; air moves cannot determine them)")


def _axis_data(recordings: Sequence[Recording], ax: str, km: float) -> list[dict]:
    chans = [f"{ax}_{c}" for c in ("current", "position", "velocity", "acceleration")]
    out = []
    for rec in recordings:
        rec.require(*chans)
        out.append({"F": km * np.asarray(rec[chans[0]]), "s": np.asarray(rec[chans[1]]),
                    "v": np.asarray(rec[chans[2]]), "a": np.asarray(rec[chans[3]]), "fs": rec.fs,
                    "segs": constant_velocity_segments(rec[chans[2]], rec.fs)})
    return out


def _speed_pairs(data: list[dict]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(s+, F+, s-, F-) for every positive segment with a negative one at the same speed (within 5 %)."""
    segs = [(d, sl, float(np.mean(d["v"][sl]))) for d in data for sl in d["segs"]]
    pairs = []
    for d, sl, vm in segs:
        if vm <= 0:
            continue
        negs = [(d2, sl2) for d2, sl2, v2 in segs if v2 < 0 and abs(abs(v2) - vm) <= 0.05 * vm]
        if not negs:
            continue
        sn = np.concatenate([d2["s"][sl2] for d2, sl2 in negs])
        fn = np.concatenate([d2["F"][sl2] for d2, sl2 in negs])
        pairs.append((d["s"][sl], d["F"][sl], sn, fn))
    return pairs


def _identify_axis(data: list[dict], ax: str, km: float, pole_pitch: float, size: int, delta: float,
                   strict: bool):
    pairs = _speed_pairs(data)
    if not pairs:
        raise CoverageError(f"axis '{ax}': no constant-velocity moves in both directions at the same speed; "
                            "step 1 (restoring force) averages a positive and a negative pass")
    pos, avg = [], []
    for sp, fp, sn, fn in pairs:
        s, f = direction_averaged(sp, fp, sn, fn)
        pos.append(s)
        avg.append(f)
    s_all, f_all = np.concatenate(pos), np.concatenate(avg)
    table = np.zeros(size)
    probe = LinearMotorAxis(K_m=km, k=0.0, s_r=0.0, m=1.0, F_C=0.0, F_br=0.0, v_s=1.0, sigma=0.0,
                            cogging=table, pole_pitch=pole_pitch)
    for _ in range(4):   # alternate steps 1 and 2
        rest = fit_restoring(s_all, f_all - probe.cogging_force(s_all))
        table = fit_cogging_table(s_all, f_all - rest["k"] * (s_all - rest["s_r"]), pole_pitch, size)
        probe = probe.with_values(cogging=table, k=rest["k"], s_r=rest["s_r"])
    cog_res = f_all - probe.restoring_force(s_all) - probe.cogging_force(s_all)
    amps = probe.cogging_amplitudes(3)
    steps = {"restoring": rest,
             "cogging": {"rms_residual_n": float(np.sqrt(np.mean(cog_res ** 2))), "table_size": size,
                         "pole_pitch_m": pole_pitch, "amplitudes_n": [float(a) for a in amps],
                         "points": int(s_all.size)}}
    vm, fm = [], []
    for d in data:
        for sl in d["segs"]:
            ftil = d["F"][sl] - probe.cogging_force(d["s"][sl]) - probe.restoring_force(d["s"][sl])
            vm.append(float(np.mean(d["v"][sl])))
            fm.append(float(np.mean(ftil)))
    try:
        fr = fit_stribeck(vm, fm, delta=delta, strict=strict)
    except CoverageError as exc:
        raise CoverageError(f"axis '{ax}': {exc}") from None
    if fr.get("undetermined"):
        slowest = min(abs(x) for x in vm)
        warnings.warn(f"axis '{ax}': the air moves' speeds ({slowest * 1e3:.3g} mm/s and faster) do not determine "
                      f"the Stribeck curve's {' and '.join(fr['undetermined'])}; using Coulomb + viscous friction "
                      f"(F_br = F_C = {fr['F_C']:.3g} N, sigma = {fr['sigma']:.4g} N s/m, v_s = "
                      f"{fr['v_s'] * 1e3:.3g} mm/s without effect), marked undetermined in AXES.toml. Add "
                      f"constant-velocity moves slower than {slowest * 1e3:.3g} mm/s to identify them, or give "
                      "--strict to refuse", IdentificationWarning, stacklevel=3)
    fr["data"] = {"velocity_m_s": vm, "force_n": fm}
    steps["friction"] = fr
    axis = probe.with_values(F_C=fr["F_C"], F_br=fr["F_br"], v_s=fr["v_s"], sigma=fr["sigma"], delta=delta,
                             undetermined=tuple(fr.get("undetermined", ())))
    return axis, steps


def run_identification(air_moves: Sequence[Recording], *, motor_constants: dict | None = None,
                       pole_pitch: float = 0.023, table_size: int = 64, delta: float = 2.0,
                       min_accel: float = 0.3, min_accel_speed: float | None = None,
                       presliding: bool = True, strict: bool = False) -> IdentificationReport:
    """Identify the three axes by the four-step method, with the fit quality of every step.

    Parameters
    ----------
    air_moves : sequence of Recording
        NC traces without cutting, each with ``{ax}_current`` [A],
        ``{ax}_position`` [m], ``{ax}_velocity`` [m/s] and
        ``{ax}_acceleration`` [m/s^2] of x, y and z; together they must hold,
        per axis, constant-velocity moves in both directions over at least one
        pole pitch, at 4 or more speeds, and accelerated moves.
    motor_constants : dict of str to float, optional
        ``K_m`` per axis [N/A]; default: the traces' ``meta["motor_constants_n_per_a"]``.
        A given constant that disagrees with one a trace carries is used, with
        an :class:`IdentificationWarning` naming the axis and both values.
    pole_pitch : float
        Pole pitch of the motors [m].
    table_size : int
        Points of the cogging table.
    delta : float
        Stribeck shape factor [-] (fixed, as in the paper).
    min_accel : float
        Smallest |acceleration| used for the masses [m/s^2].
    min_accel_speed : float, optional
        Smallest |velocity| used for the masses [m/s] (stiction is not in the
        model); default ``max(3 v_s, 5 mm/s)``.
    presliding : bool
        Run step 5 (the presliding distance ``x_pre``); False leaves it 0
        (the paper's model).
    strict : bool
        Refuse (CoverageError) when the constant-velocity speeds do not
        determine the Stribeck curve.  Default: fall back to Coulomb plus
        viscous friction for that axis (see :func:`fit_stribeck`), list
        ``F_br`` and ``v_s`` in the axis's ``undetermined`` (written to
        AXES.toml) and warn (:class:`IdentificationWarning`).

    Returns
    -------
    IdentificationReport

    Raises
    ------
    CoverageError
        When the moves cannot determine a step; the message names the axis and step.
    ConfigError
        Unknown motor constants, no recordings.
    MissingChannelError
        A trace lacks a channel.
    """
    recs = list(air_moves)
    if not recs or not all(isinstance(r, Recording) for r in recs):
        raise ConfigError("identification needs a non-empty list of Recordings (air moves)")
    kms = _motor_constants(recs, motor_constants)
    axes, steps, seconds, acc, frc = {}, {}, {}, {}, {}
    for ax in AXES:
        t0 = time.perf_counter()
        data = _axis_data(recs, ax, kms[ax])
        axis, st = _identify_axis(data, ax, kms[ax], pole_pitch, table_size, delta, strict)
        v_min = min_accel_speed if min_accel_speed is not None else max(3 * axis.v_s, 5e-3)
        a_list, f_list = [], []
        for d in data:
            sel = (np.abs(d["a"]) >= min_accel) & (np.abs(d["v"]) >= v_min)
            a_list.append(d["a"][sel])
            f_list.append(d["F"][sel] - axis.cogging_force(d["s"][sel]) - axis.restoring_force(d["s"][sel])
                          - axis.friction_force(d["v"][sel]))
        acc[ax], frc[ax] = np.concatenate(a_list), np.concatenate(f_list)
        axes[ax], steps[ax] = axis, st
        seconds[ax] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ms = fit_masses(acc, frc)
    seconds["mass"] = time.perf_counter() - t0
    for ax in AXES:
        if not ms["m"][ax] > 0:
            raise CoverageError(f"masses: axis '{ax}' came out at {ms['m'][ax]:.3g} kg; the accelerated moves do "
                                "not determine it (too small accelerations or a bad friction model)")
        axes[ax] = axes[ax].with_values(m=ms["m"][ax])
        steps[ax]["mass"] = {"m_kg": ms["m"][ax], "stacked_kg": ms["stacked"][ax], "rms_n": ms["rms_n"][ax],
                             "r2": ms["r2"][ax], "samples": ms["samples"][ax]}
    if presliding:
        stacked = ThreeAxisModel(**axes).stacked_masses()
        for ax in AXES:
            t0 = time.perf_counter()
            axis, pos, frc, lev = axes[ax], [], [], []
            for d in _axis_data(recs, ax, kms[ax]):
                pos.append(d["s"])
                frc.append(d["F"] - axis.cogging_force(d["s"]) - axis.restoring_force(d["s"])
                           - stacked[ax] * d["a"] - axis.sigma * d["v"])
                lev.append(axis.stribeck_level(d["v"]))
            fit = fit_presliding(pos, frc, lev)
            axes[ax] = axis.with_values(x_pre=fit["x_pre"])
            steps[ax]["presliding"] = fit
            seconds[ax] += time.perf_counter() - t0
    return IdentificationReport(ThreeAxisModel(**axes), steps, seconds)


def identify_axes(air_moves: Sequence[Recording], **kwargs) -> ThreeAxisModel:
    """The identified :class:`ThreeAxisModel` (see :func:`run_identification` for the report).

    Parameters
    ----------
    air_moves : sequence of Recording
        NC traces without cutting (see :func:`run_identification`).
    **kwargs
        Passed to :func:`run_identification` (``motor_constants``, ``pole_pitch`` ...).

    Returns
    -------
    ThreeAxisModel
    """
    return run_identification(air_moves, **kwargs).model
