"""Assertions for tests that compare :class:`~drivesense.recording.Recording` objects.

In the spirit of :mod:`numpy.testing` and :mod:`xarray.testing`: the functions
return None when the recordings agree and raise :class:`AssertionError`
otherwise, with a message that lists *every* difference found (channel set,
sampling rate, start time, length, units, metadata and, per channel, the
values) rather than only the first one.

>>> import numpy as np
>>> from drivesense.recording import Recording
>>> from drivesense.testing import assert_recording_allclose
>>> a = Recording.from_arrays({"force_x": np.zeros(4)}, fs=1000.0)
>>> assert_recording_allclose(a, a.with_channels({"force_x": np.full(4, 1e-12)}), atol=1e-9)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drivesense.recording import Recording
from drivesense.timebase import format_time

__all__ = ["assert_recording_allclose", "assert_recording_equal"]

#: Relative tolerance on the sampling rates in :func:`assert_recording_allclose` [-].
FS_RTOL = 1e-12
#: Tolerance on the start times in :func:`assert_recording_allclose`, in samples [-]
#: (the tolerance :class:`~drivesense.recording.Recording` allows on its time grid).
T0_TOL_SAMPLES = 1e-6


def _who(rec: Recording) -> str:
    return repr(rec.name) if rec.name else "<unnamed>"


def _channel_problems(name: str, a: np.ndarray, e: np.ndarray, rtol: float, atol: float,
                      expected: Recording, unit: str) -> str | None:
    """One line describing how channel `name` differs, or None when it agrees."""
    with np.errstate(invalid="ignore", over="ignore"):
        diff = np.abs(a - e)
        bad = ~np.isclose(a, e, rtol=rtol, atol=atol, equal_nan=True)
    if not bad.any():
        return None
    # the worst sample is the one furthest outside the tolerance
    excess = np.where(bad, np.nan_to_num(diff, nan=np.inf) - (atol + rtol * np.abs(e)), -np.inf)
    i = int(np.argmax(excess))
    finite = np.isfinite(diff)
    max_abs = float(diff[finite].max()) if finite.any() else math.inf
    nonzero = finite & (e != 0)
    max_rel = float((diff[nonzero] / np.abs(e[nonzero])).max()) if nonzero.any() else math.inf
    fs = expected.fs
    t = format_time(expected.t0 + i / fs, fs)
    return (f"channel {name!r} [{unit}]: {int(bad.sum())} of {bad.size} samples "
            f"({100.0 * bad.sum() / bad.size:.3g} %) differ; max abs diff {max_abs:.6g} [{unit}], "
            f"max rel diff {max_rel:.6g} [-]; worst sample {i} (t = {t} s): "
            f"actual {a[i]!r}, expected {e[i]!r}")


def _compare(actual: Recording, expected: Recording, *, rtol: float, atol: float,
             channels: Sequence[str] | None, check_meta: bool, exact: bool) -> None:
    for label, rec in (("actual", actual), ("expected", expected)):
        if not isinstance(rec, Recording):
            raise TypeError(f"{label} must be a drivesense Recording, got {type(rec).__name__}")
    if not (rtol >= 0 and atol >= 0):
        raise ValueError(f"rtol and atol must be non-negative, got rtol={rtol!r}, atol={atol!r}")
    problems: list[str] = []

    # which channels
    if channels is None:
        a_set, e_set = set(actual.channels), set(expected.channels)
        missing = [c for c in expected.channels if c not in a_set]
        extra = [c for c in actual.channels if c not in e_set]
        if missing:
            problems.append(f"channels missing from actual: {missing}")
        if extra:
            problems.append(f"channels only in actual: {extra}")
        compared = [c for c in expected.channels if c in a_set]
    else:
        if isinstance(channels, str):
            channels = [channels]
        compared = []
        for c in dict.fromkeys(channels):
            where = [label for label, rec in (("actual", actual), ("expected", expected)) if c not in rec]
            if where:
                problems.append(f"channel {c!r} missing from {' and '.join(where)}")
            else:
                compared.append(c)

    # time base
    if exact:
        fs_ok, t0_ok = actual.fs == expected.fs, actual.t0 == expected.t0
    else:
        fs_ok = math.isclose(actual.fs, expected.fs, rel_tol=FS_RTOL, abs_tol=0.0)
        t0_ok = abs(actual.t0 - expected.t0) <= T0_TOL_SAMPLES / expected.fs
    if not fs_ok:
        problems.append(f"fs: {actual.fs!r} Hz != {expected.fs!r} Hz")
    if not t0_ok:
        problems.append(f"t0: {actual.t0!r} s != {expected.t0!r} s "
                        f"(differ by {(actual.t0 - expected.t0) * expected.fs:.6g} samples)")
    same_length = actual.n_samples == expected.n_samples
    if not same_length:
        problems.append(f"n_samples: {actual.n_samples} != {expected.n_samples} "
                        "(values not compared)")

    # units, then values, channel by channel
    for c in compared:
        ua, ue = actual.units(c), expected.units(c)
        if ua != ue:
            problems.append(f"units of channel {c!r}: {ua!r} != {ue!r}")
        if same_length:
            line = _channel_problems(c, np.asarray(actual[c]), np.asarray(expected[c]), rtol, atol,
                                     expected, ue)
            if line is not None:
                problems.append(line)

    # metadata
    if check_meta:
        ma, me = actual.meta, expected.meta
        for k in sorted(set(ma) | set(me)):
            if k not in ma:
                problems.append(f"meta[{k!r}] missing from actual (expected {me[k]!r:.80})")
            elif k not in me:
                problems.append(f"meta[{k!r}] only in actual ({ma[k]!r:.80})")
            elif ma[k] != me[k]:
                problems.append(f"meta[{k!r}]: {ma[k]!r:.80} != {me[k]!r:.80}")

    if problems:
        how = "are not equal" if exact else f"are not close (rtol={rtol:g}, atol={atol:g})"
        head = f"Recordings {how}: actual {_who(actual)}, expected {_who(expected)}; {len(problems)} difference(s):"
        raise AssertionError("\n".join([head, *(f"  - {p}" for p in problems)]))


def assert_recording_allclose(actual: Recording, expected: Recording, *, rtol: float = 1e-7,
                              atol: float = 0.0, channels: Sequence[str] | None = None,
                              check_meta: bool = False) -> None:
    """Raise AssertionError unless two recordings agree to a tolerance.

    Checked, and all reported together: the channel sets (order is not
    compared), the sampling rate (relative 1e-12), the start time (within
    1e-6 samples), the number of samples, each channel's unit, each channel's
    values (``|actual - expected| <= atol + rtol * |expected|``, as
    :func:`numpy.isclose`) and, with `check_meta`, the metadata.

    Parameters
    ----------
    actual : Recording
        The recording under test.
    expected : Recording
        The reference; the reported times are on its time grid.
    rtol : float, optional
        Relative tolerance on the values [-] (default 1e-7).
    atol : float, optional
        Absolute tolerance on the values [in each channel's SI unit] (default 0).
    channels : sequence of str, optional
        Compare only these channels (each must be in both recordings); default
        all, and the two channel sets must be equal.
    check_meta : bool, optional
        Also require equal metadata (``Recording.meta``, compared key by key).

    Raises
    ------
    AssertionError
        Listing every difference: for each differing channel the number of
        samples outside the tolerance, the largest absolute and relative
        differences, and the index and time [s] of the worst sample (the one
        furthest outside the tolerance) with both values there.
    TypeError
        If `actual` or `expected` is not a Recording.
    ValueError
        If `rtol` or `atol` is negative.

    See Also
    --------
    assert_recording_equal : The exact comparison.
    numpy.testing.assert_allclose : The same tolerance for plain arrays.
    """
    _compare(actual, expected, rtol=float(rtol), atol=float(atol), channels=channels,
             check_meta=check_meta, exact=False)


def assert_recording_equal(actual: Recording, expected: Recording, *,
                           channels: Sequence[str] | None = None, check_meta: bool = False) -> None:
    """Raise AssertionError unless two recordings hold exactly the same data.

    Like :func:`assert_recording_allclose` with zero tolerances, and the
    sampling rates and start times compared exactly as well.

    Parameters
    ----------
    actual : Recording
        The recording under test.
    expected : Recording
        The reference.
    channels : sequence of str, optional
        Compare only these channels (each must be in both recordings); default
        all, and the two channel sets must be equal.
    check_meta : bool, optional
        Also require equal metadata.

    Raises
    ------
    AssertionError
        Listing every difference, as :func:`assert_recording_allclose` does.
    TypeError
        If `actual` or `expected` is not a Recording.

    See Also
    --------
    Recording.equals : The same question answered with a bool (channel order
        and metadata included).
    """
    _compare(actual, expected, rtol=0.0, atol=0.0, channels=channels, check_meta=check_meta, exact=True)
