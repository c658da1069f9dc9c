"""What a first try found: cross-cutting checks of the command line as a new user meets it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.io import read_recording
from drivesense.recording import Recording

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


# ------------------------------------------------ item 14: key columns whole at 80 columns, units not eaten
@pytest.fixture
def narrow(monkeypatch):
    """The CLI's console at 80 columns (CliRunner output is piped, not a terminal)."""
    from drivesense.cli.common import console

    monkeypatch.setattr(console, "width", 80)


def _table_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if "…" in line]


def test_mtconnect_probe_keeps_channels_whole(narrow):
    data = Path(__file__).parent / "data" / "mtconnect" / "devices.xml"
    res = invoke("mtconnect", "probe", data)
    assert res.exit_code == 0, res.output
    assert not _table_lines(res.output)
    for channel in ("x_table_position", "x_position_commanded", "spindle_accelerometer_acceleration"):
        assert f" {channel} " in res.output, channel


def test_wear_tables_keep_state_and_experiment_whole(narrow, tmp_path):
    res = invoke("wear", "simulate", "--list")
    assert res.exit_code == 0 and not _table_lines(res.output), res.output
    assert invoke("wear", "simulate", "C", "--out", tmp_path / "s.csv").exit_code == 0
    res = invoke("wear", "track", tmp_path / "s.csv")
    assert res.exit_code == 0, res.output
    assert not _table_lines(res.output)
    assert " progressing " in res.output and " near end of life " in res.output


def test_archive_search_keeps_the_tool_whole(narrow, tmp_path, monkeypatch):
    import numpy as np

    from drivesense.io import write_recording
    from drivesense.recording import Recording

    monkeypatch.setenv("DRIVESENSE_ARCHIVE", str(tmp_path / "a.sqlite"))
    tool = "solid carbide end mill D10 Z4 TiAlN, 38/35 degree variable helix"
    rec = Recording.from_arrays({"x_current_ref": np.zeros(50)}, fs=1000.0,
                                meta={"name": "cut 7", "tool": tool, "machine": "Haas VF-2 [2016]"})
    write_recording(rec, tmp_path / "r.nc")
    assert invoke("archive", "add", tmp_path / "r.nc").exit_code == 0
    res = invoke("archive", "search", "--tool", "carbide")
    assert res.exit_code == 0, res.output
    assert "…" not in res.output and "Haas VF-2 [2016]" in res.output
    assert all(len(line) <= 80 for line in res.output.splitlines())
    cells = " ".join(line.split("│")[5].strip() for line in res.output.splitlines() if line.count("│") == 7)
    assert cells == tool          # the tool column, read down: the whole description


def test_accuracy_table_keeps_scenario_names_whole():
    from io import StringIO

    from rich.console import Console

    from drivesense.cli.common import accuracy_table

    rows = [{"scenario": f"side_-x+y_ap{k}_ae10_vf800_n6000_seed{k}", "direction": "feed", "peak_to_peak_n": 120.0,
             "method": m, "nrmse": 0.05} for k in range(2) for m in ("current", "rigid", "medob", "vibration")]
    out = StringIO()
    Console(file=out, width=80).print(accuracy_table(rows, "accuracy"))
    assert "side_-x+y_ap0_ae10_vf800_n6000_seed0" in out.getvalue() and "…" not in out.getvalue()


def test_units_in_brackets_survive_rich_markup(tmp_path):
    res = invoke("sensor", "simulate", "--out-dir", tmp_path / "s", "--levels", "1.3")
    assert res.exit_code == 0, res.output
    assert "accel_ref [m/s^2]" in " ".join(res.output.split())


# ------------------------------------------------ item 18: drivesense --version
def test_version_prints_the_package_version():
    from importlib.metadata import version

    import drivesense

    res = invoke("--version")
    assert res.exit_code == 0 and res.output == f"drivesense {version('drivesense')}\n"
    assert res.output == "drivesense 0.1.0\n" and drivesense.__version__ == version("drivesense")


# ------------------------------------------- items 2 and 10: --assume-si, --fs and --resample where traces are read
TRACE_READERS = ("estimate", "friction", "train", "plot", "identify frf", "identify linear", "identify nc", "sensor calibrate",
                 "sensor apply", "xml export", "archive add")


def _commands():
    """Every leaf command of the app: {'identify frf': click command, ...}."""
    from typer.main import get_command

    def walk(cmd, path):
        if hasattr(cmd, "commands"):
            for name, sub in cmd.commands.items():
                yield from walk(sub, [*path, name])
        else:
            yield " ".join(path), cmd

    return dict(walk(get_command(app), []))


def test_every_command_that_reads_traces_has_the_trace_options():
    commands = _commands()
    for name in TRACE_READERS:
        opts = {o for p in commands[name].params for o in p.opts}
        assert {"--assume-si", "--fs", "--resample"} <= opts, name


def test_header_without_units_is_refused_unless_assume_si(tmp_path):
    """um and rev read as m and rad gave 3e10 N and exit 0."""
    trace = tmp_path / "t.csv"
    trace.write_text("time,current_ref,motor_angle,table_position\n" + "".join(
        f"{k * 1e-3!r},{0.1 * (k % 5)},{k * 0.01},{k * 2.0}\n" for k in range(64)))
    res = invoke("plot", trace, "-c", "table_position", "--out", tmp_path / "p.png")
    assert res.exit_code == 2 and "Traceback" not in res.output
    msg = " ".join(res.output.split())
    assert "'time', 'current_ref', 'motor_angle', 'table_position' have no unit" in msg and "--assume-si" in msg
    assert "table_position [mm]" in msg and not (tmp_path / "p.png").exists()
    res = invoke("plot", trace, "-c", "table_position", "--out", tmp_path / "p.png", "--assume-si")
    assert res.exit_code == 0, res.output
    res = invoke("xml", "export", trace, "--out", tmp_path / "t.xml", "--assume-si")
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "t.xml")["x_table_position"][1] == 2.0       # metres, as the user said


def test_jittery_time_and_no_time_column_name_the_options_that_fix_them(tmp_path):
    import numpy as np

    t = np.arange(400) * 1e-3 + np.random.default_rng(0).uniform(-3e-4, 3e-4, 400) * (np.arange(400) % 399 > 0)
    jitter = tmp_path / "jitter.csv"
    jitter.write_text("time [s],force_x [N]\n" + "".join(f"{a!r},{float(np.sin(40 * a))!r}\n" for a in t.tolist()))
    res = invoke("xml", "export", jitter, "--out", tmp_path / "j.xml")
    assert res.exit_code == 2 and "--resample HZ" in " ".join(res.output.split()) and "rel_tol" not in res.output
    res = invoke("xml", "export", jitter, "--out", tmp_path / "j.xml", "--resample", "1000")
    assert res.exit_code == 0, res.output
    rec = read_recording(tmp_path / "j.xml")
    assert rec.fs == 1000.0 and any("--resample" in step for step in rec.meta["provenance"])
    bare = tmp_path / "bare.csv"
    bare.write_text("force_x [N]\n" + "".join(f"{k % 7}\n" for k in range(64)))
    res = invoke("plot", bare, "-c", "force_x", "--out", tmp_path / "b.png")
    msg = " ".join(res.output.split())
    assert res.exit_code == 2 and "--fs HZ" in msg and "fs must be given" not in msg
    res = invoke("plot", bare, "-c", "force_x", "--out", tmp_path / "b.png", "--fs", "500")
    assert res.exit_code == 0, res.output


# ----------------------------------------- item 7 (and 9): every command on a binary, an empty and a missing file
#: Commands that read no input file, and why they are left out of the file checks.
NO_INPUT_FILE = {
    "demo": "simulates its own data",
    "simulate": "simulates its own data",
    "bench": "simulates its own data",
    "axis": "writes a preset",
    "dataset build": "simulates its own data (its --out FILE is checked below)",
    "wear simulate": "simulates its own data",
    "sensor simulate": "simulates its own data",
    "batch wear": "reads its inputs in the tasks: a bad one gets an error row and exit 1 (tests/test_fleet.py)",
    "batch identify": "reads its inputs in the tasks: a bad one gets an error row and exit 1 (tests/test_fleet.py)",
}
#: Each command's input files: argument lists with '{IN}' where the bad file goes (its suffix follows it);
#: GOOD/AXIS/XML/MODEL/FILTER stand for valid files, OUT for an output path.
INPUT_FILES = {
    "estimate": [["{IN}.csv", "--axis", "AXIS", "--out", "OUT.csv"], ["{IN}.nc", "--axis", "AXIS", "--out", "OUT.csv"],
                 ["GOOD.nc", "--axis", "{IN}.toml", "--out", "OUT.csv"],
                 ["GOOD.nc", "--method", "model", "--axes", "{IN}.toml", "--out", "OUT.csv"],
                 ["GOOD.nc", "--method", "lstm", "--model", "{IN}", "--out", "OUT.csv"],
                 ["GOOD.nc", "--axis", "AXIS", "--idle", "{IN}.csv", "--out", "OUT.csv"]],
    "friction": [["{IN}.csv", "--axis", "AXIS"], ["GOOD.nc", "--axis", "{IN}.toml"]],
    "detect": [["{IN}.csv", "--axis", "AXIS", "--idle", "GOOD.nc", "--json", "OUT.json"],
               ["GOOD.nc", "--axis", "AXIS", "--idle", "{IN}.nc", "--json", "OUT.json"],
               ["GOOD.nc", "--axis", "AXIS", "--tare", "0:0.01", "--limits", "{IN}.json", "--json", "OUT.json"]],
    "teach": [["{IN}.csv", "GOOD.nc", "--axis", "AXIS", "--tare", "0:0.01", "--out", "OUT.json"]],
    "monitor": [["{IN}.toml"], ["--replay", "{IN}.csv", "--axis", "AXIS", "--idle", "GOOD.nc"],
                ["--replay", "GOOD.nc", "--spindle-rpm", "6000", "--axis", "{IN}.toml", "--idle", "GOOD.nc"],
                ["--replay", "GOOD.nc", "--spindle-rpm", "6000", "--axis", "AXIS", "--idle", "{IN}.nc"]],
    "publish": [["{IN}.csv", "--mqtt", "mqtt://127.0.0.1:9"], ["{IN}.nc", "--mqtt", "mqtt://127.0.0.1:9"]],
    "train": [["lstm", "--data", "{IN}", "--out", "OUT"], ["hybrid", "--data", "GOOD.nc", "--axes", "{IN}.toml",
                                                          "--out", "OUT"]],
    "plot": [["{IN}.csv", "-c", "force_x"], ["{IN}.nc", "-c", "force_x"], ["{IN}.xml", "-c", "force_x"]],
    "identify frf": [["{IN}.csv", "--fix", "K_t=0.45,lead=0.005", "--out", "OUT.toml"],
                     ["{IN}.nc", "--fix", "K_t=0.45,lead=0.005", "--out", "OUT.toml"]],
    "identify linear": [["{IN}.nc", "--out", "OUT.toml"], ["{IN}.csv", "--out", "OUT.toml"]],
    "identify nc": [["{IN}.nc", "--out", "OUT.toml"], ["{IN}.csv", "--out", "OUT.toml"]],
    "wear calibrate": [["{IN}.csv"]],
    "wear track": [["{IN}.csv"]],
    "feedpower fit": [["{IN}.csv", "--model", "OUT.json"]],
    "feedpower predict": [["{IN}.csv", "--model", "MODEL", "--out", "OUT.csv"],
                          ["GOOD.csv", "--model", "{IN}.json", "--out", "OUT.csv"]],
    "sensor calibrate": [["{IN}.csv", "--out", "OUT.json"], ["{IN}.nc", "--out", "OUT.json"]],
    "sensor apply": [["{IN}.nc", "--filter", "FILTER", "--out", "OUT.nc"],
                     ["GOOD.nc", "--filter", "{IN}.json", "--out", "OUT.nc"]],
    "xml validate": [["{IN}.xml"]],
    "xml export": [["{IN}.csv", "--out", "OUT.xml"], ["{IN}.nc", "--out", "OUT.xml"]],
    "xml import": [["{IN}.xml", "--out", "OUT.nc"]],
    "xml transform": [["{IN}.xml"], ["XML", "--xslt", "{IN}.xsl"]],
    "archive add": [["{IN}.xml", "--archive", "OUT.sqlite"], ["{IN}.nc", "--archive", "OUT.sqlite"],
                    ["{IN}.csv", "--archive", "OUT.sqlite"]],
    "archive search": [["--archive", "{IN}.sqlite"]],
    "archive show": [["abc", "--archive", "{IN}.sqlite"]],
    "archive export": [["abc", "--out", "OUT.nc", "--archive", "{IN}.sqlite"]],
    "archive rm": [["abc", "--archive", "{IN}.sqlite"]],
    "batch estimate": [["GOOD.nc", "--axis", "{IN}.toml", "--idle", "GOOD.nc", "--workers", "0", "--out", "OUT"],
                       ["GOOD.nc", "--axis", "AXIS", "--idle", "{IN}.nc", "--workers", "0", "--out", "OUT"]],
    "batch detect": [["GOOD.nc", "--axis", "AXIS", "--tare", "0:0.01", "--limits", "{IN}.json", "--workers", "0",
                      "--out", "OUT"]],
    "mtconnect probe": [["{IN}.xml"]],
    "mtconnect import": [["{IN}.xml", "--out", "OUT.nc"], ["{IN}.txt", "--out", "OUT.nc"],
                         ["XML", "--devices", "{IN}.xml", "--out", "OUT.nc"]],
}
_BAD_FILES = {"binary": __import__("random").Random(5).randbytes(5000), "empty": b"", "missing": None}


@pytest.fixture(scope="module")
def good_files(tmp_path_factory) -> dict:
    import numpy as np

    from drivesense.io import write_recording

    d = tmp_path_factory.mktemp("good")
    assert invoke("axis", "--out", d / "axis.toml").exit_code == 0
    rec = Recording.from_arrays({"x_current_ref": np.sin(np.arange(64.0)), "force_x": np.ones(64)}, fs=1000.0)
    write_recording(rec, d / "good.nc")
    write_recording(rec, d / "good.csv")
    write_recording(rec, d / "good.xml")
    data = Path(__file__).parent / "data"
    assert invoke("feedpower", "fit", data / "feed_power_table3.csv", "--model", d / "model.json").exit_code == 0
    assert invoke("sensor", "simulate", "--out-dir", d / "s", "--levels", "1.3").exit_code == 0
    assert invoke("sensor", "calibrate", d / "s" / "shaker_1.3g.nc", "--out", d / "filter.json").exit_code == 0
    return {"GOOD.nc": d / "good.nc", "GOOD.csv": d / "good.csv", "AXIS": d / "axis.toml", "XML": d / "good.xml",
            "MODEL": d / "model.json", "FILTER": d / "filter.json"}


def test_every_command_is_checked_or_listed_as_reading_no_file():
    assert set(INPUT_FILES) | set(NO_INPUT_FILE) == set(_commands())
    assert not set(INPUT_FILES) & set(NO_INPUT_FILE)


@pytest.mark.parametrize("kind", list(_BAD_FILES))
@pytest.mark.parametrize("command, template", [(c, t) for c, ts in INPUT_FILES.items() for t in ts],
                         ids=lambda v: v if isinstance(v, str) else "-".join(a for a in v if "{IN}" in a))
def test_bad_input_file_gives_one_line_and_exit_2(command, template, kind, good_files, tmp_path):
    args = []
    for a in template:
        if "{IN}" in a:
            path = tmp_path / a.replace("{IN}", f"bad_{kind}")
            if _BAD_FILES[kind] is not None:
                path.write_bytes(_BAD_FILES[kind])
            a = path
        elif a in good_files:
            a = good_files[a]
        elif a.startswith("OUT"):
            a = tmp_path / a.replace("OUT", "out")
        args.append(a)
    res = invoke(*command.split(), *args)
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit), res.output
    assert "error:" in res.output, res.output
    if kind == "binary" and any(str(a).endswith(".csv") and "{IN}" in str(a) for a in template):
        assert "not a text CSV file" in res.output, res.output


def test_dataset_build_out_a_file_is_refused_in_one_line(tmp_path):
    (tmp_path / "data").write_text("not a folder")
    res = invoke("dataset", "build", "--out", tmp_path / "data")
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "--out" in res.output and "is a file" in res.output and len(res.output.strip().splitlines()) == 1


# ------------------------------------------------------------ item 12: one rule for every output option
def _minimal_args(cmd, skip: str) -> list[str]:
    """A placeholder for each required parameter but `skip` (the checks run before anything is read)."""
    args = []
    for p in cmd.params:
        if p.required and p.name != skip:
            args += ["placeholder"] if p.param_type_name == "argument" else [p.opts[0], "placeholder"]
    return args


@pytest.mark.parametrize("option", ["--out", "--json", "--plot", "--out-dir"])
def test_output_into_a_missing_folder_is_refused_by_every_command(option, tmp_path):
    checked = []
    for name, cmd in _commands().items():
        param = next((p for p in cmd.params if option in p.opts), None)
        if param is None:
            continue
        missing = tmp_path / "typo" / "deeper"
        res = invoke(*name.split(), *_minimal_args(cmd, param.name), option, missing / "result.out")
        assert res.exit_code == 2, (name, res.output)
        assert f"{option}: folder '{missing}' does not exist" in " ".join(res.output.split()), (name, res.output)
        assert not (tmp_path / "typo").exists(), name
        checked.append(name)
    assert checked


def test_reading_a_missing_archive_is_an_error_and_creates_nothing(tmp_path):
    for args in (["search"], ["show", "abc"], ["rm", "abc"], ["export", "abc", "--out", tmp_path / "x.nc"]):
        res = invoke("archive", *args, "--archive", tmp_path / "typo.sqlite")
        assert res.exit_code == 2 and "typo.sqlite' does not exist" in " ".join(res.output.split()), res.output
        res = invoke("archive", *args, "--archive", tmp_path / "no" / "a.sqlite")
        assert res.exit_code == 2, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    (tmp_path / "empty.sqlite").write_bytes(b"")
    res = invoke("archive", "search", "--archive", tmp_path / "empty.sqlite")
    assert res.exit_code == 2 and "not a drivesense archive" in res.output
    assert (tmp_path / "empty.sqlite").stat().st_size == 0


def test_feedpower_fit_model_output_follows_the_same_rule(tmp_path):
    data = Path(__file__).parent / "data" / "feed_power_table3.csv"
    res = invoke("feedpower", "fit", data, "--model", tmp_path / "typo" / "model.json")
    assert res.exit_code == 2 and "--model: folder" in res.output and not (tmp_path / "typo").exists()
