"""Scoring an estimate against a reference force (``drivesense.score``), on signals with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal as sps

from drivesense.errors import CoverageError
from drivesense.estimate import SignalParams
from drivesense.estimate.design import lowpass_sos
from drivesense.recording import Recording
from drivesense.score import Score, aligned_reference, harmonic_amplitudes, score_estimate

FS = 10_000.0
N = 20_000
T = np.arange(N) / FS
SOS = lowpass_sos(SignalParams(), FS)


def force_signal() -> np.ndarray:
    """A milling-like force: DC, tooth pass at 33.3 Hz and harmonics, well inside the band."""
    return (12.0 + 8.0 * np.sin(2 * math.pi * 33.3 * T) + 3.0 * np.sin(2 * math.pi * 66.6 * T + 0.4)
            + 1.0 * np.cos(2 * math.pi * 99.9 * T))


def ref_rec(x=None, **meta) -> Recording:
    x = force_signal() if x is None else x
    return Recording.from_arrays({"force_x": x}, fs=FS, meta={"score_window": [0.2, 1.9], **meta})


def est_rec(x, latency=None) -> Recording:
    meta = {} if latency is None else {"latency_s": latency}
    return Recording.from_arrays({"force_x": x}, fs=FS, meta=meta)


@pytest.fixture(scope="module")
def ref() -> Recording:
    return ref_rec()


# ------------------------------------------------------------------ basics
def test_perfect_estimate_scores_zero(ref):
    s = score_estimate(est_rec(ref["force_x"]), ref)
    assert isinstance(s, Score)
    assert s.rmse_n == 0.0 and s.nrmse == 0.0 and s.max_abs_error_n == 0.0
    assert s.window == (0.2, 1.9)
    assert s.peak_to_peak_n == pytest.approx(np.ptp(ref["force_x"][(T >= 0.2) & (T < 1.9)]))
    assert math.isnan(s.harmonic_error)


def test_perfect_filtered_estimate_scores_zero(ref):
    """An estimate that is the reference through the same low-pass (same start) scores 0."""
    x = ref["force_x"]
    filtered = sps.sosfilt(SOS, x, zi=sps.sosfilt_zi(SOS) * x[0])[0]
    s = score_estimate(est_rec(filtered), ref, sos=SOS)
    assert s.rmse_n < 1e-12


@pytest.mark.parametrize("d", [0.5, -2.0])
def test_constant_offset_gives_rmse_d(ref, d):
    s = score_estimate(est_rec(ref["force_x"] + d), ref)
    assert s.rmse_n == pytest.approx(abs(d), rel=1e-12)
    assert s.max_abs_error_n == pytest.approx(abs(d), rel=1e-12)
    assert s.nrmse == pytest.approx(abs(d) / s.peak_to_peak_n, rel=1e-12)


def test_known_rmse_of_sinusoidal_error(ref):
    err = 0.3 * np.sin(2 * math.pi * 50.0 * T)  # whole periods inside the window
    s = score_estimate(est_rec(ref["force_x"] + err), ref, window=(0.2, 1.8))
    assert s.rmse_n == pytest.approx(0.3 / math.sqrt(2), rel=1e-3)
    assert s.max_abs_error_n == pytest.approx(0.3, rel=1e-3)
    assert s.window == (0.2, 1.8)


def test_window_restricts_comparison(ref):
    x = ref["force_x"].copy()
    x[T < 0.1] += 100.0  # a start-up transient outside the window
    assert score_estimate(est_rec(x), ref).rmse_n == 0.0
    assert score_estimate(est_rec(x), ref, window=(0.0, 1.0)).rmse_n > 10


def test_default_window_without_meta_is_whole_trace():
    r = Recording.from_arrays({"force_x": force_signal()}, fs=FS)
    s = score_estimate(est_rec(force_signal()), r)
    assert s.window[0] == 0.0 and s.window[1] == pytest.approx(N / FS)


def test_too_small_window_raises(ref):
    with pytest.raises(CoverageError, match="fewer than 10 samples"):
        score_estimate(est_rec(ref["force_x"]), ref, window=(0.5, 0.5005))
    with pytest.raises(ValueError):
        score_estimate(est_rec(ref["force_x"]), ref, window=(5.0, 6.0))


def test_flat_reference_gives_infinite_nrmse():
    r = ref_rec(np.full(N, 3.0))
    s = score_estimate(est_rec(np.full(N, 4.0)), r)
    assert s.rmse_n == pytest.approx(1.0) and s.peak_to_peak_n == 0.0 and s.nrmse == math.inf


def test_other_channel(ref):
    r = Recording.from_arrays({"force_y": force_signal()}, fs=FS, meta={"score_window": [0.2, 1.9]})
    e = Recording.from_arrays({"force_y": force_signal() + 1.0}, fs=FS)
    assert score_estimate(e, r, channel="force_y").rmse_n == pytest.approx(1.0)


def test_score_to_dict(ref):
    d = score_estimate(est_rec(ref["force_x"] + 1.0), ref).to_dict()
    assert d["rmse_n"] == pytest.approx(1.0) and d["window"] == [0.2, 1.9]


# ----------------------------------------------------------------- latency
@pytest.mark.parametrize("k", [1, 3, 7])
def test_delayed_copy_with_declared_latency_scores_zero(ref, k):
    x = ref["force_x"]
    delayed = np.concatenate([np.full(k, x[0]), x[:-k]])
    good = score_estimate(est_rec(delayed, latency=k / FS), ref)
    assert good.rmse_n < 1e-12
    bad = score_estimate(est_rec(delayed), ref)  # latency not declared: counted as error
    assert bad.rmse_n > 0.05 * k


def test_fractional_latency_is_interpolated(ref):
    x = ref["force_x"]
    delay = 2.5 / FS
    delayed = np.interp(T - delay, T, x)
    s = score_estimate(est_rec(delayed, latency=delay), ref)
    # linear interpolation of a <= 100 Hz signal at 10 kHz: tiny error
    assert s.rmse_n < 1e-3 * s.peak_to_peak_n


def test_aligned_reference_filters_then_delays():
    x = force_signal()
    out = aligned_reference(x, FS, SOS, 3 / FS)
    filt = sps.sosfilt(SOS, x, zi=sps.sosfilt_zi(SOS) * x[0])[0]
    np.testing.assert_allclose(out[3:], filt[:-3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:3], filt[0])
    # no filter, no delay: unchanged
    np.testing.assert_array_equal(aligned_reference(x, FS, None, 0.0), x)
    # the filter starts in its steady state: a constant passes unchanged
    np.testing.assert_allclose(aligned_reference(np.full(100, 7.0), FS, SOS, 0.0), 7.0, rtol=1e-12)


def test_filtered_reference_delayed_estimate(ref):
    """Estimate = LPF(reference) delayed by 2 samples, declared: zero error with sos and latency."""
    x = ref["force_x"]
    filt = sps.sosfilt(SOS, x, zi=sps.sosfilt_zi(SOS) * x[0])[0]
    delayed = np.concatenate([np.full(2, filt[0]), filt[:-2]])
    assert score_estimate(est_rec(delayed, latency=2e-4), ref, sos=SOS).rmse_n < 1e-12


# --------------------------------------------------------------- harmonics
def test_harmonic_amplitudes_recovers_known_sinusoids():
    amps = harmonic_amplitudes(force_signal(), FS, [33.3, 66.6, 99.9])
    np.testing.assert_allclose(amps, [8.0, 3.0, 1.0], rtol=1e-9)
    # a frequency that is absent reads ~0; DC does not leak
    amps = harmonic_amplitudes(force_signal(), FS, [33.3, 150.0])
    assert amps[0] == pytest.approx(8.0, rel=1e-3) and amps[1] < 1e-2


def test_harmonic_amplitudes_with_noise():
    rng = np.random.default_rng(0)
    x = 5.0 * np.sin(2 * math.pi * 120.0 * T + 1.0) + rng.normal(0, 1.0, N)
    amp = harmonic_amplitudes(x, FS, [120.0])[0]
    assert amp == pytest.approx(5.0, abs=0.05)  # noise floor ~ sqrt(2/N)


def test_harmonic_error_in_score(ref):
    x = ref["force_x"]
    est = 12.0 + 1.1 * (x - 12.0)  # every harmonic 10 % too large
    s = score_estimate(est_rec(est), ref, tooth_pass_hz=33.3, cutoff_hz=120.0)
    assert s.harmonic_error == pytest.approx(0.1, rel=1e-3)
    s = score_estimate(est_rec(x), ref, tooth_pass_hz=33.3, cutoff_hz=120.0)
    assert s.harmonic_error < 1e-9
    # cut-off below the tooth pass: no harmonic to compare
    s = score_estimate(est_rec(est), ref, tooth_pass_hz=33.3, cutoff_hz=30.0)
    assert math.isnan(s.harmonic_error)


def test_harmonic_error_only_below_cutoff(ref):
    x = ref["force_x"]
    est = x + 2.0 * np.cos(2 * math.pi * 99.9 * T)  # 3rd harmonic amplitude 1 -> 3
    below = score_estimate(est_rec(est), ref, tooth_pass_hz=33.3, cutoff_hz=80.0)
    assert below.harmonic_error < 5e-3  # only least-squares leakage from the unfitted 99.9 Hz
    incl = score_estimate(est_rec(est), ref, tooth_pass_hz=33.3, cutoff_hz=120.0)
    # amplitude-weighted: sum |A_est - A_ref| / sum A_ref = (0 + 0 + 2) / (8 + 3 + 1)
    assert incl.harmonic_error == pytest.approx(2.0 / 12.0, rel=1e-3)
