"""Adaptive calibration cadence on closed-form trends (linear, accelerating, step), its bounds and input
checks, and the simulator's cadence hook."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.condition.cadence import AdaptiveCadence, CadenceSettings, propose_interval
from drivesense.sim.tool_life import simulate_tool_life, table1_experiments

BASE = 1.0                       # m, the fixed cadence's interval
SETTINGS = CadenceSettings(step=0.06, shortest=0.25, longest=2.0, z=3.0, window=3)


def proposals(trend, distances, se=0.0):
    """The interval proposed after each calibration of an exact trend y(d) (y(0) = 1)."""
    out = []
    for n in range(2, len(distances) + 1):
        d = distances[:n]
        y = trend(d)
        p = propose_interval(d, {"F_ref": (y, np.full(n, se))}, BASE, SETTINGS)
        out.append(p)
    return out


def test_linear_trend_gives_a_constant_interval_of_step_over_slope():
    slope = 0.05                                   # per m: 6 % takes 1.2 m
    d = np.arange(0.0, 8.0, 1.0)
    got = proposals(lambda x: 1 + slope * x, d)
    np.testing.assert_allclose([p.interval for p in got], SETTINGS.step / slope, rtol=1e-9)
    assert all("rising" in p.reason for p in got)


def test_accelerating_trend_shrinks_the_interval_to_the_extrapolated_step():
    # y = 1 + a d + b d^3: the slope and curvature grow, so each proposal is shorter than the one before
    trend = lambda x: 1 + 0.03 * x + 0.0005 * x ** 3  # noqa: E731
    d = np.arange(0.0, 8.0, 1.0)
    got = [p.interval for p in proposals(trend, d)]
    assert all(b < a for a, b in zip(got[2:], got[3:])) and got[-1] > SETTINGS.shortest * BASE
    # at the last point the proposal moves the local quadratic by exactly one step
    x = d[-4:] - d[-1]
    c, b, _ = np.polyfit(x, trend(d[-4:]), 2)
    assert b * got[-1] + c * got[-1] ** 2 == pytest.approx(SETTINGS.step, rel=1e-6)
    # and never longer than the linear extrapolation of the same slope would give
    assert got[-1] < SETTINGS.step / (0.03 + 3 * 0.0005 * d[-1] ** 2) * 1.0001


def test_step_brings_the_next_calibration_in_at_the_shortest_interval():
    trend = lambda x: 1 + 0.01 * x + 0.2 * (x >= 5.0)  # noqa: E731  a 20 % jump (a chip) at 5 m
    d = np.arange(0.0, 8.0, 1.0)
    got = proposals(trend, d, se=0.005)
    by_last = {float(d[i + 1]): p for i, p in enumerate(got)}
    assert by_last[5.0].interval == SETTINGS.shortest * BASE and "jumped" in by_last[5.0].reason
    assert by_last[4.0].interval == SETTINGS.longest * BASE         # flat before: the longest interval
    # a jump within the noise does not count
    quiet = propose_interval(d[:6], {"F_ref": (trend(d[:6]), np.full(6, 0.1))}, BASE, SETTINGS)
    assert "jumped" not in quiet.reason


def test_flat_or_falling_signals_get_the_longest_interval_and_few_points_the_fixed_one():
    d = np.arange(0.0, 5.0)
    flat = propose_interval(d, {"F_ref": (np.ones(5), np.zeros(5))}, BASE, SETTINGS)
    assert flat.interval == SETTINGS.longest * BASE and flat.factor == SETTINGS.longest
    falling = propose_interval(d, {"K_tc": (1 - 0.01 * d, np.zeros(5))}, BASE, SETTINGS)
    assert falling.interval == SETTINGS.longest * BASE
    one = propose_interval([0.0], {"F_ref": ([1.0], [0.0])}, BASE, SETTINGS)
    assert one.interval == BASE and "fixed interval" in one.reason
    steep = propose_interval(d, {"F_ref": (1 + 0.5 * d, np.zeros(5))}, BASE, SETTINGS)
    assert steep.interval == SETTINGS.shortest * BASE                 # 6 % in 0.12 m: clipped


def test_the_fastest_signal_sets_the_interval():
    d = np.arange(0.0, 6.0)
    p = propose_interval(d, {"F_ref": (1 + 0.01 * d, np.zeros(6)), "K_tc": (1 + 0.04 * d, np.zeros(6))}, BASE,
                         SETTINGS)
    assert p.interval == pytest.approx(SETTINGS.step / 0.04) and p.reason.startswith("K_tc")


def test_proposal_in_cuts():
    p = propose_interval(np.arange(4.0), {"F_ref": (1 + 0.05 * np.arange(4.0), np.zeros(4))}, BASE, SETTINGS)
    assert p.cuts(0.1524) == math.floor(1.2 / 0.1524)
    assert p.cuts(10.0) == 1                                            # at least one cut
    with pytest.raises(ConfigError, match="cut length"):
        p.cuts(0.0)


def test_input_checks():
    with pytest.raises(ConfigError, match="fixed calibration interval"):
        propose_interval([0, 1], {"F_ref": ([1, 1], [0, 0])}, 0.0)
    with pytest.raises(InvalidSignalError, match="non-decreasing"):
        propose_interval([1, 0], {"F_ref": ([1, 1], [0, 0])}, 1.0)
    with pytest.raises(InvalidSignalError, match="'F_ref' has 3 values"):
        propose_interval([0, 1], {"F_ref": ([1, 1, 1], [0, 0, 0])}, 1.0)
    with pytest.raises(InvalidSignalError, match="start at a value > 0"):
        propose_interval([0, 1], {"F_ref": ([0, 1], [0, 0])}, 1.0)
    with pytest.raises(ConfigError, match="'shortest'"):
        CadenceSettings(shortest=3.0, longest=2.0)
    with pytest.raises(ConfigError, match="'window'"):
        CadenceSettings(window=1)


def test_simulator_follows_the_cadence_and_continuous_experiments_ignore_it():
    exp = table1_experiments()["G"]
    asked = []

    def every_half(table, distance):
        asked.append((len(table), distance))
        return 0.5 * exp.calibration_interval

    life = simulate_tool_life("G", 3, cadence=every_half)
    d = life.truth["distance"]
    assert np.allclose(np.diff(d)[:5] - np.diff(d)[0], 0.0)
    fixed = simulate_tool_life("G", 3)
    # the calibration cuts do not wear the tool on aluminium: the wear-cut distance between calibrations is the cadence's
    assert np.diff(d)[0] == pytest.approx(np.diff(fixed.truth["distance"])[0] - 0.5 * exp.calibration_interval)
    assert asked and all(n == len(exp.calibration_cuts()) for n, _ in asked)
    cont = AdaptiveCadence(1.0)
    simulate_tool_life("A", 1, max_calibrations=3, cadence=cont)
    assert cont.proposals == []                                        # every sweep is a calibration
    with pytest.raises(ConfigError, match="cadence proposed"):
        simulate_tool_life("G", 3, cadence=lambda t, d: float("nan"))


def test_a_tool_chips_the_same_whatever_the_cadence():
    """Chipping has a random stream of its own (common random numbers): another cadence on a tool whose
    calibration cuts do not wear it (aluminium) gives the same chips, in the same order and depths."""
    exp = table1_experiments()["H"]
    fixed = simulate_tool_life("H", 8)
    dense = simulate_tool_life("H", 8, cadence=lambda table, distance: 0.5 * exp.calibration_interval)
    assert len(fixed.chips) >= 3
    assert [depth for _, depth in dense.chips] == [depth for _, depth in fixed.chips]
    assert len(dense.truth["distance"]) > 1.8 * len(fixed.truth["distance"])
