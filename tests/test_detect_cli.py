"""``drivesense detect`` and ``drivesense teach`` as a user meets them: a simulated breakage written to CSV in
mm, the same cut without it, teach-in from good runs, and every bad input (a clear message, exit 2)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.io import write_csv
from drivesense.sim.process_events import ProcessEvent, simulate_event_cut
from drivesense.sim.scenarios import CutCondition, ScenarioSettings, simulate_idle

runner = CliRunner()
MM = {"x_table_position": "mm", "y_table_position": "mm"}


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("detect")
    assert invoke("axis", "--out", d / "axis.toml").exit_code == 0
    cond = CutCondition("t", "feed", 1.5e-3, 4000.0, feed_speed=3e-3, axial_depth=1e-3)
    settings = replace(ScenarioSettings(), duration=4.0, t_contact=0.8)
    for name, events, seed in (("broken", (ProcessEvent("breakage", 3.2, flute=1),), 3), ("good", (), 4),
                               ("good2", (), 5), ("good3", (), 6),
                               ("missing", (ProcessEvent("missing_tool", 0.8),), 7)):
        rec = simulate_event_cut(cond, events=events, settings=settings, seed=seed)
        write_csv(rec, d / f"{name}.csv", units=MM)
    for k, rec in enumerate(simulate_idle(cond, settings, repeats=2, seed=50)):
        write_csv(rec, d / f"idle{k}.csv", units=MM)
    return d


def _detect(work: Path, trace: str, *extra):
    return invoke("detect", work / trace, "--axis", work / "axis.toml", "--idle", work / "idle0.csv",
                  "--idle", work / "idle1.csv", "--teeth", 2, *extra)


def test_breakage_in_a_csv_trace_in_mm(work):
    res = _detect(work, "broken.csv", "--json", work / "broken.json", "--plot", work / "broken.png")
    assert res.exit_code == 0, res.output
    doc = json.loads((work / "broken.json").read_text())
    kinds = [e["kind"] for e in doc["events"]]
    assert kinds and kinds[0] in ("breakage", "chipping")
    first = doc["events"][0]
    assert 3.2 < first["time_s"] < 3.2 + 2 * 60 / 4000.0        # within two revolutions
    assert first["axis"] == "x" and 0 <= first["confidence"] <= 1 and first["latency_s"] > 0
    assert doc["latency_s"] >= first["latency_s"]
    assert (work / "broken.png").stat().st_size > 10_000


def test_no_event_without_one(work):
    res = _detect(work, "good.csv", "--json", work / "good.json")
    assert res.exit_code == 0, res.output
    assert json.loads((work / "good.json").read_text())["events"] == []


def test_teach_then_detect_a_missing_tool(work):
    res = invoke("teach", work / "good2.csv", work / "good3.csv", "--axis", work / "axis.toml", "--idle",
                 work / "idle0.csv", "--idle", work / "idle1.csv", "--out", work / "limits.json")
    assert res.exit_code == 0, res.output
    limits = json.loads((work / "limits.json").read_text())
    # the simulated runs carry the NC's block numbers: bins per block, counted along the path within each
    assert limits["align"] == "block" and limits["within"] == "path" and limits["runs"] == 2
    assert limits["force_limit_n"] > 0 and [g["block"] for g in limits["segments"]] == [20.0]
    res = _detect(work, "missing.csv", "--limits", work / "limits.json", "--json", work / "missing.json")
    assert res.exit_code == 0, res.output
    kinds = {e["kind"] for e in json.loads((work / "missing.json").read_text())["events"]}
    assert "missing_tool" in kinds
    res = _detect(work, "good.csv", "--limits", work / "limits.json", "--json", work / "good_taught.json")
    assert res.exit_code == 0, res.output
    assert json.loads((work / "good_taught.json").read_text())["events"] == []


def test_no_spindle_speed_is_refused(work, tmp_path):
    import pandas as pd

    df = pd.read_csv(work / "good.csv").drop(columns=["spindle_speed [rad/s]"])
    df.to_csv(tmp_path / "nospindle.csv", index=False)
    res = invoke("detect", tmp_path / "nospindle.csv", "--axis", work / "axis.toml", "--idle", work / "idle0.csv",
                 "--idle", work / "idle1.csv", "--teeth", 2, "--json", tmp_path / "e.json")
    assert res.exit_code == 2
    assert "--spindle-rpm" in res.output and "Traceback" not in res.output


def test_too_short_a_cut_for_a_baseline(work, tmp_path):
    res = _detect(work, "good.csv", "--baseline-revs", 5000, "--json", tmp_path / "e.json")
    assert res.exit_code == 2
    assert "baseline" in res.output and "--baseline-revs" in res.output


def test_bad_options_are_named(work, tmp_path):
    res = _detect(work, "good.csv", "--spindle-rpm", -5, "--json", tmp_path / "e.json")
    assert res.exit_code == 2 and "--spindle-rpm" in res.output
    res = _detect(work, "good.csv", "--baseline-revs", 1, "--json", tmp_path / "e.json")
    assert res.exit_code == 2 and "--baseline-revs" in res.output
    (tmp_path / "bad.json").write_text("{}")
    res = _detect(work, "good.csv", "--limits", tmp_path / "bad.json", "--json", tmp_path / "e.json")
    assert res.exit_code == 2 and "--limits" in res.output
    res = invoke("detect", work / "good.csv", "--axis", work / "axis.toml", "--teeth", 2,
                 "--json", tmp_path / "e.json")
    assert res.exit_code == 2 and "--idle" in res.output
    res = invoke("teach", work / "good2.csv", "--axis", work / "axis.toml", "--idle", work / "idle0.csv",
                 "--out", tmp_path / "l.json")
    assert res.exit_code == 2 and "2 good runs" in res.output


def test_simulate_with_an_event(tmp_path):
    res = invoke("simulate", "feed_r1.5_S4000", "--event", "chipping@6:0.5", "--out", tmp_path / "c.nc")
    assert res.exit_code == 0, res.output
    res = invoke("simulate", "cross_r1.5_S4000", "--event", "breakage@6", "--out", tmp_path / "x.nc")
    assert res.exit_code == 2 and "--event" in res.output
    res = invoke("simulate", "feed_r1.5_S4000", "--event", "explosion@6", "--out", tmp_path / "y.nc")
    assert res.exit_code == 2 and "KIND@TIME" in res.output
