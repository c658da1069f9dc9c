"""``bench nc --real DIR``: identify on one cut and its air cut of a folder, score the other cuts beside the regression."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drivesense.bench.nc_real import is_air_cut, real_bench_files, run_real_nc_bench
from drivesense.cli import app
from drivesense.errors import ConfigError
from cli_checks import one_line, one_line_error

runner = CliRunner()

KIT = "kit-dmc60h"
AXES = ("x", "y", "z")
#: File name -> (program, air cut, seed): a session of exports as a controller writes them.
SESSION = {"M_pocket_1.csv": ("pocket", False, 1), "M_pocket_Aircut_0.csv": ("pocket", True, 1),
           "M_contour_1.csv": ("contour", False, 2), "M_slots_1.csv": ("slots", False, 3)}


def invoke(*args, env: dict | None = None):
    return runner.invoke(app, [str(a) for a in args], env=env)




@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """The session's exports through the shipped KIT map (and an extra air cut of another program)."""
    from drivesense.io import resolve_column_map, write_csv
    from drivesense.sim import simulate_nc_program

    out = tmp_path_factory.mktemp("kit_session")
    cmap = resolve_column_map(KIT)
    for name, (program, air, seed) in SESSION.items():
        write_csv(simulate_nc_program(program, rate=50.0, air=air, seed=seed), out / name, column_map=cmap)
    # an air cut of another program: the pocket's air cut shares the longer name prefix with the calibration cut
    shutil.copy(out / "M_pocket_Aircut_0.csv", out / "Z_other_Aircut_0.csv")
    (out / "notes.txt").write_text("not a trace", encoding="utf-8")
    return out


@pytest.fixture(scope="module")
def result(folder) -> dict:
    return run_real_nc_bench(folder, columns=KIT, calibration="M_pocket_1.csv", vertical="z")


def _copy(folder: Path, dest: Path, *names: str) -> Path:
    dest.mkdir()
    for name in names:
        shutil.copy(folder / name, dest / name)
    return dest


# ------------------------------------------------------------------ air cuts by name
@pytest.mark.parametrize("name", ["X_Aircut_0.csv", "x_air_cut.csv", "cut_air.csv", "M_AIR-CUT_2.nc", "air.csv",
                                  "run.air.csv", Path("some/dir/M_pocket_Aircut_0.csv")])
def test_is_air_cut_true(name):
    assert is_air_cut(name)


@pytest.mark.parametrize("name", ["repair.csv", "fairing_1.csv", "hair_2.csv", "M_pocket_1.csv", "airbus_cut.csv",
                                  Path("air_cuts/M_pocket_1.csv")])
def test_is_air_cut_false(name):
    assert not is_air_cut(name)


def test_real_bench_files_picks_the_air_cut_sharing_the_longest_prefix(folder):
    files = real_bench_files(folder, calibration="M_pocket_1.csv")
    assert files["calibration"].name == "M_pocket_1.csv"
    assert files["air"].name == "M_pocket_Aircut_0.csv"
    assert [p.name for p in files["held_out"]] == ["M_contour_1.csv", "M_slots_1.csv"]
    default = real_bench_files(folder)                  # default calibration: the first cut by name
    assert default["calibration"].name == "M_contour_1.csv"
    explicit = real_bench_files(folder, calibration="M_pocket_1.csv", air="Z_other_Aircut_0.csv")
    assert explicit["air"].name == "Z_other_Aircut_0.csv"


# ------------------------------------------------------------------ the bench
def test_result_is_strict_json_and_names_the_files(result, folder):
    text = json.dumps(result, allow_nan=False)
    assert json.loads(text) == result
    res = result["nc_real"]
    assert set(result) == {"nc_real"}
    assert res["folder"] == str(folder) and res["columns"] == KIT and res["vertical"] == "z"
    assert res["calibration"] == "M_pocket_1.csv" and res["air"] == "M_pocket_Aircut_0.csv"
    assert res["rate_hz"] == pytest.approx(50.0)
    assert res["carries"] == {}
    assert isinstance(res["baseline"], str) and res["baseline"]


def test_the_identification_is_reported(result):
    ident = result["nc_real"]["identification"]
    assert ident["seconds"] > 0
    assert set(ident["axes"]) == set(AXES)
    for a in AXES:
        assert {"K_m", "terms", "active_bounds", "dropped", "held_out"} <= set(ident["axes"][a])
        assert f"inertia_{a}" in ident["axes"][a]["terms"]
    assert set(ident["regression_check"]) == set(AXES)
    assert set(ident["choice"]) == set(AXES) and all(v in ("model", "sliding", "regression") for v in ident["choice"].values())


def test_every_other_cut_is_scored_per_axis_with_ratios(result):
    res = result["nc_real"]
    rows = {row["file"]: row for row in res["files"]}
    assert set(rows) == {"M_contour_1.csv", "M_slots_1.csv"}          # not the calibration cut, no air cut
    for name, row in rows.items():
        assert row["samples"] > 100
        assert set(row["nrmse"]) == {"regression", "model", "auto"}
        for method, per_axis in row["nrmse"].items():
            assert set(per_axis) == set(AXES)
            assert all(math.isfinite(v) and v > 0 for v in per_axis.values()), (name, method)
        assert set(row["ratio"]) == {"model", "auto"}
        for method in ("model", "auto"):
            for a in AXES:
                assert row["ratio"][method][a] == pytest.approx(row["nrmse"][method][a] / row["nrmse"]["regression"][a])
    for method in ("model", "auto"):
        summary = res["summary"][method]
        ratios = [row["ratio"][method][a] for row in rows.values() for a in AXES]
        assert summary["mean_ratio"] == pytest.approx(sum(ratios) / len(ratios))
        assert summary["worst_ratio"] == pytest.approx(max(ratios))
        assert set(summary["per_axis_mean_ratio"]) == set(AXES)


def test_targets_are_met_on_the_simulator(result):
    res = result["nc_real"]
    targets = res["targets"]
    assert {"best_worst_axis_ratio", "best_mean_ratio", "masses_physical", "identify_seconds"} <= set(targets)
    for name, target in targets.items():
        assert {"value", "target", "met"} <= set(target), name
    assert targets["masses_physical"]["met"] is True
    assert set(targets["masses_physical"]["value"]) == set(AXES)
    assert all(m > 0 for m in targets["masses_physical"]["value"].values())
    best_worst = min(res["summary"]["model"]["worst_ratio"], res["summary"]["auto"]["worst_ratio"])
    assert targets["best_worst_axis_ratio"]["value"] == pytest.approx(best_worst)
    assert targets["best_worst_axis_ratio"]["met"] == (best_worst <= 1.0)
    best_mean = min(res["summary"]["model"]["mean_ratio"], res["summary"]["auto"]["mean_ratio"])
    assert targets["best_mean_ratio"]["value"] == pytest.approx(best_mean)
    assert targets["best_mean_ratio"]["met"] == (best_mean <= 0.8)
    assert targets["identify_seconds"]["value"] == pytest.approx(res["identification"]["seconds"])
    assert targets["identify_seconds"]["met"] == (targets["identify_seconds"]["value"] < 10.0)
    # on the simulator the controller-rate model beats the 13-term regression on every held-out file and axis
    assert targets["best_worst_axis_ratio"]["met"] and targets["best_mean_ratio"]["met"]


# ------------------------------------------------------------------ errors
def test_a_folder_without_an_air_cut_is_a_one_line_config_error(folder, tmp_path):
    dest = _copy(folder, tmp_path / "no_air", "M_pocket_1.csv", "M_contour_1.csv")
    with pytest.raises(ConfigError) as exc:
        run_real_nc_bench(dest, columns=KIT)
    one_line(exc, "--real", "air cut", "found 2 cut(s) and 0 air cut(s)")


def test_a_folder_without_a_cut_is_a_one_line_config_error(folder, tmp_path):
    dest = _copy(folder, tmp_path / "only_air", "M_pocket_Aircut_0.csv")
    with pytest.raises(ConfigError) as exc:
        real_bench_files(dest)
    one_line(exc, "found 0 cut(s) and 1 air cut(s)")


def test_not_a_folder_is_a_one_line_config_error(tmp_path):
    with pytest.raises(ConfigError) as exc:
        run_real_nc_bench(tmp_path / "missing", columns=KIT)
    one_line(exc, "--real", "not a folder")


def test_calibration_naming_a_missing_file_is_a_one_line_config_error(folder):
    with pytest.raises(ConfigError) as exc:
        run_real_nc_bench(folder, columns=KIT, calibration="M_nothing_1.csv")
    one_line(exc, "--calibration M_nothing_1.csv", "no such file", "M_pocket_1.csv")


def test_air_naming_a_missing_file_is_a_one_line_config_error(folder):
    with pytest.raises(ConfigError) as exc:
        real_bench_files(folder, air="M_nothing_Aircut_0.csv")
    one_line(exc, "--air M_nothing_Aircut_0.csv", "no such file")


def test_calibration_naming_an_air_cut_is_a_one_line_config_error(folder):
    with pytest.raises(ConfigError) as exc:
        run_real_nc_bench(folder, columns=KIT, calibration="M_pocket_Aircut_0.csv")
    one_line(exc, "--calibration M_pocket_Aircut_0.csv", "air cut")


def test_a_folder_with_only_the_calibration_cut_is_a_one_line_config_error(folder, tmp_path):
    dest = _copy(folder, tmp_path / "one_cut", "M_pocket_1.csv", "M_pocket_Aircut_0.csv")
    with pytest.raises(ConfigError) as exc:
        run_real_nc_bench(dest, columns=KIT, vertical="z")
    one_line(exc, "no held-out cut")


# ------------------------------------------------------------------ the command line
def test_bench_nc_real_from_the_command_line(folder, tmp_path):
    res = invoke("bench", "nc", "--real", folder, "--columns", KIT, "--calibration", "M_pocket_1.csv",
                 "--vertical", "z", "--json", tmp_path / "b.json", env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "M_contour_1.csv" in res.output and "M_slots_1.csv" in res.output
    text = (tmp_path / "b.json").read_text()
    payload = json.loads(text)
    json.dumps(payload, allow_nan=False)
    assert "machine" in payload and "nc_real" in payload
    res_ = payload["nc_real"]
    assert res_["calibration"] == "M_pocket_1.csv" and res_["air"] == "M_pocket_Aircut_0.csv"
    assert {row["file"] for row in res_["files"]} == {"M_contour_1.csv", "M_slots_1.csv"}
    assert res_["targets"]["masses_physical"]["met"] is True


def test_bench_nc_real_with_carries_from_the_command_line(folder, tmp_path):
    res = invoke("bench", "nc", "--real", folder, "--columns", KIT, "--calibration", "M_pocket_1.csv",
                 "--vertical", "z", "--carries", "y=x", "--json", tmp_path / "b.json")
    assert res.exit_code == 0, res.output
    payload = json.loads((tmp_path / "b.json").read_text())
    assert payload["nc_real"]["carries"] == {"y": ["x"]}


def test_real_options_without_real_are_refused():
    one_line_error(invoke("bench", "nc", "--columns", KIT), "--columns", "--real")
    one_line_error(invoke("bench", "nc", "--vertical", "z", "--calibration", "C.csv"), "--calibration", "--vertical")


def test_real_applies_to_bench_nc_only(folder):
    one_line_error(invoke("bench", "speed", "--real", folder), "--real", "speed")


def test_bench_nc_real_errors_from_the_command_line(folder, tmp_path):
    dest = _copy(folder, tmp_path / "no_air", "M_pocket_1.csv", "M_contour_1.csv")
    one_line_error(invoke("bench", "nc", "--real", dest, "--columns", KIT), "air cut")
    one_line_error(invoke("bench", "nc", "--real", folder, "--columns", KIT, "--calibration", "M_pocket_Aircut_0.csv"),
                   "--calibration", "air cut")


def test_air_must_be_named_as_an_air_cut(folder):
    with pytest.raises(ConfigError) as exc:
        real_bench_files(folder, calibration="M_pocket_1.csv", air="M_contour_1.csv")
    one_line(exc, "not named as an air cut")
