"""Recording assertions (``drivesense.testing``): pass on agreement, report every difference on failure."""

from __future__ import annotations

import re

import numpy as np
import pytest

from drivesense.recording import Recording
from drivesense.testing import assert_recording_allclose, assert_recording_equal

FS = 1000.0
N = 200
T = np.arange(N) / FS


def rec(**overrides) -> Recording:
    chans = {"force_x": 10.0 + np.sin(2 * np.pi * 5 * T), "x_current": 0.5 * np.cos(2 * np.pi * 5 * T)}
    chans.update(overrides)
    return Recording.from_arrays(chans, fs=FS, t0=0.25, meta={"name": "run"})


def failure(fn, *args, **kw) -> str:
    with pytest.raises(AssertionError) as info:
        fn(*args, **kw)
    return str(info.value)


# ------------------------------------------------------------------ passing cases
def test_identical_recordings_pass_both():
    a = rec()
    assert assert_recording_allclose(a, rec()) is None
    assert assert_recording_equal(a, rec(), check_meta=True) is None


def test_within_tolerance_passes_allclose_but_not_equal():
    a = rec()
    b = a.with_channels({"force_x": a["force_x"] * (1 + 1e-9)})
    assert_recording_allclose(b, a)                      # rtol 1e-7 by default
    assert_recording_allclose(b, a, rtol=0.0, atol=1e-7)
    msg = failure(assert_recording_equal, b, a)
    assert "'force_x'" in msg and "'x_current'" not in msg


def test_channel_order_is_not_compared():
    a = rec()
    assert_recording_equal(a.select("x_current", "force_x"), a)


def test_tiny_t0_and_fs_rounding_is_close_but_not_equal():
    a = rec()
    b = Recording.from_arrays({c: a[c] for c in a.channels}, fs=FS * (1 + 1e-15), t0=0.25 + 1e-12)
    assert_recording_allclose(b, a)
    msg = failure(assert_recording_equal, b, a)
    assert "fs:" in msg and "t0:" in msg


# ------------------------------------------------------------------ each failure kind
def test_values_outside_tolerance_are_located():
    a = rec()
    x = a["force_x"].copy()
    x[[17, 123]] += [0.01, 0.5]                          # the worst sample is 123
    msg = failure(assert_recording_allclose, a.with_channels({"force_x": x}), a, rtol=1e-6)
    assert "1 difference(s)" in msg and "rtol=1e-06" in msg
    line = next(s for s in msg.splitlines() if "'force_x'" in s)
    assert "[N]" in line and "2 of 200 samples" in line
    assert "worst sample 123" in line and "t = 0.373 s" in line  # t0 + 123 / fs
    max_abs = float(re.search(r"max abs diff ([0-9.e+-]+)", line).group(1))
    max_rel = float(re.search(r"max rel diff ([0-9.e+-]+)", line).group(1))
    assert max_abs == pytest.approx(0.5, rel=1e-5)
    assert max_rel == pytest.approx(0.5 / abs(a["force_x"][123]), rel=1e-5)
    assert f"expected {a['force_x'][123]!r}" in line


def test_worst_sample_is_the_one_furthest_outside_the_tolerance():
    """A large but allowed difference on a large value does not hide a small forbidden one."""
    e = Recording.from_arrays({"force_x": np.r_[1000.0, 0.0, 1.0]}, fs=FS)
    a = e.with_channels({"force_x": np.r_[1000.5, 0.0, 1.01]})
    msg = failure(assert_recording_allclose, a, e, rtol=1e-3)
    assert "1 of 3 samples" in msg and "worst sample 2 " in msg and "max abs diff 0.5 " in msg


def test_every_differing_channel_is_listed():
    a = rec()
    b = a.with_channels({"force_x": a["force_x"] + 1.0, "x_current": a["x_current"] * 2})
    msg = failure(assert_recording_allclose, b, a)
    assert "2 difference(s)" in msg
    assert "channel 'force_x' [N]" in msg and "channel 'x_current' [A]" in msg
    # a selection compares only the channels named
    assert_recording_allclose(b, a, channels=["force_x"], atol=1.0 + 1e-9)


def test_channel_sets():
    a = rec()
    msg = failure(assert_recording_allclose, a.select("force_x"), a)
    assert "channels missing from actual: ['x_current']" in msg
    msg = failure(assert_recording_allclose, a, a.select("x_current"))
    assert "channels only in actual: ['force_x']" in msg
    msg = failure(assert_recording_allclose, a.select("force_x"), a, channels=["force_x", "x_current", "force_y"])
    assert "channel 'x_current' missing from actual" in msg
    assert "channel 'force_y' missing from actual and expected" in msg


def test_sample_rate_start_time_and_length():
    a = rec()
    other_fs = Recording.from_arrays({c: a[c] for c in a.channels}, fs=2 * FS, t0=a.t0)
    assert "fs: 2000.0 Hz != 1000.0 Hz" in failure(assert_recording_allclose, other_fs, a)
    late = Recording.from_arrays({c: a[c] for c in a.channels}, fs=FS, t0=a.t0 + 1e-3)
    msg = failure(assert_recording_allclose, late, a)
    assert "t0: 0.251 s != 0.25 s" in msg and "1 samples" in msg
    short = a.slice_time(None, a.t0 + 0.1)
    msg = failure(assert_recording_allclose, short, a)
    assert "n_samples: 100 != 200" in msg and "values not compared" in msg


def test_units():
    a = Recording.from_arrays({"v": np.ones(3)}, fs=FS, units={"v": "m"})
    b = Recording.from_arrays({"v": np.ones(3)}, fs=FS, units={"v": "N"})
    assert "units of channel 'v': 'N' != 'm'" in failure(assert_recording_allclose, b, a)


def test_metadata_only_when_asked():
    a = rec()
    b = a.with_meta(name="other", extra=1)
    assert_recording_allclose(b, a)
    msg = failure(assert_recording_equal, b, a, check_meta=True)
    assert "meta['name']: 'other' != 'run'" in msg and "meta['extra'] only in actual" in msg
    assert "actual 'other', expected 'run'" in msg


def test_all_problems_are_reported_together():
    a = rec()
    b = Recording.from_arrays({"force_x": a["force_x"] + 1, "y_current": a["x_current"]}, fs=FS, t0=0.0)
    msg = failure(assert_recording_allclose, b, a)
    assert "4 difference(s)" in msg
    for text in ("missing from actual: ['x_current']", "only in actual: ['y_current']", "t0: 0.0 s != 0.25 s",
                 "channel 'force_x' [N]: 200 of 200 samples"):  # values of shared channels still compared
        assert text in msg
    assert len(msg.splitlines()) == 5


def test_bad_arguments():
    a = rec()
    with pytest.raises(TypeError, match="expected must be a drivesense Recording"):
        assert_recording_allclose(a, a.dataset)
    with pytest.raises(ValueError, match="non-negative"):
        assert_recording_allclose(a, a, rtol=-1.0)
