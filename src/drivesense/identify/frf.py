"""Frequency-response identification of a ball-screw axis (first paper, Sec. 2.3, Fig. 5).

1. :func:`measure_frf` estimates, from a trace taken while an excitation runs
   on the current reference, the frequency responses of motor-side and table
   acceleration per motor thrust ``K_t I / R`` (Welch cross-spectra, with
   coherence).  With the excitation signal recorded, the closed-loop-safe
   estimate ``S_ry / S_ru`` (excitation ``r`` as instrument) is used; otherwise
   the classical H1 ``S_uy / S_uu`` on the current reference.
2. :func:`fit_frf` fits the dual-inertia model (``J_r, M_t, C_t, C_k, D_r,
   K_r``) and the encoder-side dead time ``T_b`` by iterative nonlinear least
   squares in the frequency domain — the paper's differential iteration:
   linearise about the current estimate, solve, repeat (here
   ``scipy.optimize.least_squares``, trust-region reflective, on
   log-parameters) — weighted by the coherence, with confidence intervals
   from the Jacobian.  ``K_t`` and the lead are catalogue values the user
   gives (without them the fit has no physical scale); ``T_a`` and
   ``omega_cc`` default to catalogue values and stay fixed.

The model FRF includes everything between the numbers in the trace and the
mechanics: the current-loop model ``H(s)``, the dead times ``T_a + T_b``, the
zero-order hold of the current reference and the second difference that turns
encoder samples into accelerations.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize
from scipy import signal as sps

from drivesense.errors import ConfigError, IdentificationError, InvalidSignalError
from drivesense.machine.signal_chain import SignalParams
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.recording import Recording

__all__ = ["MeasuredFRF", "FRFFit", "measure_frf", "fit_frf", "model_frf", "split_fix", "FIT_PARAMETERS",
           "CATALOGUE_DEFAULTS"]

#: Parameters :func:`fit_frf` can estimate (mechanics in SI, ``T_b`` [s]).
FIT_PARAMETERS = ("J_r", "M_t", "C_t", "C_k", "D_r", "K_r", "T_b")
#: Catalogue values the fit takes as given when ``--fix`` does not name them.
CATALOGUE_DEFAULTS = {"T_a": 0.2e-3, "omega_cc": 5000.0}


def split_fix(fix: dict) -> tuple[float, float, dict, dict]:
    """The known values of a fit (``--fix``) as ``K_t, lead, chain, fixed``.

    Parameters
    ----------
    fix : dict
        Name -> SI value: ``K_t`` [N*m/A] and ``lead`` [m] required; ``T_a`` [s] and ``omega_cc`` [rad/s]
        (default :data:`CATALOGUE_DEFAULTS`); any of :data:`FIT_PARAMETERS` to hold fixed.

    Returns
    -------
    tuple
        ``K_t``, ``lead``, the signal-chain values (``T_a``, ``omega_cc``) and the fixed fit parameters.

    Raises
    ------
    ConfigError
        ``K_t`` or ``lead`` missing (the message names ``--fix``).
    """
    missing = [k for k in ("K_t", "lead") if k not in fix]
    if missing:
        raise ConfigError(f"--fix must give {' and '.join(missing)}: the motor torque constant [N*m/A] and the "
                          "screw lead [m] are catalogue values; without them the fit has no physical scale")
    given = dict(fix)
    K_t, lead = given.pop("K_t"), given.pop("lead")
    chain = {k: given.pop(k, v) for k, v in CATALOGUE_DEFAULTS.items()}
    return K_t, lead, chain, given
_LOG_PARAMS = ("J_r", "M_t", "C_t", "C_k", "D_r", "K_r")


@dataclass(frozen=True)
class MeasuredFRF:
    """Measured frequency responses of acceleration per motor thrust.

    Attributes
    ----------
    freq : ndarray
        Frequencies [Hz].
    motor, table : ndarray (complex)
        Motor-side and table acceleration per motor thrust [(m/s^2)/N].
    coherence_motor, coherence_table : ndarray
        Coherence of each response with the reference signal [-].
    n_averages : int
        Number of Welch segments averaged.
    fs : float
        Sample rate of the trace [Hz].
    reference : str
        ``"excitation"`` (closed-loop estimate S_ry/S_ru) or ``"current_ref"`` (H1).
    """

    freq: np.ndarray
    motor: np.ndarray
    table: np.ndarray
    coherence_motor: np.ndarray
    coherence_table: np.ndarray
    n_averages: int
    fs: float
    reference: str


def _second_difference(x: np.ndarray, fs: float) -> np.ndarray:
    """``(x[n] - 2 x[n-1] + x[n-2]) fs^2`` assigned to sample ``n`` (first two samples repeat)."""
    a = np.empty_like(x)
    a[2:] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) * fs * fs
    a[:2] = a[2]
    return a


def measure_frf(recording: Recording, *, K_t: float, lead: float, axis_name: str = "x",
                nperseg: int | None = None, fmin: float = 5.0, fmax: float = 2000.0,
                reference: str = "auto", window: tuple[float, float] | None = None) -> MeasuredFRF:
    """Estimate motor and table acceleration per motor thrust from an excitation trace.

    Parameters
    ----------
    recording : Recording
        Trace with ``{ax}_current_ref`` [A], ``{ax}_motor_angle`` [rad],
        ``{ax}_table_position`` [m] and, ideally, ``{ax}_current_excitation`` [A].
    K_t : float
        Motor torque constant [N*m/A] (catalogue).
    lead : float
        Screw lead [m/rev] (catalogue).
    axis_name : str
        Axis letter of the channels.
    nperseg : int, optional
        Welch segment length [samples] (Hann window, half overlap; frequency
        resolution ``fs / nperseg``); default 8192.
    fmin, fmax : float
        Frequency band kept [Hz].
    reference : {"auto", "excitation", "current_ref"}
        Reference of the spectral estimate; ``auto`` uses the excitation if recorded.
    window : tuple of float, optional
        Time window [s] to analyse (default ``meta["excitation_window"]`` or all).

    Returns
    -------
    MeasuredFRF
    """
    ax = axis_name
    recording.require(f"{ax}_current_ref", f"{ax}_motor_angle", f"{ax}_table_position")
    exc_name = f"{ax}_current_excitation"
    if reference == "auto":
        reference = "excitation" if exc_name in recording.channels else "current_ref"
    if reference == "excitation":
        recording.require(exc_name)
    elif reference != "current_ref":
        raise ConfigError(f"reference must be 'auto', 'excitation' or 'current_ref', got {reference!r}")
    window = window or tuple(recording.meta.get("excitation_window", (recording.t0, recording.t0 + recording.duration)))
    rec = recording.slice_time(*window)
    fs = rec.fs
    nperseg = nperseg or 8192
    if rec.n_samples < 2 * nperseg:
        raise InvalidSignalError(f"FRF window holds {rec.n_samples} samples; at least {2 * nperseg} "
                                 f"(two Welch segments of {nperseg}) are needed — record longer or lower --nperseg")
    R = lead / (2.0 * math.pi)
    thrust = K_t / R * rec[f"{ax}_current_ref"]
    a_m = _second_difference(R * rec[f"{ax}_motor_angle"], fs)
    a_t = _second_difference(rec[f"{ax}_table_position"], fs)
    overlap = nperseg // 2
    kw = dict(fs=fs, nperseg=nperseg, noverlap=overlap, window="hann", detrend="constant")
    with np.errstate(divide="ignore", invalid="ignore"):   # no excitation: 0/0, refused below
        if reference == "excitation":
            r = rec[exc_name]
            f, s_ru = sps.csd(r, thrust, **kw)
            _, s_rm = sps.csd(r, a_m, **kw)
            _, s_rt = sps.csd(r, a_t, **kw)
            motor, table = s_rm / s_ru, s_rt / s_ru
            _, coh_m = sps.coherence(r, a_m, **kw)
            _, coh_t = sps.coherence(r, a_t, **kw)
            _, coh_u = sps.coherence(r, thrust, **kw)
            coh_m, coh_t = coh_m * coh_u, coh_t * coh_u
            energy = np.abs(s_ru)
        else:
            f, s_uu = sps.welch(thrust, **kw)
            _, s_um = sps.csd(thrust, a_m, **kw)
            _, s_ut = sps.csd(thrust, a_t, **kw)
            motor, table = s_um / s_uu, s_ut / s_uu
            _, coh_m = sps.coherence(thrust, a_m, **kw)
            _, coh_t = sps.coherence(thrust, a_t, **kw)
            energy = s_uu
    in_band = (f >= fmin) & (f <= fmax) & np.isfinite(motor) & np.isfinite(table)
    # bins the excitation actually drives (a multisine leaves gaps between its lines)
    keep = in_band & (energy > 0.01 * np.median(energy[in_band])) if in_band.any() else in_band
    if keep.sum() < 10:
        raise InvalidSignalError(f"fewer than 10 excited frequencies in {fmin}-{fmax} Hz: is the excitation "
                                 "running in the analysed window?")
    n_avg = max(1, (rec.n_samples - nperseg) // (nperseg - overlap) + 1)
    return MeasuredFRF(f[keep], motor[keep], table[keep], coh_m[keep], coh_t[keep], n_avg, fs, reference)


def model_frf(axis: BallScrewAxis, freq, *, T_a: float, T_b: float, omega_cc: float, fs: float):
    """Model of :func:`measure_frf`'s responses for given parameters.

    The plant (dual-inertia mechanics driven through the current-loop model)
    is discretised exactly for the zero-order-held current reference
    (``scipy.signal.cont2discrete``), delayed by ``T_a + T_b`` and followed by
    the second difference that turns encoder samples into accelerations, so
    the model is exact for a sampled drive, not only well below Nyquist.

    Parameters
    ----------
    axis : BallScrewAxis
        Mechanics.
    freq : array_like
        Frequencies [Hz].
    T_a, T_b : float
        Driver and encoder-side dead times [s].
    omega_cc : float
        Current-loop bandwidth [rad/s] (0: ideal current loop).
    fs : float
        Sample rate of the trace [Hz].

    Returns
    -------
    motor, table : ndarray (complex)
        Acceleration per motor thrust [(m/s^2)/N].
    """
    m = axis.matrices()
    minv = np.linalg.inv(m.M)
    n_mech = 4
    with_loop = omega_cc > 0
    n = n_mech + (1 if with_loop else 0)
    A = np.zeros((n, n))
    A[0:2, 2:4] = np.eye(2)
    A[2:4, 0:2] = -minv @ m.K
    A[2:4, 2:4] = -minv @ m.C
    B = np.zeros((n, 1))
    if with_loop:
        A[2:4, 4] = minv[:, 0]  # the loop output is the motor thrust [N]
        A[4, 4] = -omega_cc
        B[4, 0] = omega_cc
    else:
        B[2:4, 0] = minv[:, 0]
    C = np.zeros((2, n))
    C[0, 0] = C[1, 1] = 1.0
    T = 1.0 / fs
    Ad, Bd, *_ = sps.cont2discrete((A, B, C, np.zeros((2, 1))), T, method="zoh")
    lam, V = np.linalg.eig(Ad)
    CV = C @ V
    VB = np.linalg.solve(V, Bd)[:, 0]
    w = 2.0 * math.pi * np.asarray(freq, float)
    z = np.exp(1j * w * T)
    resp = (CV[:, None, :] * (VB[None, None, :] / (z[None, :, None] - lam[None, None, :]))).sum(axis=2)
    factor = np.exp(-1j * w * (T_a + T_b)) * (1.0 - 1.0 / z) ** 2 * fs * fs
    return resp[0] * factor, resp[1] * factor


@dataclass
class FRFFit:
    """Result of :func:`fit_frf`.

    Attributes
    ----------
    axis : BallScrewAxis
        Identified axis (fixed values kept).
    signal : SignalParams
        ``T_a``, identified ``T_b``, ``T_comp = T_a + T_b``, ``omega_cc``.
    values : dict
        Every parameter's value (SI; ``T_b`` in s).
    free : tuple of str
        Parameters that were estimated.
    ci95 : dict
        95 % confidence interval ``(low, high)`` of each free parameter.
    rel_std : dict
        Standard deviation of each free parameter relative to its value
        (``T_b``: absolute, in s).
    iterations : int
        Jacobian evaluations of the iteration.
    normalised_rms : float
        RMS of the coherence-weighted residual [-] (about 1 when the model
        explains the data down to the measurement noise).
    seconds : float
        Time the fit took [s].
    measured : MeasuredFRF
        The data fitted.
    """

    axis: BallScrewAxis
    signal: SignalParams
    values: dict
    free: tuple
    ci95: dict
    rel_std: dict
    iterations: int
    normalised_rms: float
    seconds: float
    measured: MeasuredFRF = field(repr=False)

    def model(self, freq=None):
        """Fitted model responses ``(motor, table)`` at ``freq`` [Hz] (default: the measured ones).

        Parameters
        ----------
        freq : array_like, optional
            Frequencies [Hz]; default the measured ones.
        """
        f = self.measured.freq if freq is None else freq
        return model_frf(self.axis, f, T_a=self.signal.T_a, T_b=self.signal.T_b,
                         omega_cc=self.signal.omega_cc, fs=self.measured.fs)

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"values": self.values, "free": list(self.free),
                "ci95": {k: list(v) for k, v in self.ci95.items()}, "rel_std": self.rel_std,
                "iterations": self.iterations, "normalised_rms": self.normalised_rms,
                "seconds": self.seconds, "reference": self.measured.reference,
                "n_frequencies": int(self.measured.freq.size)}


def _initial_guess(meas: MeasuredFRF, R: float, K_t: float, lead: float, T_a: float, omega_cc: float,
                   cost) -> dict:
    """Start values: total mass from the rigid-body level, the resonance from the table peak,
    then the inertia ratio and the dead time by a coarse grid search on the fit cost."""
    f = meas.freq
    band = (f > 50) & (f < 0.8 * f.max())
    if band.sum() < 5:
        raise IdentificationError("the measured band does not reach above 50 Hz: resonance and stiffness "
                                  "cannot be determined (raise --fmax / the excitation band)")
    mag_t = np.abs(meas.table)
    f_res = float(f[np.flatnonzero(band)[np.argmax(mag_t[band])]])
    low = (f > 0.1 * f_res) & (f < 0.35 * f_res)
    if low.sum() < 3:
        raise IdentificationError(f"no measured frequencies between {0.1 * f_res:.0f} and {0.35 * f_res:.0f} Hz "
                                  f"(below the resonance near {f_res:.0f} Hz): the mass cannot be determined "
                                  "(lower --fmin / the excitation band)")
    # rigid-body level, corrected for the signal chain (current loop, delays, sampling)
    unit = BallScrewAxis(J_r=0.5 * R * R, M_t=0.5, C_t=0.0, C_k=0.0, D_r=0.0, K_r=1e12, lead=lead, K_t=K_t)
    _, chain_t = model_frf(unit, f[low], T_a=T_a, T_b=0.0, omega_cc=omega_cc, fs=meas.fs)
    m_tot = float(np.median(np.abs(chain_t) / mag_t[low]))
    w_n = 2 * math.pi * f_res
    best, best_cost = None, math.inf
    for alpha in np.geomspace(0.005, 2.0, 40):
        M_r = m_tot / (1.0 + alpha)
        M_t = alpha * M_r
        K_r = w_n**2 / (1.0 / M_r + 1.0 / M_t)
        cand = {"J_r": M_r * R * R, "M_t": M_t, "C_t": 100.0 * M_t, "D_r": 100.0 * M_r * R * R,
                "C_k": 0.1 / w_n * K_r, "K_r": K_r}
        for t_b in np.arange(0.0, 2.0e-3, 0.1e-3):
            c = cost({**cand, "T_b": t_b})
            if c < best_cost:
                best, best_cost = {**cand, "T_b": t_b}, c
    return best


#: Decades either side of its start value a mechanical parameter may take in the fit.
_LOG_SPAN = 6


def _exp(x: float) -> float:
    """``exp(x)``, or inf where it overflows (the interval of an undetermined parameter)."""
    return math.exp(x) if x < 709.0 else math.inf


def fit_frf(measured: MeasuredFRF, *, K_t: float, lead: float, fixed: dict | None = None,
            T_a: float = 0.2e-3, omega_cc: float = 5000.0, max_rel_std: float = 0.25) -> FRFFit:
    """Fit the dual-inertia model and ``T_b`` to measured FRFs.

    Parameters
    ----------
    measured : MeasuredFRF
        From :func:`measure_frf`.
    K_t : float
        Torque constant [N*m/A] (catalogue, fixed).
    lead : float
        Screw lead [m/rev] (catalogue, fixed).
    fixed : dict, optional
        Other parameters to hold at given values (any of :data:`FIT_PARAMETERS`).
    T_a : float
        Driver dead time [s] (catalogue, fixed).
    omega_cc : float
        Current-loop bandwidth [rad/s] (catalogue, fixed).
    max_rel_std : float
        A free parameter whose relative standard deviation [-] exceeds this is
        declared undetermined.

    Returns
    -------
    FRFFit

    Raises
    ------
    IdentificationError
        The data cannot determine a parameter (named), or the band misses the resonance.
    ConfigError
        Unknown names in ``fixed``.
    """
    t0 = time.perf_counter()
    fixed = dict(fixed or {})
    unknown = [k for k in fixed if k not in FIT_PARAMETERS]
    if unknown:
        raise ConfigError(f"cannot fix {', '.join(unknown)}: fixable are {', '.join(FIT_PARAMETERS)} "
                          "(K_t, lead, T_a, omega_cc are given separately)")
    R = lead / (2.0 * math.pi)
    free = tuple(p for p in FIT_PARAMETERS if p not in fixed)
    if not free:
        raise ConfigError("every parameter is fixed: nothing to fit")
    coh = [np.clip(c, 0.05, 0.9999) for c in (measured.coherence_motor, measured.coherence_table)]
    data = (measured.motor, measured.table)
    sigma = [np.abs(d) * np.sqrt((1 - c) / (2 * measured.n_averages * c)) for d, c in zip(data, coh)]
    scale_tb = 1e-4  # T_b in units of 0.1 ms inside the solver

    def residual_of(v):
        axis = BallScrewAxis(**{k: v[k] for k in _LOG_PARAMS}, lead=lead, K_t=K_t)
        gm, gt = model_frf(axis, measured.freq, T_a=T_a, T_b=v["T_b"], omega_cc=omega_cc, fs=measured.fs)
        e = [(g - d) / s for g, d, s in zip((gm, gt), data, sigma)]
        return np.concatenate([e[0].real, e[0].imag, e[1].real, e[1].imag])

    guess = _initial_guess(measured, R, K_t, lead, T_a, omega_cc,
                           lambda v: float(np.sum(residual_of({**v, **fixed}) ** 2)))
    no_start = [p for p in free if guess is None or not (math.isfinite(guess[p]) and guess[p] >= 0
                                                         and (p == "T_b" or guess[p] > 0))]
    if no_start:
        raise IdentificationError(
            f"the measured FRFs cannot determine {', '.join(no_start)}: they give no start value (is an "
            "excitation running on the current reference?); excite the axis, or fix these with --fix NAME=VALUE")
    guess.update(fixed)

    def unpack(x):
        vals = dict(guess)
        for p, xi in zip(free, x):
            vals[p] = xi * scale_tb if p == "T_b" else math.exp(xi)
        return vals

    def residual(x):
        return residual_of(unpack(x))

    def pack(vals):
        return np.array([vals[p] / scale_tb if p == "T_b" else math.log(vals[p]) for p in free])

    x0 = pack(guess)
    # mechanics within _LOG_SPAN decades of the start value: without excitation a parameter runs away
    # (and would overflow exp); one that ends on that edge is undetermined
    span = _LOG_SPAN * math.log(10.0)
    lower = np.array([0.0 if p == "T_b" else x - span for p, x in zip(free, x0)])
    upper = np.array([np.inf if p == "T_b" else x + span for p, x in zip(free, x0)])
    sol = optimize.least_squares(residual, x0, method="trf", x_scale="jac", bounds=(lower, upper),
                                 max_nfev=400, xtol=1e-12, ftol=1e-12)
    on_edge = [p for p, x, lo, hi in zip(free, sol.x, lower, upper)
               if p != "T_b" and min(x - lo, hi - x) < 1e-3 * span]
    vals = unpack(sol.x)
    m = sol.fun.size
    dof = max(m - len(free), 1)
    s2 = 2.0 * sol.cost / dof
    _, sv, vt = np.linalg.svd(sol.jac, full_matrices=False)
    tiny = sv <= 1e-9 * max(sv.max(), 1e-300)
    # parameters with weight in a null direction of the Jacobian are undetermined (infinite std)
    in_null = (np.abs(vt[tiny]) > 0.1).any(axis=0) if tiny.any() else np.zeros(len(free), bool)
    inv_sv2 = np.where(tiny, 0.0, 1.0 / np.where(tiny, 1.0, sv) ** 2)
    cov = (vt.T * inv_sv2) @ vt * s2
    rel_std, ci = {}, {}
    for i, p in enumerate(free):
        sd = math.inf if in_null[i] else math.sqrt(max(cov[i, i], 0.0))
        if p == "T_b":
            rel_std[p] = sd * scale_tb
            ci[p] = (vals[p] - 1.96 * sd * scale_tb, vals[p] + 1.96 * sd * scale_tb)
        else:
            rel_std[p] = sd
            ci[p] = (vals[p] * _exp(-1.96 * sd), vals[p] * _exp(1.96 * sd))
    bad = [p for p in free if (p != "T_b" and rel_std[p] > max_rel_std)
           or (p == "T_b" and rel_std[p] > 0.5e-3)]
    if on_edge:
        raise IdentificationError(
            f"the measured FRFs cannot determine {', '.join(on_edge)}: the fit ran {_LOG_SPAN} decades away "
            "from the start value (is an excitation running on the current reference?); excite the axis around "
            "its resonance, or fix these with --fix NAME=VALUE")
    if bad:
        detail = ", ".join(f"{p} (relative std {rel_std[p]:.3g})" if p != "T_b"
                           else f"T_b (std {rel_std[p] * 1e3:.3g} ms)" for p in bad)
        raise IdentificationError(
            f"the measured FRFs cannot determine {detail}: widen the excitation band around the "
            f"resonance, excite longer, or fix these with --fix NAME=VALUE")
    axis = BallScrewAxis(**{k: vals[k] for k in _LOG_PARAMS}, lead=lead, K_t=K_t)
    signal = SignalParams(T_a=T_a, T_b=vals["T_b"], T_comp=T_a + vals["T_b"], omega_cc=omega_cc)
    values = {**{k: float(vals[k]) for k in FIT_PARAMETERS}, "K_t": K_t, "lead": lead, "T_a": T_a,
              "omega_cc": omega_cc}
    return FRFFit(axis, signal, values, free, ci, rel_std, int(sol.njev or sol.nfev),
                  float(math.sqrt(2.0 * sol.cost / m)), time.perf_counter() - t0, measured)
