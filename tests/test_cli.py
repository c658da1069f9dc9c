"""The command line as a user meets it: happy paths and every bad input of the core issue."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.io import read_csv, read_recording, write_csv, write_recording
from drivesense.sim.scenarios import ScenarioSettings, paper_conditions, simulate_cut, simulate_idle

runner = CliRunner()
USER_UNITS = {"x_table_position": "mm", "x_motor_angle": "deg", "x_current_ref": "mA"}


def invoke(*args: str):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A folder with an axis file, a cross-feed CSV trace in user units and feed traces with idle runs."""
    d = tmp_path_factory.mktemp("cli")
    assert invoke("axis", "--out", d / "axis.toml").exit_code == 0
    short = replace(ScenarioSettings(), duration=2.5, t_contact=1.2)
    cross = next(c for c in paper_conditions() if c.direction == "cross")
    feed = next(c for c in paper_conditions() if c.direction == "feed")
    cut = simulate_cut(cross, short, seed=3)
    write_csv(cut.select("x_current_ref", "x_motor_angle", "x_table_position", "force_x"), d / "cross.csv",
              units=USER_UNITS)
    feed_cut = simulate_cut(feed, short, seed=4)
    write_recording(feed_cut, d / "feed.nc")
    for k, rec in enumerate(simulate_idle(feed, short, repeats=2, seed=50)):
        write_recording(rec, d / f"idle{k}.nc")
    # an idle run over a shorter stretch of travel: does not cover the cut
    half = simulate_idle(feed, replace(short, duration=1.2), repeats=1, seed=60)[0]
    write_recording(half, d / "idle_short.nc")
    return d


def _csv_with(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _lines_from(work: Path, n: int = 400) -> list[str]:
    lines = [line for line in (work / "cross.csv").read_text().splitlines() if not line.startswith("#")]
    return lines[: n + 1]     # header and n rows, without the metadata line


# --------------------------------------------------------------------- happy
def test_estimate_csv_in_user_units_with_tare(work):
    out = work / "force.csv"
    res = invoke("estimate", work / "cross.csv", "--axis", work / "axis.toml", "--method", "vibration",
                 "--tare", "0.5:1.1", "--out", out, "--json", work / "est.json")
    assert res.exit_code == 0, res.output
    force = read_csv(out)
    assert force.channels == ["force_x"] and force.units("force_x") == "N"
    header = out.read_text().splitlines()[0]
    assert header.startswith("time [s]") and "force_x [N]" in header
    assert list(pd.read_csv(out).columns) == header.split(",")        # other tools read it with defaults
    assert read_csv(out).meta["latency_s"] == pytest.approx(0.3e-3)    # from the sidecar FORCE.csv.json
    info = json.loads((work / "est.json").read_text())
    assert info["method"] == "vibration"
    assert info["latency_s"] == pytest.approx(0.3e-3)
    # the trace carries its true force: the estimate must be close to it (NRMSE well under 10 %)
    assert info["score_vs_reference"]["nrmse"] < 0.10


def test_estimate_with_idle_runs_and_plot(work):
    res = invoke("estimate", work / "feed.nc", "--axis", work / "axis.toml", "--method", "rigid",
                 "--idle", work / "idle0.nc", "--idle", work / "idle1.nc", "--out", work / "f2.csv",
                 "--plot", work / "f2.png", "--json", work / "f2.json")
    assert res.exit_code == 0, res.output
    info = json.loads((work / "f2.json").read_text())
    assert info["compensation"] == "friction map" and info["friction_map_repeatability_n"] >= 0
    assert (work / "f2.png").stat().st_size > 10_000


def test_simulate_list_and_file(work):
    res = invoke("simulate", "--list")
    assert res.exit_code == 0 and "cross_r6_S10000" in res.output and "idle_feed_r1.5_S1000" in res.output
    res = invoke("simulate", "feed_r1.5_S4000", "--out", work / "sim.nc")
    assert res.exit_code == 0, res.output
    rec = read_recording(work / "sim.nc")
    assert {"x_current_ref", "x_motor_angle", "x_table_position", "force_x"} <= set(rec.channels)


def test_help_lists_commands():
    res = invoke("--help")
    assert res.exit_code == 0
    for cmd in ("demo", "simulate", "estimate", "bench", "axis"):
        assert cmd in res.output


# ----------------------------------------------------------------- bad input
def _bad(work, trace, *extra, axis=None):
    res = invoke("estimate", trace, "--axis", axis or work / "axis.toml", "--out", work / "bad_out.csv", *extra)
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    return " ".join(res.output.split())


@pytest.mark.parametrize("row, col, value, expect", [
    (50, 2, "nan", ["x_motor_angle [deg]", "nan", "51"]),
    (60, 1, "inf", ["x_current_ref [mA]", "inf", "61"]),
])
def test_non_finite_value_names_column_and_line(work, row, col, value, expect):
    lines = _lines_from(work)
    cells = lines[row].split(",")
    cells[col] = value
    lines[row] = ",".join(cells)
    msg = _bad(work, _csv_with(work / f"{value}.csv", "\n".join(lines)))
    for part in expect:
        assert part in msg.lower() or part in msg


def test_non_monotonic_time(work):
    lines = _lines_from(work)
    lines[30], lines[31] = lines[31], lines[30]
    msg = _bad(work, _csv_with(work / "order.csv", "\n".join(lines)))
    assert "time" in msg and ("monoton" in msg or "decreas" in msg or "increas" in msg)


def test_jittery_time(work):
    lines = _lines_from(work)
    cells = lines[100].split(",")
    cells[0] = repr(float(cells[0]) + 3e-5)
    lines[100] = ",".join(cells)
    msg = _bad(work, _csv_with(work / "jitter.csv", "\n".join(lines)))
    assert "jitter" in msg or "uniform" in msg


def test_missing_channel(work):
    rec = read_csv(work / "cross.csv")
    write_csv(rec.select("x_current_ref", "x_table_position"), work / "missing.csv")
    msg = _bad(work, work / "missing.csv")
    assert "x_motor_angle" in msg


def test_unknown_unit(work):
    lines = _lines_from(work)
    lines[0] = lines[0].replace("x_table_position [mm]", "x_table_position [furlong]")
    msg = _bad(work, _csv_with(work / "unit.csv", "\n".join(lines)))
    assert "furlong" in msg and "x_table_position" in msg


@pytest.mark.parametrize("edit, expect", [
    (lambda t: t.replace("K_t = ", "Kt = "), "Kt"),
    (lambda t: "\n".join(line for line in t.splitlines() if not line.startswith("K_r")), "K_r"),
    (lambda t: t.replace("M_t = 6.55", "M_t = -6.55"), "M_t"),
    (lambda t: t.replace("lpf_order = 4", "lpf_order = 4.5"), "lpf_order"),
    (lambda t: t.replace("[axis]", "[axis"), "TOML"),
    (lambda t: t.replace("T_b = ", "T_bee = "), "T_bee"),
])
def test_bad_axis_file(work, edit, expect):
    text = (work / "axis.toml").read_text()
    bad = work / "bad_axis.toml"
    bad.write_text(edit(text))
    msg = _bad(work, work / "cross.csv", axis=bad)
    assert expect in msg


def test_missing_axis_file(work):
    msg = _bad(work, work / "cross.csv", axis=work / "nope.toml")
    assert "nope.toml" in msg


def test_trace_too_short(work):
    lines = _lines_from(work, n=40)
    msg = _bad(work, _csv_with(work / "short.csv", "\n".join(lines)))
    assert "samples" in msg and "needs" in msg


def test_idle_runs_do_not_cover_the_cut(work):
    msg = _bad(work, work / "feed.nc", "--idle", work / "idle_short.nc")
    assert "cover" in msg and "mm" in msg


def test_bad_tare_and_method(work):
    assert "START:END" in _bad(work, work / "cross.csv", "--tare", "abc")
    assert "outside" in _bad(work, work / "cross.csv", "--tare", "10:11")
    assert "unknown method" in _bad(work, work / "cross.csv", "--method", "magic")


def test_demo_runs_and_writes_json_and_figures(tmp_path):
    res = invoke("demo", "--out", tmp_path / "demo", "--json", tmp_path / "demo.json")
    assert res.exit_code == 0, res.output
    payload = json.loads((tmp_path / "demo.json").read_text())
    rows = payload["accuracy"]
    assert len(rows) == 40 and {r["method"] for r in rows} == {"current", "rigid", "medob", "vibration"}
    pngs = {p.name for p in (tmp_path / "demo").glob("*.png")}
    assert {f"{c}.png" for c in {r["scenario"] for r in rows}} <= pngs
    assert any(name.startswith("friction_maps_") for name in pngs)
    assert all(np.isfinite(r["nrmse"]) for r in rows)


def test_friction_map_command(work):
    res = invoke("friction", work / "idle0.nc", work / "idle1.nc", "--axis", work / "axis.toml",
                 "--method", "vibration", "--plot", work / "fm.png", "--json", work / "fm.json")
    assert res.exit_code == 0, res.output
    info = json.loads((work / "fm.json").read_text())
    assert info["runs"] == 2 and info["bins"] > 100 and info["repeatability_rms_n"] >= 0
    assert info["dominant_wavelengths"] and (work / "fm.png").exists()


# ------------------------------------------------------- first try: estimate without a reference or compensation
@pytest.fixture(scope="module")
def no_reference(work) -> Path:
    """The feed cut without its reference force (a real trace has none)."""
    path = work / "feed_noref.nc"
    rec = read_recording(work / "feed.nc")
    write_recording(rec.select("x_current_ref", "x_motor_angle", "x_table_position", "spindle_speed"), path)
    return path


def test_estimate_plot_without_reference_centres_a_few_tooth_periods_and_takes_a_window(work, no_reference):
    res = invoke("estimate", no_reference, "--axis", work / "axis.toml", "--tare", "0.5:1.1", "--out",
                 work / "nr.csv", "--plot", work / "nr.png", "--json", work / "nr.json")
    assert res.exit_code == 0, res.output
    info = json.loads((work / "nr.json").read_text())
    a, b = info["plot_window_s"]
    tooth = 60 / 1000 / 2                      # feed_r6_S1000: 1000 min^-1, two flutes
    assert b - a == pytest.approx(5 * tooth) and 1.2 < a < b < 2.5    # in the cut (contact at 1.2 s)
    assert (work / "nr.png").stat().st_size > 10_000
    res = invoke("estimate", no_reference, "--axis", work / "axis.toml", "--tare", "0.5:1.1", "--out",
                 work / "nr.csv", "--plot", work / "nr.png", "--plot-window", "1.5:1.6", "--json", work / "nr.json")
    assert res.exit_code == 0, res.output
    assert json.loads((work / "nr.json").read_text())["plot_window_s"] == [1.5, 1.6]
    assert "--plot-window" in _bad(work, no_reference, "--plot", work / "x.png", "--plot-window", "7:8")
    assert "--plot-window" in _bad(work, no_reference, "--plot", work / "x.png", "--plot-window", "1.6:1.5")
    assert "give --plot" in _bad(work, no_reference, "--plot-window", "1.5:1.6")


def test_estimate_without_compensation_warns_and_says_so_in_the_json(work, no_reference):
    res = invoke("estimate", no_reference, "--axis", work / "axis.toml", "--out", work / "nc.csv",
                 "--json", work / "nc.json")
    assert res.exit_code == 0, res.output
    warning = next(line for line in res.output.splitlines() if line.startswith("warning:"))
    assert "friction" in warning and "--idle" in warning and "--tare START:END" in warning
    info = json.loads((work / "nc.json").read_text())
    assert info["compensation"] == "none" and len(info["warnings"]) == 1 and "--idle" in info["warnings"][0]
    res = invoke("estimate", no_reference, "--axis", work / "axis.toml", "--tare", "0.5:1.1", "--out",
                 work / "nc.csv", "--json", work / "nc.json")
    assert res.exit_code == 0 and "warning:" not in res.output
    assert json.loads((work / "nc.json").read_text())["warnings"] == []


def test_estimate_output_carries_the_sign_convention(work):
    res = invoke("estimate", work / "cross.csv", "--axis", work / "axis.toml", "--tare", "0.5:1.1",
                 "--out", work / "sg.csv", "--json", work / "sg.json")
    assert res.exit_code == 0, res.output
    sign = "force on the workpiece (table) along +axis"
    assert json.loads((work / "sg.json").read_text())["sign"] == sign
    assert read_csv(work / "sg.csv").meta["sign"] == sign
