"""What a first try found: cross-cutting checks of the command line as a new user meets it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.io import read_recording

runner = CliRunner()


def invoke(*args, env: dict | None = None):
    return runner.invoke(app, [str(a) for a in args], env=env)


# ------------------------------------------------ item 17: the linear-motor machine from the command line
def test_simulate_list_describes_every_scenario_of_both_machines():
    from drivesense.sim.catalog import describe_scenarios

    res = invoke("simulate", "--list", env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.output
    described = describe_scenarios()
    assert {"feed_r1.5_S1000", "idle_feed_r6_S1000", "frf_chirp", "groove_+x", "side_-x-y", "pocket_ccw",
            "ramp_-y+z", "air_moves"} <= set(described)
    assert all(line.strip() for line in described.values())
    for name in described:             # every name whole, at 80 columns and piped
        assert f" {name} " in res.output, name


def test_simulate_linear_machine_identify_and_estimate_from_the_command_line(tmp_path: Path):
    res = invoke("simulate", "pocket_ccw", "--out", tmp_path / "pocket.nc", "--ap", "1.5", "--vf", "400")
    assert res.exit_code == 0, res.output
    cut = read_recording(tmp_path / "pocket.nc")
    assert cut.fs == 250.0 and {"x_current", "y_position", "force_x", "force_y", "force_z"} <= set(cut.channels)
    assert cut.meta["a_p_m"] == pytest.approx(1.5e-3) and cut.meta["v_f_m_s"] == pytest.approx(400 / 60e3)
    res = invoke("simulate", "air_moves", "--out", tmp_path / "air")
    assert res.exit_code == 0, res.output
    moves = sorted((tmp_path / "air").glob("*.nc"))
    assert len(moves) == 9 and {p.stem for p in moves} >= {"air_x_travel", "air_y_speeds", "air_z_accel"}
    res = invoke("identify", "linear", *moves, "--out", tmp_path / "AXES.toml")
    assert res.exit_code == 0, res.output
    res = invoke("estimate", tmp_path / "pocket.nc", "--method", "model", "--axes", tmp_path / "AXES.toml",
                 "--out", tmp_path / "force.csv", "--json", tmp_path / "est.json")
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "est.json").read_text())
    assert info["score_vs_reference"]["force_x"]["nrmse"] < 0.2
    assert info["sign"] == "force on the workpiece (table) along +axis"


def test_simulate_refuses_misplaced_options():
    res = invoke("simulate", "feed_r6_S1000", "--out", "x.nc", "--rpm", "3000")
    assert res.exit_code == 2 and "--rpm" in res.output and "linear machine's processes" in res.output
    res = invoke("simulate", "air_moves", "--out", "air.nc")
    assert res.exit_code == 2 and "give --out a folder" in res.output
    res = invoke("simulate", "no_such_thing", "--out", "x.nc")
    assert res.exit_code == 2 and "unknown scenario" in res.output and "air_moves" in res.output
