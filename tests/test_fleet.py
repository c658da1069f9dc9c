"""Fleet batches: one method over many inputs, resumable, failures recorded, on Dask or in this process.

The inputs are the demo axis' simulated 4 s cuts (the second one with a flute breakage) and its idle runs;
what the methods compute is tested elsewhere.  Here a batch must key every result by the content of its input
and of every file its job reads, run only what has no row yet, record a broken input without stopping, give
the same results bit for bit on a Dask cluster as in this process, and write archived inputs' results back
into their archive exactly once.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import distributed  # noqa: F401 - the parallel tests need the real Dask: a missing install must fail, not skip
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError
from drivesense.fleet import (BatchInput, DetectJob, EstimateJob, IdentifyJob, WearJob, archive_inputs, file_inputs,
                              files_from_patterns, run_batch, task_key)
from drivesense.io import read_recording, write_recording

runner = CliRunner()
#: Columns of a summary row that every input has.
ROW_COLUMNS = ["input", "key", "status", "error", "outputs", "seconds", "cpu_seconds"]
#: Columns about the run (when, where, how long), not about the result.
RUN_COLUMNS = {"seconds", "cpu_seconds", "finished", "worker"}


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """AXIS.toml and the demo's idle runs idle*.nc (what a user has for --axis and --idle)."""
    from drivesense.bench.rig import setup_demo_axis

    folder = tmp_path_factory.mktemp("demo")
    setup_demo_axis(folder)
    return folder


@pytest.fixture(scope="module")
def cuts():
    """Four simulated 4 s cuts of the demo axis (10 kHz, with the true force_x); the second has a breakage."""
    from drivesense.monitor.sources import SimulatedSource

    src = SimulatedSource("m", seed=11, cut_s=4.0)
    recs = [src.simulate_cut(k) for k in range(4)]
    assert [e["kind"] for e in recs[1].meta["truth"]["events"]] == ["breakage"]
    return recs


@pytest.fixture(scope="module")
def traces(tmp_path_factory, cuts) -> list[Path]:
    """The cuts as cut0.nc .. cut3.nc (read only: tests copy what they change)."""
    folder = tmp_path_factory.mktemp("traces")
    return [write_recording(rec, folder / f"cut{i}.nc") for i, rec in enumerate(cuts)]


def _copies(paths, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for p in paths:
        shutil.copy2(p, folder / Path(p).name)
    return folder


def _idle(demo: Path) -> list[Path]:
    return sorted(demo.glob("idle*.nc"))


def _estimate(demo: Path, **kw) -> EstimateJob:
    return EstimateJob(**{"method": "vibration", "axis_file": demo / "AXIS.toml", "idle": _idle(demo), **kw})


def _detect(demo: Path) -> DetectJob:
    return DetectJob(method="vibration", axis_file=demo / "AXIS.toml", idle=_idle(demo), teeth=2)


def _items(*patterns) -> list[BatchInput]:
    return file_inputs(files_from_patterns([str(p) for p in patterns]))


def _outputs(out: Path, row: dict) -> list[Path]:
    return [out / rel for rel in row["outputs"].split(";") if rel]


def _mtimes(out: Path, rows) -> dict:
    return {f: f.stat().st_mtime_ns for r in rows for f in _outputs(out, r)}


def _result(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in RUN_COLUMNS}


def _assert_same_results(out_a: Path, rows_a, out_b: Path, rows_b) -> None:
    """Every row value (run columns aside) and every result file equal, bit for bit."""
    assert [_result(r) for r in rows_a] == [_result(r) for r in rows_b]
    for row in rows_a:
        for rel in filter(None, row["outputs"].split(";")):
            if rel.endswith(".nc"):
                a, b = read_recording(out_a / rel), read_recording(out_b / rel)
                assert a.channels == b.channels
                assert all(np.array_equal(a[c], b[c]) for c in a.channels), rel
            else:
                assert (out_a / rel).read_bytes() == (out_b / rel).read_bytes(), rel


def _archive(path: Path, recs) -> Path:
    from drivesense.archive import open_archive

    with open_archive(path) as store:
        for rec in recs:
            store.add(rec.with_meta(machine="vmc1"))
    return path


# ------------------------------------------------------------------------------------------------ keys
def test_task_key_is_stable_and_follows_content_not_path(demo, traces, tmp_path):
    job_hash = _estimate(demo).config_hash()
    twin = tmp_path / "elsewhere.nc"
    shutil.copy2(traces[0], twin)
    a, b, other, same_content = file_inputs([traces[0], traces[0], traces[1], twin])
    assert task_key(a, job_hash) == task_key(b, job_hash) == task_key(a, _estimate(demo).config_hash())
    assert len(task_key(a, job_hash)) == 32 and int(task_key(a, job_hash), 16) >= 0
    assert task_key(same_content, job_hash) == task_key(a, job_hash)
    assert task_key(other, job_hash) != task_key(a, job_hash)
    assert task_key(a, _estimate(demo, method="rigid").config_hash()) != task_key(a, job_hash)


def test_config_hash_follows_options_and_file_contents_not_paths(demo, tmp_path):
    base = _estimate(demo).config_hash()
    assert _estimate(demo).config_hash() == base                        # stable
    assert _estimate(demo, method="rigid").config_hash() != base
    assert _estimate(demo, idle=_idle(demo)[:1]).config_hash() != base
    moved = tmp_path / "moved" / "renamed.toml"
    moved.parent.mkdir()
    shutil.copy2(demo / "AXIS.toml", moved)
    assert _estimate(demo, axis_file=moved).config_hash() == base       # same content, another path
    changed = tmp_path / "AXIS.toml"
    changed.write_text((demo / "AXIS.toml").read_text() + "\n# edited\n")
    assert _estimate(demo, axis_file=changed).config_hash() != base     # another content, same name


def test_reader_options_left_at_their_defaults_do_not_change_the_hash(demo):
    base = _estimate(demo).config_hash()
    defaults = {"fs": None, "resample": None, "assume_si": False, "bad_samples": None}
    assert _estimate(demo, reader=defaults).config_hash() == base
    assert _estimate(demo, reader={**defaults, "assume_si": True}).config_hash() != base
    assert _estimate(demo, reader={**defaults, "bad_samples": "repair"}).config_hash() != base


def test_config_hash_refuses_a_missing_file_naming_its_option(demo, tmp_path):
    with pytest.raises(ConfigError, match="--idle"):
        _estimate(demo, idle=[tmp_path / "no_such_idle.nc"]).config_hash()


# ---------------------------------------------------------------------------------------------- serial
def test_serial_batch_writes_results_rows_and_summary_in_input_order(demo, traces, tmp_path):
    folder = _copies(traces[:3], tmp_path / "in")
    items = _items(folder)
    out = tmp_path / "out"
    report = run_batch(_estimate(demo), items, out, workers=0)
    assert (report.inputs, report.ran, report.skipped, report.failed, report.workers) == (3, 3, 0, 0, 0)
    assert [r["status"] for r in report.rows] == ["ok"] * 3
    for row in report.rows:
        (force,) = _outputs(out, row)
        assert force.parent == out / "results" and force.name.endswith(".force.nc") and force.exists()
        assert read_recording(force).n_samples == row["samples"] == 40000
        assert (out / "rows" / f"{row['key']}.json").exists()
    frame = pd.read_parquet(report.summary)
    assert report.summary == out / "summary.parquet"
    assert set(ROW_COLUMNS) <= set(frame.columns)
    assert list(frame["input"]) == [i.name for i in items] == [str(p) for p in sorted(folder.glob("*.nc"))]
    assert list(frame["key"]) == [r["key"] for r in report.rows]
    assert (frame["status"] == "ok").all() and (frame["error"] == "").all() and (frame["seconds"] >= 0).all()
    assert ((frame["cpu_seconds"] > 0) & (frame["cpu_seconds"] <= frame["seconds"] * 1.05 + 0.01)).all()


def test_rerun_runs_nothing_and_a_new_input_runs_alone(demo, traces, tmp_path):
    folder = _copies(traces[:3], tmp_path / "in")
    out = tmp_path / "out"
    first = run_batch(_estimate(demo), _items(folder), out, workers=0)
    stamps = _mtimes(out, first.rows)
    again = run_batch(_estimate(demo), _items(folder), out, workers=0)
    assert (again.ran, again.skipped, again.failed) == (0, 3, 0)
    assert again.rows == first.rows
    assert _mtimes(out, first.rows) == stamps                          # nothing rewritten
    shutil.copy2(traces[3], folder / "cut3.nc")
    more = run_batch(_estimate(demo), _items(folder), out, workers=0)
    assert (more.inputs, more.ran, more.skipped) == (4, 1, 3)
    assert _mtimes(out, first.rows) == stamps
    assert len(pd.read_parquet(more.summary)) == 4


def test_a_broken_input_gets_an_error_row_and_never_stops_the_batch(demo, traces, tmp_path):
    folder = _copies(traces[:2], tmp_path / "in")
    broken = folder / "broken.nc"
    broken.write_bytes(b"garbage bytes, not a netCDF file")
    out = tmp_path / "out"
    report = run_batch(_estimate(demo), _items(folder), out, workers=0)
    assert (report.ran, report.failed) == (3, 1)
    status = {r["input"]: r for r in report.rows}
    assert status[str(broken)]["status"] == "error" and status[str(broken)]["outputs"] == ""
    assert "broken.nc" in status[str(broken)]["error"]
    assert all(r["status"] == "ok" and r["error"] == "" for name, r in status.items() if name != str(broken))
    frame = pd.read_parquet(report.summary)
    assert list(frame["status"]) == [status[n]["status"] for n in frame["input"]] and len(frame) == 3
    again = run_batch(_estimate(demo), _items(folder), out, workers=0)
    assert (again.ran, again.skipped, again.failed) == (0, 3, 1)        # a failure is a row: done
    retried = run_batch(_estimate(demo), _items(folder), out, workers=0, retry_failed=True)
    assert (retried.ran, retried.skipped, retried.failed) == (1, 2, 1)


def test_a_deleted_row_makes_the_rerun_run_exactly_that_input(demo, traces, tmp_path):
    folder = _copies(traces[:3], tmp_path / "in")
    out = tmp_path / "out"
    first = run_batch(_estimate(demo), _items(folder), out, workers=0)
    gone = first.rows[1]
    keep = _mtimes(out, [first.rows[0], first.rows[2]])
    (out / "rows" / f"{gone['key']}.json").unlink()
    again = run_batch(_estimate(demo), _items(folder), out, workers=0)
    assert (again.ran, again.skipped) == (1, 2)
    assert (out / "rows" / f"{gone['key']}.json").exists()
    assert _result(again.rows[1]) == _result(gone)
    assert _mtimes(out, [first.rows[0], first.rows[2]]) == keep


def test_a_batch_without_inputs_or_with_negative_workers_is_refused(demo, traces, tmp_path):
    with pytest.raises(ConfigError, match="no input"):
        run_batch(_estimate(demo), [], tmp_path / "out", workers=0)
    with pytest.raises(ConfigError, match="--workers"):
        run_batch(_estimate(demo), _items(traces[0]), tmp_path / "out", workers=-1)
    with pytest.raises(ConfigError, match="matches no file"):
        files_from_patterns([str(tmp_path / "nothing*.nc")])


# -------------------------------------------------------------------------------------------- parallel
def test_two_workers_give_the_serial_results_bit_for_bit(demo, traces, tmp_path):
    """Estimate on a LocalCluster of two processes: rows and force arrays equal to the serial run's; a broken
    input fails there too."""
    folder = _copies(traces, tmp_path / "in")
    (folder / "broken.nc").write_bytes(b"garbage bytes, not a netCDF file")
    items = _items(folder)
    job = _estimate(demo)
    serial = run_batch(job, items, tmp_path / "serial", workers=0)
    parallel = run_batch(job, items, tmp_path / "parallel", workers=2)
    assert (parallel.ran, parallel.failed, parallel.workers) == (5, 1, 2)
    assert {r["worker"].rsplit(":", 1)[1] for r in parallel.rows}.isdisjoint({str(os.getpid())})
    _assert_same_results(tmp_path / "serial", serial.rows, tmp_path / "parallel", parallel.rows)
    assert pd.read_parquet(parallel.summary).drop(columns=list(RUN_COLUMNS)).equals(
        pd.read_parquet(serial.summary).drop(columns=list(RUN_COLUMNS)))


def test_a_client_of_your_own_runs_detect_bit_for_bit_and_stays_open(demo, traces, tmp_path):
    from distributed import Client

    from drivesense.fleet.batch import local_cluster

    items = _items(*traces)
    job = _detect(demo)
    serial = run_batch(job, items, tmp_path / "serial", workers=0)
    assert sum(r["events"] for r in serial.rows) == 1
    with local_cluster(2, dashboard=False) as cluster, Client(cluster) as client:
        parallel = run_batch(job, items, tmp_path / "parallel", client=client)
        assert client.submit(sum, [1, 2]).result() == 3                 # the caller's client is left open
    assert (parallel.ran, parallel.failed, parallel.workers) == (4, 0, 2)
    _assert_same_results(tmp_path / "serial", serial.rows, tmp_path / "parallel", parallel.rows)


def test_an_edited_csv_sidecar_makes_the_result_stale(demo, cuts, tmp_path):
    from drivesense.io import write_csv
    from drivesense.io.csv import sidecar_path

    trace = write_csv(cuts[0], tmp_path / "cut.csv")
    out = tmp_path / "out"
    first = run_batch(_estimate(demo), _items(trace), out, workers=0)
    side = sidecar_path(trace)
    meta = json.loads(side.read_text())
    meta["score_window"] = [3.0, 4.0]
    side.write_text(json.dumps(meta))
    fresh = run_batch(_estimate(demo), _items(trace), tmp_path / "fresh", workers=0)
    assert fresh.rows[0]["score_rmse_n"] != first.rows[0]["score_rmse_n"]     # the sidecar changes the result
    again = run_batch(_estimate(demo), _items(trace), out, workers=0)
    assert again.ran == 1


# --------------------------------------------------------------------------------------------- archive
def test_archived_inputs_get_their_force_estimate_archived_once(demo, cuts, tmp_path):
    from drivesense.archive import open_archive

    archive = _archive(tmp_path / "a.sqlite", cuts[:2])
    items = archive_inputs(str(archive))
    assert len(items) == 2 and all(i.machine == "vmc1" and i.name.startswith("archive:") for i in items)
    job = _estimate(demo)
    report = run_batch(job, items, tmp_path / "out", workers=0)
    assert (report.ran, report.failed, report.archived) == (2, 0, 2)
    with open_archive(archive, create=False) as store:
        assert store.count() == 4
        derived = {h.id for h in store.search(None, limit=10)} - {i.experiment for i in items}
        assert sorted(d.split("-estimate-")[0] for d in derived) == sorted(i.experiment for i in items)
        for row, item in zip(report.rows, items):
            exp_id = f"{item.experiment}-estimate-{row['key'][:12]}"
            archived = store.load(exp_id).recordings[0]
            written = read_recording(_outputs(tmp_path / "out", row)[0])
            assert np.array_equal(archived["force_x"], written["force_x"])
    again = run_batch(job, items, tmp_path / "out", workers=0)
    assert (again.ran, again.archived) == (0, 0)
    with open_archive(archive, create=False) as store:
        assert store.count() == 4


def test_an_archived_estimate_names_its_source_and_machine(demo, cuts, tmp_path):
    from drivesense.archive import open_archive

    archive = _archive(tmp_path / "a.sqlite", cuts[:1])
    (item,) = archive_inputs(str(archive))
    report = run_batch(_estimate(demo), [item], tmp_path / "out", workers=0)
    with open_archive(archive, create=False) as store:
        meta = store.load(f"{item.experiment}-estimate-{report.rows[0]['key'][:12]}").recordings[0].meta
        machines = {h.id: h.machine for h in store.search(None, machine="vmc1", limit=10)}
    assert meta.get("derived_from") == item.experiment and meta.get("batch_key") == report.rows[0]["key"]
    assert len(machines) == 2


def test_rerunning_an_archive_query_does_not_take_its_own_results_as_inputs(demo, cuts, tmp_path):
    archive = _archive(tmp_path / "a.sqlite", cuts[:2])
    run_batch(_estimate(demo), archive_inputs(str(archive)), tmp_path / "out", workers=0)
    again = run_batch(_estimate(demo), archive_inputs(str(archive)), tmp_path / "out", workers=0)
    assert (again.inputs, again.ran, again.failed) == (2, 0, 0)


def test_archived_inputs_get_their_detected_events_archived_once(demo, cuts, tmp_path):
    from drivesense.archive import open_archive

    archive = _archive(tmp_path / "a.sqlite", cuts[:2])
    items = archive_inputs(str(archive))
    out = tmp_path / "out"
    report = run_batch(_detect(demo), items, out, workers=0)
    found = [e for r in report.rows for e in json.loads(_outputs(out, r)[0].read_text())["events"]]
    assert [e["kind"] for e in found] == ["breakage"]                  # the second cut's flute
    assert report.archived == len(found) == sum(r["events"] for r in report.rows)
    with open_archive(archive, create=False) as store:
        events = store.events()
    assert [(e["kind"], e["machine"]) for e in events] == [("breakage", "vmc1")]
    assert events[0]["source_experiment"] == items[1].experiment
    assert math.isclose(events[0]["time_s"], found[0]["time_s"])
    again = run_batch(_detect(demo), items, out, workers=0)
    assert (again.ran, again.archived) == (0, 0)
    with open_archive(archive, create=False) as store:
        assert len(store.events()) == 1


# ------------------------------------------------------------------------------------------------- CLI
def _base(demo: Path, out: Path) -> list:
    return ["--axis", demo / "AXIS.toml", *(a for p in _idle(demo) for a in ("--idle", p)), "--out", out]


def _strict_json(path: Path) -> dict:
    def refuse(name):
        raise ValueError(f"not strict JSON: {name}")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_cli_batch_estimate_writes_a_strict_json_report(demo, traces, tmp_path):
    folder = _copies(traces[:2], tmp_path / "in")
    out, report = tmp_path / "out", tmp_path / "report.json"
    res = invoke("batch", "estimate", folder, *_base(demo, out), "--workers", "0", "--json", report)
    assert res.exit_code == 0, res.output
    first = _strict_json(report)
    assert (first["job"], first["inputs"], first["ran"], first["failed"], first["workers"]) == ("estimate", 2, 2, 0, 0)
    assert len(pd.read_parquet(first["summary"])) == 2
    res = invoke("batch", "estimate", folder, *_base(demo, out), "--workers", "0", "--json", report)
    assert res.exit_code == 0, res.output
    assert (_strict_json(report)["ran"], _strict_json(report)["skipped"]) == (0, 2)



def test_cli_batch_with_a_failing_input_runs_through_and_exits_1(demo, traces, tmp_path):
    folder = _copies(traces[:1], tmp_path / "in")
    (folder / "broken.nc").write_bytes(b"garbage bytes, not a netCDF file")
    out, report = tmp_path / "out", tmp_path / "report.json"
    res = invoke("batch", "estimate", folder, *_base(demo, out), "--workers", "0", "--json", report)
    assert res.exit_code == 1 and "Traceback" not in res.output, res.output
    assert "failed: " in res.output and "broken.nc" in res.output
    done = _strict_json(report)
    assert (done["inputs"], done["ran"], done["failed"]) == (2, 2, 1)
    assert list(pd.read_parquet(done["summary"])["status"]) == ["error", "ok"]

@pytest.mark.parametrize("args, words", [
    ([], "neither"),
    (["IN", "--query", "steel"], "--archive"),
    (["NOTHING"], "matches no file"),
    (["IN", "--workers", "-1"], "--workers must be >= 0"),
])
def test_cli_batch_refuses_bad_usage_in_one_line(demo, traces, tmp_path, args, words):
    subs = {"IN": traces[0], "NOTHING": tmp_path / "nothing*.nc"}
    res = invoke("batch", "estimate", *(subs.get(a, a) for a in args), *_base(demo, tmp_path / "out"),
                 *([] if "--workers" in args else ["--workers", "0"]))
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and words in errors[0], res.output
    assert res.output.rstrip().endswith(errors[0])


# ------------------------------------------------------------------------------------------ wear, identify
@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> list[Path]:
    """Two simulated tool lives (Table 1 experiment A, seeds 0 and 1) as session CSVs."""
    folder = tmp_path_factory.mktemp("sessions")
    for seed in (0, 1):
        res = invoke("wear", "simulate", "A", "--seed", seed, "--out", folder / f"life{seed}.csv")
        assert res.exit_code == 0, res.output
    return sorted(folder.glob("*.csv"))


def test_batch_wear_tracks_every_session_table(sessions, tmp_path):
    out, report = tmp_path / "out", tmp_path / "report.json"
    res = invoke("batch", "wear", *sessions, "--out", out, "--workers", "0", "--json", report)
    assert res.exit_code == 0, res.output
    assert (_strict_json(report)["ran"], _strict_json(report)["failed"]) == (2, 0)
    frame = pd.read_parquet(out / "summary.parquet")
    assert list(frame["input"]) == [str(s) for s in sessions]
    assert (frame["status"] == "ok").all() and (frame["calibrations"] > 0).all()
    assert frame["state"].map(lambda s: isinstance(s, str) and s != "").all()
    for outputs in frame["outputs"]:
        assert outputs.endswith(".wear.json") and (out / outputs).exists()
        history = json.loads((out / outputs).read_text())
        assert isinstance(history, dict) and history


def test_inputs_of_equal_content_run_once_and_share_the_row(sessions, tmp_path):
    twin = tmp_path / "copy_of_life0.csv"
    shutil.copy2(sessions[0], twin)
    side = Path(f"{sessions[0]}.json")
    if side.exists():                                  # the sidecar is part of a CSV's content
        shutil.copy2(side, Path(f"{twin}.json"))
    items = file_inputs([sessions[0], twin, sessions[1]])
    report = run_batch(WearJob(), items, tmp_path / "out", workers=0)
    assert (report.inputs, report.ran, report.skipped) == (3, 2, 0)
    assert [r["input"] for r in report.rows] == [str(sessions[0]), str(twin), str(sessions[1])]
    assert report.rows[0]["key"] == report.rows[1]["key"] != report.rows[2]["key"]
    assert _result({**report.rows[0], "input": ""}) == _result({**report.rows[1], "input": ""})
    assert list(pd.read_parquet(report.summary)["input"]) == [r["input"] for r in report.rows]


def test_identify_refuses_to_fit_without_the_catalogue_values():
    with pytest.raises(ConfigError, match="--fix") as caught:
        IdentifyJob(fix={}).prepare()
    assert isinstance(caught.value, ValueError) and "K_t" in str(caught.value) and "lead" in str(caught.value)
    with pytest.raises(ConfigError, match="--fix must give lead"):
        IdentifyJob(fix={"K_t": 0.45}).prepare()
    IdentifyJob(fix={"K_t": 0.45, "lead": 0.005}).prepare()


def test_batch_identify_fits_the_simulated_axis(tmp_path):
    from drivesense.io.axis_file import read_axis_file
    from drivesense.sim.scenarios import simulate_frf_excitation

    rec = simulate_frf_excitation("multisine", seed=2)
    true = rec.meta["true_axis"]
    path = write_recording(rec, tmp_path / "excitation.nc")
    job = IdentifyJob(fix={"K_t": true["K_t"], "lead": true["lead"]})
    report = run_batch(job, file_inputs([path]), tmp_path / "out", workers=0)
    (row,) = report.rows
    assert row["status"] == "ok", row["error"]
    for p in ("J_r", "M_t", "K_r"):
        assert row[p] == pytest.approx(true[p], rel=0.02), p
    axis_toml, frf_json = _outputs(tmp_path / "out", row)
    assert axis_toml.name.endswith(".axis.toml") and frf_json.name.endswith(".frf.json")
    assert read_axis_file(axis_toml)[0].J_r == pytest.approx(row["J_r"])
    assert "seconds" not in json.loads(frf_json.read_text())          # only reproducible values
