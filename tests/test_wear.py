"""Tool-life simulation and the wear tracker: physics sanity, rules on exact patterns, the percent-power
indicator's moving threshold, empty sessions and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.identify.coefficients import CutTable, fit_tangential_coefficients
from drivesense.machine.cutting_power import CutConditions, cutting_power
from drivesense.condition.wear import WearTracker, WearTrackerSettings, percent_power_increase, track_wear
from drivesense.sim.tool_life import simulate_tool_life, table1_experiments

runner = CliRunner()
H = np.array([9e-6, 12e-6, 15e-6, 18e-6, 21e-6, 25e-6])
KTC, KTE = 2000e6, 35e3


def fit_of(ktc, kte, rng):
    """A calibration of six cuts with 1 % noise on F_t/a."""
    y = ktc * H + kte
    return fit_tangential_coefficients(H, y * (1 + rng.normal(0, 0.01, H.size)), warn=False)


# ----------------------------------------------------------------------------- simulator
def test_simulation_is_seeded_and_reaches_its_life_criterion():
    a, b = simulate_tool_life("B", 4), simulate_tool_life("B", 4)
    np.testing.assert_array_equal(a.spindle_power, b.spindle_power)
    assert a.failure_distance == b.failure_distance
    assert not np.array_equal(a.spindle_power, simulate_tool_life("B", 5).spindle_power)
    t = a.truth
    assert len(t["distance"]) >= 5 and np.all(np.diff(t["distance"]) > 0)
    assert t["distance"][-1] < a.failure_distance
    assert t["VB"][0] == 0.0 and t["VB"][-1] > 0.1e-3                  # worn, in metres
    assert a.table.calibration.max() == len(t["distance"]) - 1


def test_flank_wear_raises_kte_and_chipping_lowers_it():
    life = simulate_tool_life("A", 1)                                   # HSS, flank wear
    t = life.truth
    assert life.failure_mode == "flank" and not life.chips
    assert np.all(np.diff(t["VB"]) > 0) and np.all(np.diff(t["Kte"]) > 0)
    assert t["Kte"][-1] > 2 * t["Kte"][0]                               # rubbing on the flank land
    assert t["Ktc"][-1] / t["Ktc"][0] - 1 < 0.5
    chipped = simulate_tool_life("C", 1)
    assert chipped.failure_mode == "chipping"
    tc = chipped.truth
    assert len(chipped.chips) >= 3
    assert tc["Ktc"][-1] > 1.2 * tc["Ktc"][0]                           # blunted edge shears harder
    assert tc["Kte"][-1] < tc["Kte"].max() - 5e3                        # the chips took flank land away


def test_unknown_experiment():
    with pytest.raises(ConfigError, match="unknown experiment"):
        simulate_tool_life("Z")
    assert sorted(table1_experiments()) == list("ABCDEFGH")


# ----------------------------------------------------------------------------- tracker rules
def test_flank_pattern_progresses_then_alarms_when_ktc_rises():
    rng = np.random.default_rng(0)
    tracker = WearTracker()
    states = []
    for k in range(14):                                                  # K_te linear, K_tc flat ...
        states.append(tracker.update(fit_of(KTC, KTE + 5e3 * k, rng), distance=0.5 * k))
    assert states[0].state == "new" and states[6].state == "progressing" and not tracker.alarm
    assert states[-1].mode == "flank"
    alarm = tracker.update(fit_of(1.5 * KTC, KTE + 70e3, rng), distance=7.0)   # ... then K_tc jumps
    assert alarm.state == "near end of life" and alarm.alarm and "K_tc up" in alarm.evidence
    assert tracker.update(fit_of(KTC, KTE + 70e3, rng), distance=7.5).alarm    # latched


def test_accelerating_wear_raises_the_alarm_without_a_ktc_jump():
    rng = np.random.default_rng(1)
    tracker = WearTracker()
    kte = [KTE + 3e3 * k for k in range(10)] + [KTE + 27e3 + 9e3, KTE + 27e3 + 20e3, KTE + 27e3 + 35e3]
    states = [tracker.update(fit_of(KTC, v, rng), distance=0.5 * k) for k, v in enumerate(kte)]
    assert not any(s.alarm for s in states[:10])
    assert states[-1].alarm and "accelerating" in states[-1].evidence


def test_chipping_pattern():
    rng = np.random.default_rng(2)
    tracker = WearTracker()
    for k in range(6):
        tracker.update(fit_of(KTC, KTE + 4e3 * k, rng), distance=k)
    s = tracker.update(fit_of(1.25 * KTC, KTE + 2e3, rng), distance=6)       # K_tc up, K_te down: a chip
    s = tracker.update(fit_of(1.27 * KTC, KTE + 3e3, rng), distance=7)
    assert s.mode == "chipping" and "chipping" in s.evidence


def test_tracks_a_simulated_tool_life():
    life = simulate_tool_life("A", 4)
    report = track_wear(life.table, reference=life.reference_index)
    assert report.mode == life.failure_mode == "flank"
    assert report.alarm_distance is not None and report.alarm_distance < life.failure_distance
    d = report.to_dict()
    assert d["calibrations"] == len(life.truth["distance"]) and d["alarm"] is True
    json.dumps(d)                                                        # JSON-ready


def test_percent_power_threshold_moves_with_the_cutting_conditions():
    """The paper's warning (Sec. 5.2, 5.4): the end-of-life percent power increase depends on h_avg."""
    life = simulate_tool_life("A", 4)
    first = np.flatnonzero(life.table.calibration == 0)
    h = np.array([life.table.cuts[i].average_chip_thickness for i in first])
    thin, thick = int(np.argmin(h)), int(np.argmax(h))
    end = {}
    for name, ref in (("thin", thin), ("thick", thick)):
        end[name] = track_wear(life.table, reference=ref).states[-1].percent_power
    assert h[thick] / h[thin] > 2.5
    assert end["thin"] > 1.4 * end["thick"]              # same tool, same wear: different "threshold"
    # and, at one reference, the wear mode moves it too: chipping ends a life at a much smaller increase
    flank = track_wear(simulate_tool_life("C", 0).table).states[-1].percent_power
    chip = next(track_wear(L.table).states[-1].percent_power for L in (simulate_tool_life("C", s) for s in range(3, 30))
                if L.failure_mode == "chipping")
    assert chip < flank


def test_percent_power_increase():
    assert percent_power_increase(150.0, 100.0) == pytest.approx(50.0)
    np.testing.assert_allclose(percent_power_increase([100.0, 300.0], 100.0), [0.0, 200.0])
    with pytest.raises(InvalidSignalError, match="baseline"):
        percent_power_increase(1.0, 0.0)


# ----------------------------------------------------------------------------- bad input
def test_empty_and_clockless_sessions():
    with pytest.raises(InvalidSignalError, match="no cuts"):
        CutTable((), [], calibration=[])
    cuts = [CutConditions(12.7e-3, 1, 2.54e-3, 111.8, f) for f in (2e-5, 4e-5, 6e-5)]
    table = CutTable(cuts, cutting_power(KTC, KTE, cuts))
    with pytest.raises(ConfigError, match="no wear clock"):
        track_wear(table)
    with pytest.raises(ConfigError, match="reference"):
        track_wear(CutTable(cuts, cutting_power(KTC, KTE, cuts), calibration=[0, 0, 0]), reference=5)


def test_tracker_input_checks():
    rng = np.random.default_rng(3)
    tracker = WearTracker()
    tracker.update(fit_of(KTC, KTE, rng), distance=1.0)
    with pytest.raises(InvalidSignalError, match="distance"):
        tracker.update(fit_of(KTC, KTE, rng), distance=0.5)
    with pytest.raises(ConfigError, match="fit"):
        tracker.update("fit", distance=2.0)
    with pytest.raises(ConfigError, match="window"):
        WearTrackerSettings(window=1)
    with pytest.raises(ConfigError, match="z"):
        WearTrackerSettings(z=-1.0)


# ----------------------------------------------------------------------------- CLI
def test_cli_simulate_track_and_calibrate(tmp_path):
    session = tmp_path / "G.csv"
    res = runner.invoke(app, ["wear", "simulate", "G", "--seed", "2", "--out", str(session),
                              "--json", str(tmp_path / "truth.json")])
    assert res.exit_code == 0, res.output
    assert session.read_text().startswith("calibration,distance [m],")      # the header first: pandas reads it
    assert len(pd.read_csv(session).columns) == 11
    assert "experiment G" in json.loads((tmp_path / "G.csv.json").read_text())["source"]
    res = runner.invoke(app, ["wear", "track", str(session), "--json", str(tmp_path / "track.json"),
                              "--plot", str(tmp_path / "track.png")])
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "track.json").read_text())
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert info["calibrations"] == len(truth["truth"]["distance"]) and info["mode"] in ("flank", "chipping")
    nxt = info["next_calibration"]          # the session's metadata: 0.61 m interval, 152.4 mm passes
    assert nxt["fixed_interval_m"] == pytest.approx(0.61) and nxt["cut_length_m"] == pytest.approx(0.1524)
    assert nxt["cuts"] == int(nxt["interval_m"] / 0.1524 + 1e-9) >= 1 and 0.25 <= nxt["factor_of_fixed_interval"] <= 3
    assert f"next calibration after {nxt['cuts']} cut(s)" in " ".join(res.output.split())
    res = runner.invoke(app, ["wear", "track", str(session), "--cut-length", "50", "--interval", "1.0",
                              "--json", str(tmp_path / "track2.json")])
    nxt = json.loads((tmp_path / "track2.json").read_text())["next_calibration"]
    assert res.exit_code == 0 and nxt["fixed_interval_m"] == 1.0 and nxt["cut_length_m"] == pytest.approx(0.05)
    res = runner.invoke(app, ["wear", "track", str(session), "--cut-length", "-1"])
    assert res.exit_code == 2 and "--cut-length must be > 0" in " ".join(res.output.split())
    assert (tmp_path / "track.png").stat().st_size > 20_000
    res = runner.invoke(app, ["wear", "calibrate", str(session)])        # several calibrations: must choose
    assert res.exit_code == 2 and "--calibration" in res.output
    res = runner.invoke(app, ["wear", "calibrate", str(session), "--calibration", "1"])
    assert res.exit_code == 0 and "K_tc" in res.output


def test_cli_empty_session_exits_2(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_text("calibration,distance [m],diameter [mm],flutes,axial_depth [mm],spindle_speed [rpm],"
                    "feed_per_tooth [mm],entry_angle [deg],exit_angle [deg],spindle_power [W],air_power [W]\n")
    res = runner.invoke(app, ["wear", "track", str(path)])
    assert res.exit_code == 2 and "no data rows" in res.output
    res = runner.invoke(app, ["wear", "simulate", "Q", "--out", str(tmp_path / "q.csv")])
    assert res.exit_code == 2 and "unknown experiment" in res.output
