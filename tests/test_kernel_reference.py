"""The compiled estimator kernel (``drivesense.estimate.kernel``) against a scipy.signal reference.

The kernel fuses, sample by sample: the first-order current-loop model, one FIR
per input channel (current, motor angle, table position, friction-map value),
their sum and the common IIR cascade, started as if every signal had been
constant at its first value (``_prime``).  Here the same output is computed
stage by stage with ``scipy.signal.lfilter`` / ``sosfilt`` and the equivalent
initial conditions, for one call and for chunked calls.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal as sps

from drivesense.estimate import MEDOB, RigidBody, SignalParams, VibrationMode
from drivesense.estimate.design import ForceCombination, discretise
from drivesense.estimate.kernel import FrictionTable, KernelState, run_kernel
from drivesense.machine.presets import table1_axis

FS = 10_000.0
AXIS = table1_axis()
N = 3000


def inputs(n: int = N, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random-ish drive signals: a noisy current [A], a moving motor angle [rad], a table position [m]."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    current = 0.8 + 0.3 * np.sin(2 * np.pi * 37 * t) + 0.05 * rng.standard_normal(n)
    angle = 3.0 + 40.0 * t + 0.2 * np.sin(2 * np.pi * 11 * t) + 1e-4 * rng.standard_normal(n)
    table = AXIS.R * angle + 2e-6 * np.sin(2 * np.pi * 230 * t) + 1e-8 * rng.standard_normal(n)
    return current, angle, table


def fir(taps: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``sum_k taps[k] x[n-k]`` with the input's history equal to its first value."""
    taps = np.asarray(taps, float)
    if taps.size == 1:
        return taps[0] * x
    zi = sps.lfiltic(taps, [1.0], [], x=np.full(taps.size - 1, x[0]))
    return sps.lfilter(taps, [1.0], x, zi=zi)[0]


def reference(design, current, angle, table, friction: FrictionTable | None = None) -> np.ndarray:
    """The kernel's output computed stage by stage with scipy.signal."""
    h = design.h_pole
    if h > 0:   # y[n] = h y[n-1] + (1 - h) u[n-1], primed at the first value
        b, a = [0.0, 1.0 - h], [1.0, -h]
        y_cur = sps.lfilter(b, a, current, zi=sps.lfiltic(b, a, [current[0]], [current[0]]))[0]
    else:
        y_cur = current
    if friction is None or friction.values.size == 1:
        fval = np.full(table.size, 0.0 if friction is None else friction.values[0])
    else:
        grid = friction.x0 + friction.dx * np.arange(friction.values.size)
        fval = np.interp(table, grid, friction.values)      # clamped at the ends
    pairs = [(design.taps_current, y_cur), (design.taps_motor, angle), (design.taps_table, table),
             (design.taps_friction, fval)]
    r = sum(fir(taps, x) for taps, x in pairs)
    r0 = sum(np.sum(taps) * x[0] for taps, x in pairs)      # the FIR sum for constant inputs
    return sps.sosfilt(design.sos, r, zi=sps.sosfilt_zi(design.sos) * r0)[0]


def run(design, friction, current, angle, table, chunks=None) -> np.ndarray:
    state = KernelState(design, friction)
    if chunks is None:
        return run_kernel(state, current, angle, table)
    edges = np.r_[0, np.cumsum(chunks)]
    assert edges[-1] == current.size
    return np.concatenate([run_kernel(state, current[i:j], angle[i:j], table[i:j])
                           for i, j in zip(edges[:-1], edges[1:])])


def assert_matches(out: np.ndarray, ref: np.ndarray) -> None:
    """Agreement to ~1e-9 of the signal's scale (the FIRs on positions cancel large terms)."""
    scale = np.max(np.abs(ref))
    assert scale > 0
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-9 * scale)


DESIGNS = {
    "VibrationMode-central": lambda: VibrationMode(AXIS).design(FS),
    "RigidBody-central": lambda: RigidBody(AXIS).design(FS),
    "MEDOB-bilinear": lambda: MEDOB(AXIS).design(FS),
    # independent of the estimator classes: a combination with every coefficient non-zero
    "all-terms-central": lambda: discretise(ForceCombination(1.0, 3.0, 40.0, 2e5, 20.0, 300.0, 1e6),
                                            AXIS, SignalParams(), FS, "central"),
    "all-terms-bilinear": lambda: discretise(ForceCombination(1.0, 3.0, 40.0, 2e5, 20.0, 300.0, 1e6),
                                             AXIS, SignalParams(), FS, "bilinear"),
    "no-current-model": lambda: discretise(ForceCombination(1.0, 3.0, 40.0, 0.0, 20.0, 300.0, 0.0),
                                           AXIS, SignalParams(omega_cc=0.0), FS, "central"),
}


@pytest.fixture(params=list(DESIGNS), scope="module")
def design(request):
    return DESIGNS[request.param]()


def test_designs_exercise_the_paths(design):
    """Guard the reference test itself: the designs are not trivial."""
    assert design.sos.shape[1] == 6 and np.any(design.taps_current) and np.any(design.taps_friction)
    assert np.any(design.taps_motor) or np.any(design.taps_table)


def test_one_call_matches_scipy(design):
    current, angle, table = inputs()
    assert_matches(run(design, FrictionTable.zero(), current, angle, table), reference(design, current, angle, table))


@pytest.mark.parametrize("chunks", [[1, 0, 2, 997, 2000], [500] * 6, [N - 1, 1], [7] * 428 + [4]],
                         ids=["uneven", "equal", "last-sample", "tiny"])
def test_chunked_calls_match_scipy_and_the_one_call(design, chunks):
    current, angle, table = inputs(seed=1)
    whole = run(design, FrictionTable.zero(), current, angle, table)
    out = run(design, FrictionTable.zero(), current, angle, table, chunks)
    assert_matches(out, reference(design, current, angle, table))
    np.testing.assert_array_equal(out, whole)   # the state carries everything


def test_constant_inputs_start_without_a_transient(design):
    """Primed at the first values: constant signals give a constant output from the first sample."""
    n = 400
    current, angle, table = np.full(n, 0.7), np.full(n, 2.0), np.full(n, AXIS.R * 2.0)
    out = run(design, FrictionTable.zero(), current, angle, table)
    ref = reference(design, current, angle, table)
    assert_matches(out, ref)
    np.testing.assert_allclose(out, out[0], rtol=1e-9, atol=1e-9 * abs(out[0]))


@pytest.mark.parametrize("name", ["VibrationMode-central", "MEDOB-bilinear"])
def test_friction_table_path(name):
    """The friction path: taps_friction on the table lookup (linear interpolation, clamped ends)."""
    design = DESIGNS[name]()
    current, angle, table = inputs(seed=2)
    # a 5-point map whose grid covers part of the travel: interior points and both clamped ends are used
    lo, hi = table.min(), table.max()
    friction = FrictionTable([12.0, -3.0, 25.0, 4.0, 9.0], x0=lo + 0.1 * (hi - lo), dx=0.2 * (hi - lo))
    assert table.min() < friction.x0 and table.max() > friction.x0 + 4 * friction.dx
    out = run(design, friction, current, angle, table)
    assert_matches(out, reference(design, current, angle, table, friction))
    assert_matches(run(design, friction, current, angle, table, [1000, 1, 1999]), reference(
        design, current, angle, table, friction))
    # the friction contribution alone, against an independent FIR of the looked-up values
    without = run(design, FrictionTable.zero(), current, angle, table)
    fval = friction(table)
    alone = sps.sosfilt(design.sos, fir(design.taps_friction, fval),
                        zi=sps.sosfilt_zi(design.sos) * np.sum(design.taps_friction) * fval[0])[0]
    assert_matches(out - without, alone)


def test_single_value_table_is_a_tare():
    design = DESIGNS["VibrationMode-central"]()
    current, angle, table = inputs(seed=3)
    out = run(design, FrictionTable([7.5]), current, angle, table)
    assert_matches(out, reference(design, current, angle, table, FrictionTable([7.5])))
    # a tare shifts the (unit-DC-gain) low-passed estimate by -7.5 N once settled
    without = run(design, FrictionTable.zero(), current, angle, table)
    np.testing.assert_allclose(out - without, -7.5, rtol=1e-9)
