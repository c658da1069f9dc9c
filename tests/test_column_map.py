"""Column maps (``--columns``): a controller's CSV export read as it comes, and written as that export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, UnitError
from drivesense.io import ColumnMap, read_column_map, read_csv, read_trace, resolve_column_map, shipped_maps, write_csv
from drivesense.io.column_map import ColumnSpec
from cli_checks import one_line, one_line_error

runner = CliRunner()

KIT = "kit-dmc60h"
#: The export's column of each channel in the shipped KIT map.
KIT_SOURCES = {"time": "time", "x_position": "pos_x", "y_position": "pos_y", "z_position": "pos_z",
               "x_velocity": "v_x", "y_velocity": "v_y", "z_velocity": "v_z",
               "x_acceleration": "a_x", "y_acceleration": "a_y", "z_acceleration": "a_z",
               "x_current": "curr_x", "y_current": "curr_y", "z_current": "curr_z",
               "spindle_current": "curr_sp", "spindle_speed": "v_sp",
               "force_x": "f_x", "force_y": "f_y", "force_z": "f_z"}
SI = {"position": "m", "velocity": "m/s", "acceleration": "m/s^2", "current": "A", "spindle_speed": "rad/s",
      "force": "N"}


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])




def write_map(folder: Path, text: str, name: str = "map.toml") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


# ------------------------------------------------------------------ fixtures: one cut and its air cut
@pytest.fixture(scope="module")
def kit() -> ColumnMap:
    return resolve_column_map(KIT)


@pytest.fixture(scope="module")
def cut():
    from drivesense.sim import simulate_nc_program

    return simulate_nc_program("pocket", rate=50.0, seed=3)


@pytest.fixture(scope="module")
def air_cut():
    from drivesense.sim import simulate_nc_program

    return simulate_nc_program("pocket", rate=50.0, air=True, seed=3)


@pytest.fixture(scope="module")
def exports(tmp_path_factory, cut, air_cut, kit) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("kit_exports")
    return {"cut": write_csv(cut, folder / "M_pocket_1.csv", column_map=kit),
            "air": write_csv(air_cut, folder / "M_pocket_Aircut_0.csv", column_map=kit)}


def _header(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines()[0].split(",")


# ------------------------------------------------------------------ the shipped map
def test_shipped_maps_hold_the_kit_map():
    maps = shipped_maps()
    assert KIT in maps and maps[KIT].is_file() and maps[KIT].suffix == ".toml"
    cmap = resolve_column_map(KIT)
    assert isinstance(cmap, ColumnMap) and cmap.name == f"{KIT}.toml"
    assert cmap.resample_hz == 50.0
    assert {c.source: c.channel for c in cmap.columns} == {v: k for k, v in KIT_SOURCES.items()}
    by_source = {c.source: c for c in cmap.columns}
    assert by_source["pos_x"].unit == "mm" and by_source["v_sp"].unit == "deg/s"
    assert all(by_source[s].optional for s in ("curr_sp", "v_sp", "f_x", "f_y", "f_z"))
    assert not any(by_source[s].optional for s in ("time", "pos_x", "curr_x", "a_z"))
    # a ColumnMap passes through, a path to a map file reads it
    assert resolve_column_map(cmap) is cmap
    assert resolve_column_map(maps[KIT]) == cmap


def test_column_spec_factor_is_scale_times_sign():
    assert ColumnSpec("c", "x_current", "A", scale=2.5, sign=-1).factor == -2.5
    assert ColumnSpec("c", "x_current", "A").factor == 1.0


# ------------------------------------------------------------------ round trip through the export format
@pytest.mark.parametrize("which", ["cut", "air"])
def test_export_reads_back_to_the_same_channels_in_si(which, cut, air_cut, exports, kit):
    rec = cut if which == "cut" else air_cut
    back = read_csv(exports[which], column_map=kit)
    assert set(back.channels) == set(rec.channels)
    assert back.n_samples == rec.n_samples
    assert back.fs == pytest.approx(rec.fs) and back.t0 == pytest.approx(rec.t0, abs=1e-12)
    for name in rec.channels:
        quantity = next(q for q in SI if q in name)
        assert back.units(name) == SI[quantity], name
        ref = rec[name]
        np.testing.assert_allclose(back[name], ref, rtol=1e-9, atol=1e-12 * max(1.0, float(np.max(np.abs(ref)))),
                                   err_msg=name)
    if which == "air":
        assert not any(c.startswith("force_") for c in back.channels)   # optional columns, absent
    provenance = " ".join(back.meta["provenance"])
    assert f"column map {KIT}.toml" in provenance and "mm->m" in provenance and "deg/s->rad/s" in provenance


@pytest.mark.parametrize("which", ["cut", "air"])
def test_export_header_holds_the_exports_names_and_loads_with_pandas(which, cut, air_cut, exports, kit):
    pd = pytest.importorskip("pandas")
    rec = cut if which == "cut" else air_cut
    expected = [c.source for c in kit.columns if c.channel == "time" or c.channel in rec.channels]
    header = _header(exports[which])
    assert header == expected
    assert {"pos_x", "curr_x", "v_sp", "curr_sp"} <= set(header) and "[" not in ",".join(header)
    assert ("f_x" in header) == (which == "cut")
    df = pd.read_csv(exports[which])
    assert list(df.columns) == expected and len(df) == rec.n_samples
    # the file holds the export's units: mm, mm/s, deg/s, A
    np.testing.assert_allclose(df["pos_x"].to_numpy(), rec["x_position"] * 1e3, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(df["v_y"].to_numpy(), rec["y_velocity"] * 1e3, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(df["v_sp"].to_numpy(), np.degrees(rec["spindle_speed"]), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(df["curr_z"].to_numpy(), rec["z_current"], rtol=0, atol=0)
    np.testing.assert_allclose(df["time"].to_numpy(), rec.time, rtol=1e-12, atol=1e-12)


def test_write_csv_refuses_a_map_with_units_or_channels(cut, kit, tmp_path):
    with pytest.raises(ConfigError) as exc:
        write_csv(cut, tmp_path / "x.csv", column_map=kit, channels=["x_current"])
    one_line(exc, "column map")
    assert not (tmp_path / "x.csv").exists()


def test_scale_and_sign_round_trip_through_write_and_read(cut, tmp_path):
    cmap = read_column_map(write_map(tmp_path, """
[columns]
t = { channel = "time", unit = "ms" }
I1 = { channel = "x_current", unit = "mA", scale = 2.0, sign = -1 }
F1 = { channel = "force_x", unit = "kN" }
"""))
    path = write_csv(cut, tmp_path / "export.csv", column_map=cmap)
    assert _header(path) == ["t", "I1", "F1"]
    raw = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_allclose(raw[:, 0], cut.time * 1e3, rtol=1e-12)
    np.testing.assert_allclose(raw[:, 1], cut["x_current"] * 1e3 / -2.0, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(raw[:, 2], cut["force_x"] / 1e3, rtol=1e-12, atol=1e-15)
    back = read_csv(path, column_map=cmap)
    assert set(back.channels) == {"x_current", "force_x"}
    np.testing.assert_allclose(back["x_current"], cut["x_current"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(back["force_x"], cut["force_x"], rtol=1e-9, atol=1e-9)


def test_write_csv_refuses_a_map_naming_none_of_the_recordings_channels(cut, tmp_path):
    cmap = ColumnMap.from_dict({"columns": {"t": {"channel": "time", "unit": "s"},
                                            "m": {"channel": "x_motor_angle", "unit": "rad"}}}, name="other.toml")
    with pytest.raises(ConfigError) as exc:
        write_csv(cut, tmp_path / "x.csv", column_map=cmap)
    one_line(exc, "other.toml", "none of the map's channels")


# ------------------------------------------------------------------ reading: scale, sign, left-out columns
SCALED_MAP = """
[map]
description = "a test export"

[columns]
time = { channel = "time", unit = "s" }
curr_x = { channel = "x_current", unit = "A", scale = 2.0, sign = -1, note = "amplifier gain" }
pos_x = { channel = "x_position", unit = "mm" }
"""


def test_scale_and_sign_are_applied_and_unmapped_columns_left_out(tmp_path):
    cmap = read_column_map(write_map(tmp_path, SCALED_MAP))
    assert cmap.name == "map.toml" and cmap.description == "a test export" and cmap.resample_hz is None
    (tmp_path / "trace.csv").write_text(
        "time,curr_x,status,pos_x,,temp_x\n"
        "0.00,1.5,OK,10,7,20.5\n"
        "0.02,-0.5,OK,11,7,20.6\n"
        "0.04,3.0,WARN,12,7,20.7\n"
        "0.06,0.0,OK,13,7,20.8\n", encoding="utf-8")
    rec = read_csv(tmp_path / "trace.csv", column_map=cmap)
    assert set(rec.channels) == {"x_current", "x_position"}
    np.testing.assert_allclose(rec["x_current"], -2.0 * np.array([1.5, -0.5, 3.0, 0.0]))
    np.testing.assert_allclose(rec["x_position"], [0.010, 0.011, 0.012, 0.013])
    assert rec.fs == pytest.approx(50.0) and rec.n_samples == 4
    provenance = " ".join(rec.meta["provenance"])
    assert "left out status, (column 5, no name), temp_x" in provenance   # the text column and the empty cell
    assert "curr_x: scale 2, sign -1 (amplifier gain)" in provenance
    assert "column map map.toml (a test export)" in provenance


def test_header_cells_with_a_unit_match_the_map_by_name(tmp_path):
    cmap = read_column_map(write_map(tmp_path, SCALED_MAP))
    (tmp_path / "trace.csv").write_text("time [s],curr_x [A],pos_x [mm]\n0,1,10\n0.02,2,11\n0.04,3,12\n",
                                        encoding="utf-8")
    rec = read_csv(tmp_path / "trace.csv", column_map=cmap)
    np.testing.assert_allclose(rec["x_current"], [-2.0, -4.0, -6.0])
    np.testing.assert_allclose(rec["x_position"], [0.010, 0.011, 0.012])
    assert cmap.lookup(" curr_x [A] ").channel == "x_current" and cmap.lookup("other") is None


def test_an_optional_column_may_be_missing_a_required_one_may_not(tmp_path):
    (tmp_path / "trace.csv").write_text("time,curr_x\n0,1\n0.02,2\n0.04,3\n", encoding="utf-8")
    optional = read_column_map(write_map(tmp_path, """
[columns]
time = { channel = "time", unit = "s" }
curr_x = { channel = "x_current", unit = "A" }
curr_y = { channel = "y_current", unit = "A", optional = true }
""", "optional.toml"))
    rec = read_csv(tmp_path / "trace.csv", column_map=optional)
    assert list(rec.channels) == ["x_current"]
    required = read_column_map(write_map(tmp_path, """
[columns]
time = { channel = "time", unit = "s" }
curr_x = { channel = "x_current", unit = "A" }
curr_y = { channel = "y_current", unit = "A" }
""", "required.toml"))
    with pytest.raises(ConfigError) as exc:
        read_csv(tmp_path / "trace.csv", column_map=required)
    one_line(exc, "'curr_y'", "y_current", "trace.csv", "required.toml", "optional = true")


def test_a_shipped_map_column_missing_from_an_export_names_column_and_channel(exports, kit, tmp_path):
    lines = exports["cut"].read_text(encoding="utf-8").splitlines()
    header = lines[0].split(",")
    drop = header.index("curr_y")
    keep = [i for i in range(len(header)) if i != drop]
    text = "\n".join(",".join(row.split(",")[i] for i in keep) for row in lines) + "\n"
    (tmp_path / "cut.csv").write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        read_csv(tmp_path / "cut.csv", column_map=kit)
    one_line(exc, "'curr_y'", "y_current", "cut.csv")
    with pytest.raises(ConfigError) as exc:      # the same through read_trace and a shipped name
        read_trace(tmp_path / "cut.csv", columns=KIT)
    one_line(exc, "'curr_y'", "y_current")


# ------------------------------------------------------------------ bad maps: one-line ConfigErrors
_TIME = 'time = { channel = "time", unit = "s" }\n'
BAD_MAPS = {
    "unknown entry key": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", gain = 2 }\n',
                          ["column 'c'", "unknown key(s) gain"]),
    "unknown [map] key": ('[map]\nrate = 50\n[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A" }\n',
                          ["[map]", "unknown key(s) rate"]),
    "unknown section": ('[columns]\n' + _TIME + '[extra]\nx = 1\n', ["unknown section(s) extra"]),
    "sign 2": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", sign = 2 }\n',
               ["column 'c'", "sign must be 1 or -1", "2"]),
    "sign true": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", sign = true }\n',
                  ["column 'c'", "sign must be 1 or -1"]),
    "scale 0": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", scale = 0 }\n',
                ["column 'c'", "scale must be a number > 0", "got 0"]),
    "scale negative": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", scale = -1.5 }\n',
                       ["column 'c'", "scale must be a number > 0", "-1.5"]),
    "scale text": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", scale = "2" }\n',
                   ["column 'c'", "scale must be a number > 0"]),
    "unit misfit": ('[columns]\n' + _TIME + 'p = { channel = "x_position", unit = "A" }\n',
                    ["column 'p'", "x_position", "'A'", "length"]),
    "unknown unit": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "furlong" }\n',
                     ["column 'c'", "furlong"]),
    "two columns one channel": ('[columns]\n' + _TIME + 'a = { channel = "x_current", unit = "A" }\n'
                                'b = { channel = "x_current", unit = "mA" }\n', ["'a'", "'b'", "x_current"]),
    "no channel": ('[columns]\n' + _TIME + 'c = { unit = "A" }\n', ["column 'c'", "'channel'"]),
    "entry not a table": ('[columns]\n' + _TIME + 'c = "x_current"\n', ["column 'c'", "table"]),
    "optional not bool": ('[columns]\n' + _TIME + 'c = { channel = "x_current", unit = "A", optional = "yes" }\n',
                          ["column 'c'", "optional must be true or false"]),
    "scaled time": ('[columns]\ntime = { channel = "time", unit = "s", sign = -1 }\n', ["time", "scale or sign"]),
    "resample 0": ('[map]\nresample_hz = 0\n[columns]\n' + _TIME, ["resample_hz", "> 0"]),
    "no columns": ('[map]\ndescription = "empty"\n', ["[columns]"]),
    "not toml": ('this is [ not toml', ["not valid TOML"]),
}


@pytest.mark.parametrize("case", list(BAD_MAPS))
def test_a_bad_map_is_a_one_line_config_error(case, tmp_path):
    text, needles = BAD_MAPS[case]
    path = write_map(tmp_path, text, "bad.toml")
    with pytest.raises(ConfigError) as exc:
        read_column_map(path)
    one_line(exc, "bad.toml", *needles)
    with pytest.raises(ConfigError) as exc:      # the same through --columns PATH
        resolve_column_map(str(path))
    one_line(exc, "bad.toml", *needles)


def test_an_unknown_shipped_map_name_is_a_one_line_config_error():
    with pytest.raises(ConfigError) as exc:
        resolve_column_map("nope")
    one_line(exc, "nope", "not a shipped map", KIT)


def test_columns_for_a_file_that_is_not_a_csv_is_a_one_line_config_error(tmp_path, cut):
    from drivesense.io import save_netcdf

    path = save_netcdf(cut, tmp_path / "cut.nc")
    with pytest.raises(ConfigError) as exc:
        read_trace(path, columns=KIT)
    one_line(exc, "cut.nc", "--columns", "not a CSV")
    assert set(read_trace(path).channels) == set(cut.channels)     # without --columns it reads


def test_read_trace_with_a_shipped_map_name(exports, cut):
    rec = read_trace(exports["cut"], columns=KIT)
    assert set(rec.channels) == set(cut.channels)
    np.testing.assert_allclose(rec["z_position"], cut["z_position"], rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------ the command line
@pytest.fixture(scope="module")
def cli_exports(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("cli_exports")
    res = invoke("simulate", "vmc_pocket", "--out", folder / "P.csv", "--columns", KIT)
    assert res.exit_code == 0, res.output
    res = invoke("simulate", "vmc_air_pocket", "--out", folder / "A.csv", "--columns", KIT)
    assert res.exit_code == 0, res.output
    return folder


def test_simulate_writes_the_export(cli_exports):
    assert _header(cli_exports / "P.csv")[:4] == ["time", "pos_x", "pos_y", "pos_z"]
    assert "f_x" in _header(cli_exports / "P.csv") and "f_x" not in _header(cli_exports / "A.csv")
    rec = read_trace(cli_exports / "P.csv", columns=KIT)
    assert rec.fs == pytest.approx(50.0) and {"x_current", "force_z", "spindle_speed"} <= set(rec.channels)


def test_identify_and_estimate_read_the_export_with_columns(cli_exports, tmp_path):
    res = invoke("identify", "nc", cli_exports / "P.csv", "--air", cli_exports / "A.csv", "--columns", KIT,
                 "--vertical", "z", "--carries", "y=x", "--out", tmp_path / "AXES.toml", "--json", tmp_path / "id.json")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "AXES.toml").is_file()
    ident = json.loads((tmp_path / "id.json").read_text())
    assert set(ident["regression_check"]) == {"x", "y", "z"}
    for a, check in ident["regression_check"].items():
        assert check["choice"] in ("model", "sliding", "regression"), a
        assert check["model_nrmse"] > 0 and check["regression_nrmse"] > 0
    assert ident["kinematics"] == {"vertical": "z", "carries": {"y": ["x"]}}

    res = invoke("estimate", cli_exports / "P.csv", "--columns", KIT, "--axes", tmp_path / "AXES.toml",
                 "--method", "model", "--per-axis", "auto", "--out", tmp_path / "f.csv", "--json", tmp_path / "e.json")
    assert res.exit_code == 0, res.output
    est = json.loads((tmp_path / "e.json").read_text())
    assert set(est["per_axis"]) == {"x", "y", "z"}
    assert all(v in ("model", "sliding", "regression") for v in est["per_axis"].values())
    assert est["per_axis"] == {a: c["choice"] for a, c in ident["regression_check"].items()}
    assert est["samples"] == read_trace(cli_exports / "P.csv", columns=KIT).n_samples
    for a in "xyz":      # the simulator's true force is in the export: scored, and well within 50 %
        assert est["score_vs_reference"][f"force_{a}"]["nrmse"] < 0.5


def test_the_export_without_its_map_is_refused_for_its_unit_less_header(cli_exports):
    from drivesense.errors import UnitError

    with pytest.raises(UnitError) as exc:
        read_trace(cli_exports / "P.csv")
    one_line(exc, "P.csv", "have no unit", "'pos_x'")


def test_simulate_columns_to_a_nc_file_is_a_one_line_error(tmp_path):
    one_line_error(invoke("simulate", "vmc_pocket", "--out", tmp_path / "P.nc", "--columns", KIT),
                   "--columns", "P.nc")
    assert not (tmp_path / "P.nc").exists()


def test_columns_naming_no_map_is_a_one_line_error(cli_exports, tmp_path):
    one_line_error(invoke("identify", "nc", cli_exports / "P.csv", "--air", cli_exports / "A.csv", "--columns",
                          "nope", "--out", tmp_path / "AXES.toml"), "nope", "not a shipped map")


def test_a_header_unit_that_disagrees_with_the_map_is_refused(tmp_path):
    path = tmp_path / "units.csv"
    path.write_text("time [s],pos_x [m],curr_x [A]\n0,1,0.1\n0.02,1,0.1\n0.04,1,0.1\n")
    spec = tmp_path / "m.toml"
    spec.write_text('[columns]\ntime = { channel = "time", unit = "s" }\npos_x = { channel = "x_position", unit = "mm" }\n'
                    'curr_x = { channel = "x_current", unit = "A" }\n')
    with pytest.raises(UnitError, match=r"the header says \[m\], the column map m.toml says mm") as exc:
        read_csv(path, column_map=read_column_map(spec))
    assert "\n" not in str(exc.value)
