"""Recording: construction, validation, slicing, netCDF and CSV I/O."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from drivesense.errors import (
    ConfigError,
    InvalidSignalError,
    MissingChannelError,
    SignalTooShortError,
    TimebaseError,
    UnitError,
)
from drivesense.io import load_netcdf, read_csv, read_recording, write_csv, write_recording
from drivesense.io.csv import sidecar_path
from drivesense.recording import Recording, validate_timebase

DATA = Path(__file__).parent / "data"


def make_rec(n=1000, fs=1000.0, t0=0.0, **meta):
    rng = np.random.default_rng(1)
    return Recording.from_arrays(
        {"x_table_position": np.linspace(0, 0.1, n), "x_current_ref": rng.normal(size=n)},
        fs=fs, t0=t0, meta=meta or None)


def write(tmp_path, text, name="trace.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------- construction
def test_from_arrays_basics():
    rec = Recording.from_arrays({"x_table_position": [0.0, 1.0, 2.0, 3.0], "gain": [1, 2, 3, 4]},
                                fs=100.0, t0=2.0, units={"x_table_position": "mm"},
                                meta={"name": "cut_03"})
    assert rec.fs == 100.0 and rec.dt == 0.01 and rec.t0 == 2.0
    assert len(rec) == rec.n_samples == 4 and rec.duration == pytest.approx(0.04)
    np.testing.assert_allclose(rec.time, [2.0, 2.01, 2.02, 2.03])
    assert rec.channels == ["x_table_position", "gain"] and "gain" in rec and "x" not in rec
    np.testing.assert_allclose(rec["x_table_position"], [0.0, 1e-3, 2e-3, 3e-3])
    assert rec["gain"].dtype == np.float64
    assert rec.units("x_table_position") == "m" and rec.units("gain") == "1"
    assert rec.dataset["x_table_position"].attrs["units"] == "m"
    assert "cut_03" in repr(rec) and "4 samples" in repr(rec)


def test_recording_is_immutable():
    rec = make_rec(name="r")
    with pytest.raises(ValueError):
        rec["x_current_ref"][0] = 1.0
    meta = rec.meta
    meta["name"] = "changed"
    assert rec.meta["name"] == "r"
    rec2 = rec.with_meta(tool="T12").with_provenance("step one").with_provenance("step two")
    assert rec2.meta == {"name": "r", "tool": "T12", "provenance": ["step one", "step two"]}
    assert "provenance" not in rec.meta


def test_validation_names_channel_and_first_bad_sample():
    x = np.zeros(1000)
    x[[120, 130, 140]] = [np.nan, np.inf, np.nan]
    with pytest.raises(InvalidSignalError,
                       match=r"channel 'x_current_ref' has 3 non-finite values "
                             r"\(first NaN at sample 120, t=0\.0120 s\)"):
        Recording.from_arrays({"x_current_ref": x}, fs=10_000.0)
    with pytest.raises(InvalidSignalError, match="'b' has 3 samples, expected 2"):
        Recording.from_arrays({"a": [1.0, 2.0], "b": [1.0, 2.0, 3.0]}, fs=1.0)
    with pytest.raises(SignalTooShortError):
        Recording.from_arrays({"a": [1.0]}, fs=1.0)
    with pytest.raises(TimebaseError, match="fs"):
        Recording.from_arrays({"a": [1.0, 2.0]}, fs=-5.0)
    with pytest.raises(UnitError, match="channel 'x_motor_angle' expects an angle unit"):
        Recording.from_arrays({"x_motor_angle": [1.0, 2.0]}, fs=1.0, units={"x_motor_angle": "mm"})
    with pytest.raises(ConfigError, match=r"meta\['tool'\]"):
        Recording.from_arrays({"a": [1.0, 2.0]}, fs=1.0, meta={"tool": object()})


def test_wrapping_a_dataset_checks_units():
    ds = make_rec().dataset
    ds["x_table_position"].attrs["units"] = "mm"
    with pytest.raises(UnitError, match="'x_table_position' is in 'mm'"):
        Recording(ds)
    del ds["x_table_position"].attrs["units"]
    with pytest.raises(UnitError, match="no attrs"):
        Recording(ds)


def test_require_names_recording_and_missing_channels():
    rec = make_rec(name="cut_03")
    rec.require("x_current_ref")
    with pytest.raises(MissingChannelError) as err:
        rec.require("x_current_ref", "x_motor_angle")
    assert str(err.value) == ("recording 'cut_03' lacks channel(s) 'x_motor_angle' "
                              "(has: x_table_position, x_current_ref)")
    with pytest.raises(KeyError):
        rec["force_x"]


def test_slice_time_is_half_open_in_absolute_seconds():
    rec = make_rec(n=1000, fs=1000.0, t0=10.0)
    part = rec.slice_time(10.1, 10.2)
    assert part.n_samples == 100 and part.t0 == pytest.approx(10.1)
    np.testing.assert_array_equal(part["x_current_ref"], rec["x_current_ref"][100:200])
    assert rec.slice_time(end=10.5).n_samples == 500
    with pytest.raises(SignalTooShortError):
        rec.slice_time(10.999)  # one sample left
    assert rec.slice_time(0.0, 100.0).n_samples == 1000


def test_with_channels_and_select():
    rec = make_rec()
    force = np.ones(rec.n_samples)
    rec2 = rec.with_channels({"force_x": force * 2, "x_table_position": force},
                             units={"force_x": "kN"})
    assert rec2.channels == ["x_table_position", "x_current_ref", "force_x"]
    np.testing.assert_allclose(rec2["force_x"], 2000.0)
    np.testing.assert_array_equal(rec2["x_table_position"], force)
    with pytest.raises(InvalidSignalError, match="'force_x' has 3 samples"):
        rec.with_channels({"force_x": [1.0, 2.0, 3.0]})
    sel = rec2.select("force_x", "x_current_ref")
    assert sel.channels == ["force_x", "x_current_ref"] and sel.fs == rec.fs


def test_from_time_arrays_and_validate_timebase():
    t = np.arange(500) * 1e-3 + 0.25
    rec = Recording.from_time_arrays(t, {"x_current_ref": np.ones(500)})
    assert rec.fs == 1000.0 and rec.t0 == 0.25
    assert "from_time_arrays" in rec.meta["provenance"][0]
    rec_ms = Recording.from_time_arrays(t * 1e3, {"a": np.ones(500)}, units={"time": "ms"})
    assert rec_ms.fs == 1000.0
    jittery = t.copy()
    jittery[300] += 2e-5  # 2 % of a step
    with pytest.raises(TimebaseError, match=r"step to sample 300 .*\(2 % jitter"):
        validate_timebase(jittery)
    assert validate_timebase(jittery, rel_tol=0.05) == pytest.approx(1000.0)
    backwards = t.copy()
    backwards[7] = backwards[6]
    with pytest.raises(TimebaseError, match="does not increase at sample 7"):
        validate_timebase(backwards)
    with pytest.raises(TimebaseError):
        validate_timebase([1.0])


# ---------------------------------------------------------------- netCDF
def test_save_load_round_trip_is_bit_exact(tmp_path):
    meta = {"name": "cut_03", "machine": {"axes": ["x", "y"], "ratio": 1 / 3, "ok": True},
            "tool": None, "provenance": ["simulated", "ünïcode"]}
    rec = Recording.from_arrays(
        {"x_current_ref": np.random.default_rng(2).normal(size=777),
         "force_x": np.geomspace(1e-300, 1e300, 777)}, fs=1 / 3e-4, t0=-0.1, meta=meta)
    out = write_recording(rec, tmp_path / "rec.nc")
    assert out == tmp_path / "rec.nc"
    assert [p.name for p in tmp_path.iterdir()] == ["rec.nc"]  # no temp file left
    back = read_recording(out)
    assert back.equals(rec)
    assert back.meta == meta and back.fs == rec.fs and back.t0 == rec.t0
    np.testing.assert_array_equal(back.time, rec.time)
    assert back.units("force_x") == "N"
    assert read_recording(out).equals(rec)


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.nc"):
        load_netcdf(tmp_path / "missing.nc")
    ds = make_rec().dataset
    del ds.attrs["fs"]
    ds.to_netcdf(tmp_path / "other.nc", engine="netcdf4")
    with pytest.raises(InvalidSignalError, match="'fs'"):
        load_netcdf(tmp_path / "other.nc")
    with pytest.raises(ConfigError, match="'.txt'"):
        read_recording(tmp_path / "x.txt")


# ---------------------------------------------------------------- CSV
def test_read_csv_converts_to_si():
    rec = read_csv(DATA / "x_axis_small.csv")
    assert rec.channels == ["x_table_position", "x_motor_angle", "x_current_ref"]
    assert rec.fs == 1000.0 and rec.t0 == 0.0 and rec.n_samples == 20
    k = np.arange(20)
    np.testing.assert_allclose(rec["x_table_position"], 0.5e-3 * k, rtol=1e-12)
    np.testing.assert_allclose(rec["x_motor_angle"], np.deg2rad(18.0 * k), rtol=1e-12)
    np.testing.assert_allclose(rec["x_current_ref"], np.sin(k / 3), atol=1e-6)
    assert [rec.units(c) for c in rec.channels] == ["m", "rad", "A"]
    assert rec.meta["name"] == "x_axis_small"
    prov = rec.meta["provenance"][-1]
    assert prov.startswith("read_csv x_axis_small.csv") and "table_position mm->m" in prov


def test_read_csv_axis_mapping_and_fs(tmp_path):
    path = write(tmp_path, "Strom [A];Lage [um];velocity [mm/min]\n1;2;6000\n3;4;6000\n5;6;6000\n")
    rec = read_csv(path, axis="y", mapping={"Strom": "x_current_ref", "Lage": "table_position"},
                   fs=500.0)
    assert rec.channels == ["x_current_ref", "y_table_position", "y_velocity"]
    np.testing.assert_allclose(rec["y_table_position"], [2e-6, 4e-6, 6e-6])
    np.testing.assert_allclose(rec["y_velocity"], 0.1)
    assert rec.fs == 500.0 and rec.t0 == 0.0
    with pytest.raises(ConfigError, match="no 'time' column"):
        read_csv(path)


@pytest.mark.parametrize(
    "text, error, pattern",
    [
        ("time [s],current_ref [A]\n0,1\n0.001,nan\n0.002,1\n", InvalidSignalError,
         r"channel 'x_current_ref' has 1 non-finite values \(first nan at line 3\)"),
        ("time [s],force_x [N]\n0,1\n0.001,inf\n0.002,1\n", InvalidSignalError,
         r"'force_x' has 1 non-finite"),
        ("time [s],current_ref [A]\n0,1\n0.002,1\n0.001,1\n", TimebaseError,
         r"does not increase at line 4"),
        ("# c\ntime [s],current_ref [A]\n0,1\n0.001,1\n0.00205,1\n0.003,1\n", TimebaseError,
         r"not uniform: the step to line 5"),
        ("time [s],table_position [furlong]\n0,1\n0.001,1\n", UnitError,
         r"column 'table_position \[furlong\]'.*unknown unit 'furlong'"),
        ("time [s],table_position [A]\n0,1\n0.001,1\n", UnitError,
         r"'x_table_position' expects a length unit, got 'A'"),
        ("time [s],current_ref [A]\n0,1\n0.001,abc\n", InvalidSignalError,
         r"line 3, column 'current_ref \[A\]': 'abc' is not a number"),
        ("time [s],current_ref [A]\n", InvalidSignalError, "no data rows"),
        ("# only a comment\n\n", InvalidSignalError, "empty file"),
    ],
)
def test_read_csv_errors(tmp_path, text, error, pattern):
    with pytest.raises(error, match=pattern) as err:
        read_csv(write(tmp_path, text))
    assert "trace.csv" in str(err.value)


def test_csv_carries_metadata(tmp_path):
    rec = make_rec(n=50, fs=1000.0, name="meta").with_meta(nc_delay_s=0.004, score_window=[0.01, 0.04],
                                                               ratio=np.float32(1.5), label="µm, ä")
    path = write_csv(rec, tmp_path / "m.csv")
    assert path.read_text().splitlines()[0] == "time [s],x_table_position [m],x_current_ref [A]"
    frame = pd.read_csv(path)                        # other tools read it with their defaults
    assert list(frame.columns) == ["time [s]", "x_table_position [m]", "x_current_ref [A]"] and len(frame) == 50
    side = json.loads(sidecar_path(path).read_text(encoding="utf-8"))
    assert side["nc_delay_s"] == 0.004 and "provenance" not in side
    back = read_csv(path)
    assert back.meta["nc_delay_s"] == 0.004 and back.meta["score_window"] == [0.01, 0.04]
    assert back.meta["name"] == "meta" and back.meta["ratio"] == 1.5 and back.meta["label"] == "µm, ä"
    assert read_csv(path, meta={"nc_delay_s": 0.0}).meta["nc_delay_s"] == 0.0     # the caller's meta wins
    write_csv(make_rec(n=50), path)          # rewritten without metadata: the old sidecar must not stay
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.csv"] and "nc_delay_s" not in read_csv(path).meta
    # older files: the metadata on a '# meta:' line before the header
    (tmp_path / "old.csv").write_text('# meta: {"nc_delay_s": 0.002}\ntime [s],force_x [N]\n0,1\n0.001,1\n')
    assert read_csv(tmp_path / "old.csv").meta["nc_delay_s"] == 0.002
    (tmp_path / "side.csv.json").write_text("[1]")
    (tmp_path / "side.csv").write_text("time [s],force_x [N]\n0,1\n0.001,1\n")
    with pytest.raises(InvalidSignalError, match="side.csv.json' must hold a JSON object"):
        read_csv(tmp_path / "side.csv")
    (tmp_path / "bad.csv").write_text("# meta: {nope\ntime [s],force_x [N]\n0,1\n0.001,1\n")
    with pytest.raises(InvalidSignalError, match=r"bad.csv, line 1: the '# meta:' line is not valid JSON"):
        read_csv(tmp_path / "bad.csv")
    (tmp_path / "list.csv").write_text("# meta: [1]\ntime [s],force_x [N]\n0,1\n0.001,1\n")
    with pytest.raises(InvalidSignalError, match="must hold a JSON object"):
        read_csv(tmp_path / "list.csv")


def test_read_csv_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_csv(tmp_path / "nope.csv")


def test_write_read_csv_round_trip(tmp_path):
    rec = make_rec(n=300, fs=2000.0, t0=1.5, name="rt")
    exact = read_csv(write_csv(rec, tmp_path / "si.csv"))
    assert exact.fs == rec.fs and exact.t0 == rec.t0
    for c in rec.channels:
        np.testing.assert_array_equal(exact[c], rec[c])
    out = write_recording(rec, tmp_path / "user.csv", units={"time": "ms", "x_table_position": "mm"})
    assert out.read_text().splitlines()[0] == "time [ms],x_table_position [mm],x_current_ref [A]"
    back = read_recording(out)
    assert back.fs == rec.fs and back.t0 == rec.t0
    np.testing.assert_allclose(back["x_table_position"], rec["x_table_position"], rtol=1e-14)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["si.csv", "si.csv.json", "user.csv", "user.csv.json"]
    with pytest.raises(UnitError):
        write_csv(rec, tmp_path / "bad.csv", units={"x_current_ref": "mm"})
    assert not (tmp_path / "bad.csv").exists()


def test_json_files_are_strict_json(tmp_path):
    """NaN/inf (nested in dicts, lists, tuples, numpy arrays and scalars) are written as null, never NaN."""
    from drivesense.io import strict_json, write_json_file

    payload = {"harmonic_error": float("nan"), "rows": [{"x": np.float64("inf")}, (np.float32("-inf"), 1.5)],
               "array": np.array([1.0, np.nan]), "n": np.int64(3), "ok": True, "none": None}

    def refuse(name):
        raise ValueError(f"not JSON: {name}")

    text = write_json_file(tmp_path / "out.json", payload).read_text()
    back = json.loads(text, parse_constant=refuse)
    assert back == {"harmonic_error": None, "rows": [{"x": None}, [None, 1.5]], "array": [1.0, None], "n": 3,
                    "ok": True, "none": None}
    assert json.loads(strict_json(payload, indent=None), parse_constant=refuse) == back


def test_read_csv_refuses_columns_without_units_unless_assume_si(tmp_path):
    """'table_position,time,motor_angle' in um, ms and rev must not be read as m, s and rad silently."""
    path = write(tmp_path, "time,table_position,motor_angle [rev],current_ref\n0,1,0,2\n1,2,0.5,2\n2,3,1,2\n")
    with pytest.raises(UnitError) as err:
        read_csv(path)
    msg = str(err.value)
    assert "trace.csv" in msg and "'time', 'table_position', 'current_ref'" in msg and "--assume-si" in msg
    assert "table_position [mm]" in msg and "motor_angle" not in msg.split("have no unit")[0]
    rec = read_csv(path, assume_si=True)
    assert rec.fs == 1.0 and rec["x_table_position"][1] == 2.0 and rec.units("x_table_position") == "m"
    assert "SI assumed (--assume-si): time, table_position, current_ref" in rec.meta["provenance"][-1]


def test_read_csv_resamples_jittery_time_explicitly_and_takes_fs_without_time(tmp_path):
    t = np.arange(200) * 1e-3
    t[1:-1] += np.random.default_rng(1).uniform(-2e-4, 2e-4, 198)        # 20 % jitter
    text = "time [s],force_x [N]\n" + "".join(f"{a!r},{3 * a!r}\n" for a in t.tolist())
    path = write(tmp_path, text)
    with pytest.raises(TimebaseError, match=r"not uniform.*--resample HZ"):
        read_csv(path)
    rec = read_csv(path, resample=1000.0)
    assert rec.fs == 1000.0 and rec.n_samples == 200 and rec.t0 == 0.0
    np.testing.assert_allclose(rec["force_x"], 3 * rec.time, atol=1e-12)    # linear data: exact
    assert "resampled explicitly (--resample)" in rec.meta["provenance"][-1]
    with pytest.raises(ConfigError, match="--fs HZ.*--resample HZ.*not both"):
        read_csv(path, resample=1000.0, fs=1000.0)
    bare = write(tmp_path, "force_x [N]\n1\n2\n3\n", name="bare.csv")
    with pytest.raises(ConfigError, match="no 'time' column: give the sample rate with --fs HZ"):
        read_csv(bare)
    with pytest.raises(ConfigError, match="--resample needs time stamps; give the sample rate with --fs HZ"):
        read_csv(bare, resample=10.0)
    assert read_csv(bare, fs=10.0).fs == 10.0
    back = write(tmp_path, "time [s],force_x [N]\n0,1\n0.002,1\n0.001,1\n", name="back.csv")
    with pytest.raises(TimebaseError, match="does not increase at line 4"):
        read_csv(back, resample=1000.0)
