"""Input sanity of NC controller traces (#14 item 4): impossible samples refused or repaired, units, time stamps.

The traces here are written as an edge device exports them: ``time [s]``, positions in mm, velocities in
mm/s, accelerations in mm/s^2, currents in A and the spindle in deg/s, a comment line before the header.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ImplausibleSampleError, InvalidSignalError, TimebaseError
from drivesense.io import (BadSampleWarning, PlausibilityLimits, check_channels, check_plausibility, read_csv,
                           read_recording, screen_recording, write_recording)
from drivesense.recording import Recording

runner = CliRunner()
RPM = 2 * math.pi / 60
#: Controller units of each channel kind (the file's header units).
NC_UNITS = {"position": "mm", "velocity": "mm/s", "acceleration": "mm/s^2", "current": "A", "spindle_speed": "deg/s",
            "spindle_current": "A"}
#: The file's first data row is on this line: a comment line, then the header.
FIRST_ROW = 3


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def _unit_and_factor(channel: str) -> tuple[str, float]:
    """The controller's unit of a channel and its SI -> file factor."""
    if channel.startswith("spindle_speed"):
        return "deg/s", 180 / math.pi
    kind = channel.split("_", 1)[1] if channel[:2] in ("x_", "y_", "z_") else channel
    unit = NC_UNITS[kind]
    return unit, {"mm": 1e3, "mm/s": 1e3, "mm/s^2": 1e3, "A": 1.0}[unit]


def write_controller_csv(rec: Recording, path: Path, edit=None, time=None) -> Path:
    """`rec` as an edge device exports it (controller units, fixed decimals); `edit(values)` changes file values."""
    channels = [c for c in rec.channels if not c.startswith("force_")]
    values = {"time": np.asarray(rec.time if time is None else time)}
    header = ["time [s]"]
    for c in channels:
        unit, factor = _unit_and_factor(c)
        values[c] = rec[c] * factor
        header.append(f"{c} [{unit}]")
    if edit is not None:
        edit(values)
    rows = zip(*(values[k].tolist() for k in ["time", *channels]))
    path.write_text("# edge recorder export, controller units\n" + ",".join(header) + "\n"
                    + "".join(",".join(f"{v:.6f}" for v in row) + "\n" for row in rows))
    return path


@pytest.fixture(scope="module")
def groove() -> Recording:
    from drivesense.sim import machining

    return machining.simulate_process("groove_+x", 2e-3, 10e-3, 0.02, 8000)


# ------------------------------------------------------------------ clean traces: no flags
def test_clean_controller_csv_reads_without_flags(groove, tmp_path):
    rec = read_csv(write_controller_csv(groove, tmp_path / "clean.csv"))
    assert rec.fs == pytest.approx(250.0) and "repaired_samples" not in rec.meta
    np.testing.assert_allclose(rec["spindle_speed"], groove["spindle_speed"], atol=1e-6 * math.pi / 180)
    np.testing.assert_allclose(rec["x_position"], groove["x_position"], atol=1e-9)
    report = check_plausibility(rec)
    assert report.ok and len(report.checked) == 14 and "force_x" not in report.checked


def _scenarios() -> list[str]:
    from drivesense.sim.catalog import describe_scenarios

    return list(describe_scenarios())


@pytest.mark.parametrize("name", _scenarios())
def test_every_simulated_scenario_raises_no_flag(name):
    """Zero false flags on the simulator's traces, with a margin: none either with every threshold halved."""
    from drivesense.sim.catalog import simulate_scenario

    base = PlausibilityLimits()
    halved = ("position_factor", "position_tolerance", "position_speed_max", "spike_spread_factor", "spike_mad_factor")
    strict = PlausibilityLimits(**{k: getattr(base, k) / 2 for k in halved},
                                spike_floor={q: v / 2 for q, v in base.spike_floor.items()})
    for rec in simulate_scenario(name, seed=1):
        for limits in (base, strict):
            report = check_plausibility(rec, limits=limits)
            assert report.ok and not report.notes, report.summary()
        assert screen_recording(rec) is rec


# ------------------------------------------------------------------ the -3.3e6 rpm spindle sample
def _spindle_glitch(row: int, rpm: float = -3.3e6):
    def edit(values):
        values["spindle_speed"][row] = rpm * 6.0         # rpm -> deg/s
    return edit


def test_spindle_speed_of_minus_3_3e6_rpm_is_refused_naming_its_line(groove, tmp_path):
    path = write_controller_csv(groove, tmp_path / "trace.csv", _spindle_glitch(400))
    with pytest.raises(ImplausibleSampleError) as err:
        read_csv(path)
    msg = str(err.value)
    assert isinstance(err.value, InvalidSignalError) and isinstance(err.value, ValueError)
    assert f"trace.csv: 1 implausible sample: spindle_speed, line {400 + FIRST_ROW}: -1.98e+07 deg/s (-3.3e+06 rpm)" \
        in msg
    assert "beyond the physical limit of +-6e+05 deg/s (100000 rpm)" in msg
    assert "--bad-samples repair" in msg and "--bad-samples off" in msg and "bad_samples" not in msg
    assert path.read_text().splitlines()[400 + FIRST_ROW - 1].split(",")[-2] == "-19800000.000000"
    (sample,) = err.value.report.samples
    assert (sample.channel, sample.index, sample.line, sample.unit) == ("spindle_speed", 400, 403, "deg/s")
    assert sample.value == pytest.approx(-1.98e7)
    assert read_recording(path, bad_samples="off")["spindle_speed"][400] == pytest.approx(-3.3e6 * RPM)


def test_repair_interpolates_the_sample_and_reports_it(groove, tmp_path):
    path = write_controller_csv(groove, tmp_path / "trace.csv", _spindle_glitch(400))
    with pytest.warns(BadSampleWarning, match=rf"trace.csv: repaired 1 implausible sample .*line {400 + FIRST_ROW}"):
        rec = read_csv(path, bad_samples="repair")
    n = rec["spindle_speed"]
    assert n[400] == pytest.approx(0.5 * (n[399] + n[401]), rel=1e-12)
    assert abs(n[400] - groove["spindle_speed"][400]) < 0.5 * RPM * 60     # back near 8000 rpm
    (entry,) = rec.meta["repaired_samples"]
    assert entry["channel"] == "spindle_speed" and entry["line"] == 403 and entry["sample"] == 400
    assert entry["value"] == pytest.approx(-1.98e7) and entry["unit"] == "deg/s"
    assert "physical limit" in entry["reason"] and entry["replaced_by"] == pytest.approx(n[400] * 180 / math.pi)
    assert any("--bad-samples repair" in step for step in rec.meta["provenance"])
    json.dumps(rec.meta, allow_nan=False)


def test_a_spindle_spike_within_the_limit_is_an_isolated_spike(groove, tmp_path):
    path = write_controller_csv(groove, tmp_path / "trace.csv", _spindle_glitch(600, rpm=30000.0))
    with pytest.raises(ImplausibleSampleError, match=r"spindle_speed, line 603: 180000 deg/s \(3e\+04 rpm\) is an "
                                                     r"isolated spike"):
        read_csv(path)


# ------------------------------------------------------------------ position jumps
def test_a_position_jump_and_back_is_flagged_and_repairable(groove, tmp_path):
    def edit(values):
        values["x_position"][500] += 5.0                 # mm: an encoder glitch
    path = write_controller_csv(groove, tmp_path / "jump.csv", edit)
    with pytest.raises(ImplausibleSampleError) as err:
        read_csv(path)
    msg = str(err.value)
    assert "x_position, line 503:" in msg and "is +5 mm off the line between its neighbours" in msg
    assert "the logged x_velocity allows at most" in msg
    with pytest.warns(BadSampleWarning):
        rec = read_csv(path, bad_samples="repair")
    np.testing.assert_allclose(rec["x_position"][500], groove["x_position"][500], atol=2e-6)


def test_a_position_step_that_stays_is_flagged_and_not_repaired(groove, tmp_path):
    def edit(values):
        values["y_position"][700:] += 3.0
    path = write_controller_csv(groove, tmp_path / "step.csv", edit)
    with pytest.raises(ImplausibleSampleError, match=r"y_position, line 703: .* follows a position step of \+3 mm "
                                                     r"that stays") as err:
        read_csv(path)
    assert "--bad-samples repair" not in str(err.value).split("that stays")[-1]
    with pytest.raises(ImplausibleSampleError, match="--bad-samples repair cannot mend this trace.*--bad-samples off"):
        read_csv(path, bad_samples="repair")
    assert read_csv(path, bad_samples="off")["y_position"][700] == pytest.approx(groove["y_position"][700] + 3e-3,
                                                                                 abs=1e-8)


def test_position_without_velocity_channel_is_held_to_2_m_per_s():
    fs, n = 500.0, 400
    s = 0.1 + 0.05 * np.sin(np.arange(n) / fs * 2 * np.pi)         # up to 0.31 m/s
    s[123] += 0.01                                                  # 10 mm in 2 ms: 5 m/s
    report = check_channels({"z_position": s}, fs=fs, units={"z_position": "mm"}, source="z.csv")
    (bad,) = report.samples
    assert bad.index == 123 and bad.value == pytest.approx(s[123] * 1e3) and bad.unit == "mm"
    assert "without a velocity channel (2 m/s" in bad.reason
    s[123] -= 0.01
    assert check_channels({"z_position": s}, fs=fs).ok


def test_a_position_too_fast_throughout_is_a_note_not_a_flag():
    """A wrong unit or rate is not a glitch: warned, not refused (read as the user said)."""
    rec = Recording.from_arrays({"x_table_position": np.arange(64) * 2.0}, fs=1000.0)
    report = check_plausibility(rec)
    assert report.ok and "moves farther than allowed in 63 of 63 steps" in report.notes[0]
    with pytest.warns(BadSampleWarning, match="check the units of the position"):
        assert screen_recording(rec) is rec


# ------------------------------------------------------------------ spikes of velocity, acceleration, current
@pytest.mark.parametrize("channel, value", [("x_velocity", 2500.0), ("y_acceleration", -80000.0),
                                            ("x_current", 35.0), ("spindle_current", -60.0)])
def test_isolated_spikes_are_flagged(groove, tmp_path, channel, value):
    def edit(values):
        values[channel][321] = value
    path = write_controller_csv(groove, tmp_path / "spike.csv", edit)
    with pytest.raises(ImplausibleSampleError) as err:
        read_csv(path)
    (bad,) = err.value.report.samples
    assert (bad.channel, bad.line, bad.value) == (channel, 324, value)
    assert "isolated spike" in bad.reason and bad.unit == _unit_and_factor(channel)[0]


def test_only_isolated_samples_are_spikes_and_neighbours_must_agree():
    x = np.sin(np.arange(300) * 0.05)
    x[100:102] = 40.0                                              # two samples: a pulse, not flagged by default
    assert check_channels({"x_current": x}, fs=1000.0).ok
    report = check_channels({"x_current": x}, fs=1000.0, limits=PlausibilityLimits(spike_run=2))
    assert [s.index for s in report] == [100, 101] and "a spike of 2 samples" in report.samples[0].reason
    x[100:102] = [40.0, 0.8]
    (bad,) = check_channels({"x_current": x}, fs=1000.0)
    assert bad.index == 100 and "isolated spike" in bad.reason
    step = np.where(np.arange(300) < 150, 0.0, 40.0)               # a step is no spike
    assert check_channels({"x_current": step}, fs=1000.0).ok


def test_non_finite_values_are_refused_or_repaired(tmp_path):
    path = tmp_path / "nan.csv"
    t = np.arange(50) * 2e-3
    v = np.sin(t * 20)
    path.write_text("time [s],x_current [A]\n" + "".join(
        f"{a!r},{'nan' if k == 10 else repr(b)}\n" for k, (a, b) in enumerate(zip(t.tolist(), v.tolist()))))
    with pytest.raises(InvalidSignalError, match=r"1 non-finite values \(first nan at line 12\).*--bad-samples repair"):
        read_csv(path)
    with pytest.warns(BadSampleWarning, match=r"x_current, line 12: nan is not a finite number"):
        rec = read_csv(path, bad_samples="repair")
    assert rec["x_current"][10] == pytest.approx(0.5 * (v[9] + v[11]))


def test_report_to_dict_is_strict_json():
    x = np.zeros(20)
    x[5], x[9] = np.nan, 1e9
    report = check_channels({"x_velocity": x, "force_x": np.ones(20)}, fs=100.0, units={"x_velocity": "mm/s"})
    data = json.loads(json.dumps(report.to_dict(), allow_nan=False))
    assert data["n_flagged"] == 2 and data["checked"] == ["x_velocity"]
    assert data["samples"][0]["value"] == "nan" and data["samples"][1]["value"] == pytest.approx(1e12)
    assert data["samples"][1]["reason"].startswith("is beyond the physical limit of +-1e+04 mm/s")
    assert data["limits"]["spindle_speed_max"] == pytest.approx(100000 * RPM)


# ------------------------------------------------------------------ units of controller headers
@pytest.mark.parametrize("channel, unit, value, si", [
    ("spindle_speed", "deg/s", 360.0, 2 * math.pi), ("spindle_speed", "rev/min", 60.0, 2 * math.pi),
    ("spindle_speed", "rpm", 60.0, 2 * math.pi), ("spindle_speed", "°/s", 180.0, math.pi),
    ("x_velocity", "mm/s", 250.0, 0.25), ("x_acceleration", "mm/s^2", 1500.0, 1.5),
    ("x_acceleration", "mm/s²", 1500.0, 1.5), ("x_acceleration", "mm/s2", 1500.0, 1.5),
    ("x_position", "mm", 12.5, 0.0125)])
def test_controller_units_are_read(tmp_path, channel, unit, value, si):
    path = tmp_path / "u.csv"
    path.write_text(f"time [s],{channel} [{unit}]\n" + "".join(f"{k * 0.004:.3f},{value}\n" for k in range(10)),
                    encoding="utf-8")
    rec = read_csv(path)
    np.testing.assert_allclose(rec[channel], si, rtol=1e-14)


# ------------------------------------------------------------------ an edge recorder's raw time column
def _edge_time(n: int, fs: float, seed: int = 3) -> np.ndarray:
    """Stamps of an edge recorder: +-5 % jitter and, every 150 samples, a doubled step (a late sample)."""
    steps = np.full(n - 1, 1 / fs) * (1 + np.random.default_rng(seed).uniform(-0.05, 0.05, n - 1))
    steps[149::150] *= 2
    return np.concatenate([[0.0], np.cumsum(steps)])


def test_irregular_time_stamps_need_resample_and_read_with_it(groove, tmp_path):
    t = _edge_time(groove.n_samples, groove.fs)
    # the recorder samples the motion at its own stamps: positions follow the stamps
    moved = groove.with_channels({c: np.interp(t, groove.time - groove.t0, groove[c]) for c in groove.channels})
    path = write_controller_csv(moved, tmp_path / "edge.csv", time=t)
    with pytest.raises(TimebaseError, match=r"not uniform.*line .*--resample HZ"):
        read_csv(path)
    rec = read_csv(path, resample=250.0)
    assert rec.fs == 250.0 and "repaired_samples" not in rec.meta
    assert any("--resample" in step for step in rec.meta["provenance"])
    np.testing.assert_allclose(rec["x_position"], np.interp(rec.time, t, moved["x_position"]), atol=1e-9)
    res = invoke("xml", "export", path, "--out", tmp_path / "edge.xml")
    assert res.exit_code == 2 and "--resample HZ" in " ".join(res.output.split())
    res = invoke("xml", "export", path, "--out", tmp_path / "edge.xml", "--resample", "250")
    assert res.exit_code == 0, res.output


def test_glitch_in_a_jittery_trace_is_named_by_file_line_before_resampling(groove, tmp_path):
    t = _edge_time(groove.n_samples, groove.fs)
    moved = groove.with_channels({c: np.interp(t, groove.time - groove.t0, groove[c]) for c in groove.channels})
    path = write_controller_csv(moved, tmp_path / "edge.csv", _spindle_glitch(299), time=t)
    with pytest.raises(ImplausibleSampleError, match="spindle_speed, line 302:"):
        read_csv(path, resample=250.0)
    with pytest.warns(BadSampleWarning):
        rec = read_csv(path, resample=250.0, bad_samples="repair")
    assert rec.meta["repaired_samples"][0]["line"] == 302
    assert np.abs(rec["spindle_speed"] / RPM - 8000).max() < 100


# ------------------------------------------------------------------ the command line
def test_every_trace_reading_command_has_bad_samples():
    from typer.main import get_command

    def walk(cmd, path):
        if hasattr(cmd, "commands"):
            for name, sub in cmd.commands.items():
                yield from walk(sub, [*path, name])
        else:
            yield " ".join(path), cmd

    readers = {name: cmd for name, cmd in walk(get_command(app), []) if any("--resample" in p.opts for p in cmd.params)}
    assert {"estimate", "plot", "xml export", "identify nc", "archive add"} <= set(readers)
    for name, cmd in readers.items():
        param = next((p for p in cmd.params if "--bad-samples" in p.opts), None)
        assert param is not None, f"{name} reads traces (--resample) but has no --bad-samples"
        assert param.default is None, name          # refuse for CSV, no check of .nc/.xml unless given


def test_cli_refuses_with_the_line_and_repairs_with_a_warning(groove, tmp_path):
    path = write_controller_csv(groove, tmp_path / "trace.csv", _spindle_glitch(400))
    res = invoke("xml", "export", path, "--out", tmp_path / "t.xml")
    msg = " ".join(res.output.split())
    assert res.exit_code == 2 and "Traceback" not in res.output and msg.startswith("error: trace.csv:")
    assert "spindle_speed, line 403: -1.98e+07 deg/s (-3.3e+06 rpm)" in msg and "--bad-samples repair" in msg
    assert not (tmp_path / "t.xml").exists()
    res = invoke("xml", "export", path, "--out", tmp_path / "t.xml", "--bad-samples", "repair")
    msg = " ".join(res.output.split())
    assert res.exit_code == 0, res.output
    assert "warning: trace.csv: repaired 1 implausible sample" in msg and "line 403" in msg
    back = read_recording(tmp_path / "t.xml")
    assert abs(back["spindle_speed"][400] / RPM - 8000) < 100
    res = invoke("xml", "export", path, "--out", tmp_path / "t.xml", "--bad-samples", "maybe")
    assert res.exit_code == 2 and "--bad-samples" in res.output


def test_cli_checks_saved_recordings_by_sample_index_when_asked(groove, tmp_path):
    """.nc/.xml recordings are drivesense's own lossless files: checked when --bad-samples is given."""
    n = groove["spindle_speed"].copy()
    n[250] = -3.3e6 * RPM
    write_recording(groove.with_channels({"spindle_speed": n}), tmp_path / "g.nc")
    res = invoke("plot", tmp_path / "g.nc", "-c", "spindle_speed", "--out", tmp_path / "p.png")
    assert res.exit_code == 0 and "warning" not in res.output, res.output
    res = invoke("plot", tmp_path / "g.nc", "-c", "spindle_speed", "--out", tmp_path / "p.png", "--bad-samples",
                 "refuse")
    msg = " ".join(res.output.split())
    assert res.exit_code == 2 and "g.nc: 1 implausible sample: spindle_speed, sample 250:" in msg
    assert "(-3.3e+06 rpm)" in msg
    res = invoke("plot", tmp_path / "g.nc", "-c", "spindle_speed", "--out", tmp_path / "p.png", "--bad-samples",
                 "repair")
    assert res.exit_code == 0 and "warning: g.nc: repaired 1" in " ".join(res.output.split()), res.output
    res = invoke("plot", tmp_path / "g.nc", "-c", "spindle_speed", "--out", tmp_path / "p.png", "--bad-samples", "off")
    assert res.exit_code == 0 and "warning" not in res.output, res.output


def test_library_readers_of_saved_recordings_check_only_when_asked(groove, tmp_path):
    n = groove["spindle_speed"].copy()
    n[250] = -3.3e6 * RPM
    write_recording(groove.with_channels({"spindle_speed": n}), tmp_path / "g.nc")
    assert read_recording(tmp_path / "g.nc")["spindle_speed"][250] == n[250]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ImplausibleSampleError, match="g.nc: .*sample 250"):
            read_recording(tmp_path / "g.nc", bad_samples="refuse")
