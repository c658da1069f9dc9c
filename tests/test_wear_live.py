"""Wear as a live event (issue #31, item 5): each production cut's spindle power against the last calibration.

Known truth from the tool-life simulator (its production passes and their true VB) and from exact
power of the cutting model; its events are the detectors' Event record.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.condition.wear_live import (LiveWearMonitor, LiveWearSettings, cut_power, remaining_life,
                                            track_wear_live)
from drivesense.errors import ConfigError, MissingChannelError, NotFittedError
from drivesense.identify.coefficients import fit_cut_table
from drivesense.machine.cutting_power import CutConditions, CutTable, cutting_power
from drivesense.recording import Recording
from drivesense.sim.tool_life import simulate_tool_life

KTC, KTE = 2000e6, 35e3
CUTS = [CutConditions(12.7e-3, 1, 2.54e-3, 160.0, f * 1e-3, a, math.pi)
        for a in (0.0, math.pi / 2) for f in (0.03, 0.05, 0.07)]
PROD = CutConditions(12.7e-3, 1, 2.54e-3, 160.0, 0.05e-3, math.pi / 3, math.pi)


def _calibration(ktc=KTC, kte=KTE):
    return fit_cut_table(CutTable(CUTS, cutting_power(ktc, kte, CUTS)), warn=False)


def test_simulated_production_passes_leave_the_calibrations_unchanged():
    life = simulate_tool_life("C", 3)
    again = simulate_tool_life("C", 3)
    np.testing.assert_array_equal(life.production.cutting_power, again.production.cutting_power)
    assert len(life.production) > 5 * len(life.table.groups())          # 22 passes between calibrations
    d = life.production.distance
    assert np.all(np.diff(d) > 0) and d[-1] < life.failure_distance
    assert np.all(np.diff(life.production_truth["VB"][:20]) > 0)          # before the first chip: wear only grows
    assert simulate_tool_life("A", 3).production is None                  # continuous: every cut calibrates


def test_residual_is_zero_for_the_calibrated_tool_and_rises_with_wear():
    mon = LiveWearMonitor()
    mon.calibrate(_calibration(), 0.0)
    row, events = mon.push(PROD, float(cutting_power(KTC, KTE, PROD)), 0.1)
    assert abs(row.residual) < 1e-9 and not events
    worn = float(cutting_power(KTC, KTE * 1.5, PROD))                    # flank land: K_te up by half
    row, _ = mon.push(PROD, worn, 0.2)
    assert 0.1 < row.residual < 0.5


def test_residual_on_a_simulated_life_follows_the_true_wear():
    life = simulate_tool_life("C", 2)
    rep = track_wear_live(life.table, life.production, LiveWearSettings(use_tracker=False))
    res = np.array([c.residual for c in rep.cuts])
    level = np.array([c.level for c in rep.cuts])
    first = life.production.distance < life.table.groups()[1][0]       # against the new tool's calibration
    assert abs(np.median(res[first][:5])) < 0.05                          # ~0 at the start
    vb = life.production_truth["VB"]
    clean = life.production_truth["chip_depth"] == 0
    assert np.corrcoef(vb[clean], level[clean])[0, 1] > 0.8              # level rises with the true flank wear


def test_event_fires_before_failure_on_a_simulated_life():
    life = simulate_tool_life("B", 1)
    rep = track_wear_live(life.table, life.production)
    assert rep.events and rep.alarm_distance < life.failure_distance
    event = rep.events[0]
    assert event.kind == "wear" and event.axis == "spindle"
    assert {"rule", "distance_m"} <= set(event.evidence)
    assert rep.to_dict()["alarm"] and rep.to_dict()["events"][0]["kind"] == "wear"


def test_a_wear_event_is_the_detectors_event_record_in_strict_json():
    from drivesense.events.detector import Event

    life = simulate_tool_life("B", 1)
    event = track_wear_live(life.table, life.production).events[0]
    assert isinstance(event, Event)
    inf = Event("wear", 12.0, "spindle", 0.7, 0.0, "live_wear", {"remaining_distance_m": math.inf})
    assert inf.to_json()["evidence"]["remaining_distance_m"] is None      # strict JSON


def test_remaining_life_on_a_linear_trend():
    x = np.linspace(0.0, 5.0, 40)
    rng = np.random.default_rng(0)
    y = 0.08 * x + rng.normal(0.0, 0.01, x.size)                          # +8 % per m, 1 % noise
    remaining, slope, now = remaining_life(x, y, 1.0)
    assert remaining == pytest.approx((1.0 - 0.4) / 0.08, rel=0.10)      # 7.5 m within 10 %
    assert slope == pytest.approx(0.08, rel=0.10) and now == pytest.approx(0.4, abs=0.02)
    assert remaining_life(x, -y, 1.0)[0] == math.inf
    assert remaining_life(x, y + 1.0, 1.0)[0] == 0.0


def test_monitor_predicts_remaining_life_of_an_exact_linear_wear():
    s = LiveWearSettings(use_tracker=False, failure_rise=0.5)
    mon = LiveWearMonitor(s)
    mon.calibrate(_calibration(), 0.0)
    p0 = float(cutting_power(KTC, KTE, PROD))
    for k in range(40):
        row, _ = mon.push(PROD, p0 * (1 + 0.05 * k * 0.1), 0.1 * (k + 1))   # level +5 % per m
    # level now 0.05 * 3.9 m of wear (the baseline's median cut is the new tool) -> (0.5 - level) / 0.05 m left
    expected = (0.5 - 0.05 * (3.9 - 0.2)) / 0.05
    assert row.remaining_distance == pytest.approx(expected, rel=0.05)


def test_bad_input_gets_a_one_line_error():
    mon = LiveWearMonitor()
    with pytest.raises(NotFittedError, match="no calibration yet") as exc:
        mon.push(PROD, 100.0, 0.1)
    assert "\n" not in str(exc.value)
    mon.calibrate(_calibration(), 0.0)
    with pytest.raises(ValueError, match="cutting_power"):
        mon.push(PROD, float("nan"), 0.1)
    with pytest.raises(ValueError, match="non-decreasing"):
        mon.push(PROD, 100.0, -1.0)
    rec = Recording.from_arrays({"spindle_speed": np.full(200, 160.0)}, fs=100.0)
    with pytest.raises(MissingChannelError, match="spindle_power") as exc:
        cut_power(rec, (1.0, 2.0), (0.0, 0.5))
    assert "\n" not in str(exc.value)
    with pytest.raises(ConfigError, match="distance"):
        track_wear_live(CutTable(CUTS, cutting_power(KTC, KTE, CUTS), calibration=[0] * 6),
                        CutTable([PROD], [100.0]))
    with pytest.raises(ConfigError, match="failure_rise"):
        LiveWearSettings(failure_rise=0.0)


def test_cut_power_from_a_trace():
    t = np.arange(400) / 100.0
    power = np.where(t >= 2.0, 900.0, 300.0)
    rec = Recording.from_arrays({"spindle_power": power}, fs=100.0)
    assert cut_power(rec, (2.5, 3.9), (0.5, 1.5)) == pytest.approx(600.0)
