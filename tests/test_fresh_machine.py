"""What a first try on a fresh machine found: lost errors, silent wrong results, messages that mislead.

Each test is one item of that report: the HTTP server's errors reach the command line, ``--speed`` is checked
before any work, output formats follow the suffix, a method refuses a rate that cannot resolve what it
models, machine ids work in every route, user text is never turned into markup or emoji, and CI's own
rules (declared dependencies, no skips under ``CI=true``) hold.
"""

from __future__ import annotations

import socket
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, SampleRateError
from drivesense.io import read_recording, write_recording
from drivesense.recording import Recording
from cli_checks import one_line_error
from servers import run_until_cuts

runner = CliRunner()
ROOT = Path(__file__).resolve().parent.parent


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])



def decimated(rec: Recording, factor: int) -> Recording:
    """Every `factor`-th sample, as a controller trace at a low rate records it."""
    return Recording.from_arrays({c: rec[c][::factor] for c in rec.channels}, fs=rec.fs / factor, t0=rec.t0,
                                 meta=dict(rec.meta))


@pytest.fixture(scope="module")
def feed_files(tmp_path_factory, paper_scenario):
    """The feed-direction cut, its idle runs and the Table 1 axis file, written as a user would have them."""
    folder = tmp_path_factory.mktemp("feed")
    scen = paper_scenario("feed_r6_S1000")
    write_recording(scen.cut, folder / "cut.nc")
    idle = []
    for i, run in enumerate(scen.idle):
        write_recording(run, folder / f"idle{i}.nc")
        idle += ["--idle", folder / f"idle{i}.nc"]
    assert invoke("axis", "--out", folder / "axis.toml").exit_code == 0
    return folder, idle, scen


# ------------------------------------------------------------------ dependencies and CI
def test_the_monitor_extra_declares_the_websocket_library():
    """Without a WebSocket library uvicorn answers /ws with 404 and the dashboard stays empty."""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for extra in ("monitor", "test"):
        names = {d.split(">")[0].split("=")[0].split("[")[0].strip().lower() for d in extras[extra]}
        assert "websockets" in names, extra


def test_ci_runs_the_readme_test_command_in_a_new_environment():
    ci = (ROOT / ".ci" / "run").read_text()
    assert "scripts/test --fresh" in ci
    script = (ROOT / "scripts" / "test").read_text()
    assert "python3 -m venv" in script and "torch==2.13.0" in script and '".[test]"' in script
    readme = (ROOT / "README.md").read_text()
    assert "bash scripts/test" in readme


def test_a_skip_under_ci_is_a_failure(pytester, monkeypatch):
    """``CI=true``: a test that would skip (no browser, broker, database or package) fails the run."""
    pytester.copy_example(str(ROOT / "tests" / "conftest.py"))
    pytester.makepyfile(test_skips="import pytest\n\ndef test_needs_a_server():\n    pytest.skip('no server')\n")
    with monkeypatch.context() as env:                 # (CI's own CI=true is restored afterwards)
        env.setenv("CI", "true")
        result = pytester.runpytest_inprocess("-q", "-p", "no:cacheprovider")
        assert result.ret != 0
        result.stdout.fnmatch_lines(["*CI=true: 1 test(s) skipped*no server*"])
        env.delenv("CI")
        assert pytester.runpytest_inprocess("-q", "-p", "no:cacheprovider").ret == 0   # elsewhere a skip is fine


# ------------------------------------------------------------------ the live monitor
def test_a_dashboard_port_in_use_stops_the_monitor_before_any_work():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        res = invoke("monitor", "--demo", "--http", f"127.0.0.1:{port}", "--duration", "1")
    one_line_error(res, f"--http 127.0.0.1:{port}", "cannot listen")
    assert "dashboard:" not in res.output and "simulating" not in res.output


def test_an_http_server_failing_while_running_reaches_the_command(monkeypatch):
    """A failure of the dashboard server after the start ends the command with its message, not exit 0."""
    import drivesense.monitor.web as web

    async def broken(service, host, port, stop, *, sock=None):
        stop.set()
        raise ConfigError(f"--http {host}:{port}: the dashboard server did not start")

    monkeypatch.setattr(web, "serve_http", broken)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    res = invoke("monitor", "--demo", "--http", f"127.0.0.1:{port}", "--duration", "5")
    one_line_error(res, "did not start")


@pytest.mark.parametrize("args", [("monitor", "--demo"), ("monitor", "--replay", "nothing.csv"),
                                  ("publish", "nothing.csv", "--mqtt", "mqtt://127.0.0.1:1")])
def test_speed_is_checked_before_any_work_in_every_mode(args):
    for bad in ("-5", "nan"):
        res = invoke(*args, "--speed", bad)
        one_line_error(res, "--speed must be >= 0")
        assert "simulating" not in res.output


def test_a_config_with_a_negative_source_speed_is_refused(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[machine]]\nid = "m1"\nsource = {kind = "simulated", speed = -1}\n')
    one_line_error(invoke("monitor", cfg), "source speed must be >= 0")


def test_machine_ids_that_would_break_routes_and_event_ids_are_refused(tmp_path):
    from drivesense.monitor.service import check_machine_id, machine_id_from

    for bad in ("a/b", "", " m1", "m1?", "m#1", "m+1", "é", "-m", "x" * 65):
        with pytest.raises(ConfigError, match="letters, digits"):
            check_machine_id(bad)
    for good in ("m1", "Mill-7.a_b", "0", "x" * 64):
        assert check_machine_id(good) == good
    assert machine_id_from("cut 1 (night)") == "cut_1__night_"
    assert machine_id_from("???") == "machine"
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[machine]]\nid = "hall2/m1"\nsource = {kind = "simulated"}\n')
    one_line_error(invoke("monitor", cfg), "'hall2/m1'", "[[machine]] id")


def test_every_route_works_for_an_accepted_machine_id():
    pytest.importorskip("fastapi")
    from fastapi.testclient import TestClient

    from drivesense.monitor.demo import demo_machine
    from drivesense.monitor.service import MonitorService
    from drivesense.monitor.web import create_app

    mid = "Mill-7.a_b"
    spec = demo_machine(mid, speed=0, cut_s=3.0)
    svc = MonitorService([spec], token="t")
    run_until_cuts(svc, spec, 2)
    with TestClient(create_app(svc)) as client:
        assert client.get(f"/api/machines/{mid}/force?seconds=1").status_code == 200
        assert client.get(f"/api/machines/{mid}/spectrum?axis=x").status_code == 200
        events = client.get("/api/events").json()
        assert events and all(e["machine"] == mid and e["id"].split("/")[0] == mid for e in events)
        ack = client.post(f"/api/events/{events[0]['id']}/ack", headers={"Authorization": "Bearer t"}, json={})
        assert ack.status_code == 200, ack.text
        limits = client.put(f"/api/machines/{mid}/limits", headers={"Authorization": "Bearer t"},
                            json={"axis": "x", "force_limit_n": 400})
        assert limits.status_code == 200, limits.text


def test_a_typo_in_the_service_section_lists_the_known_keys(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[service]\nhtpp = "127.0.0.1:8765"\n\n[[machine]]\nid = "m1"\nsource = {kind = "simulated"}\n')
    line = one_line_error(invoke("monitor", cfg), "unknown key(s) htpp", "known:")
    assert "http" in line.split("known:")[1] and "events" in line.split("known:")[1]


# ------------------------------------------------------------------ estimate
def test_estimate_output_follows_the_suffix(feed_files):
    folder, idle, scen = feed_files
    out = folder / "force.nc"
    res = invoke("estimate", folder / "cut.nc", "--axis", folder / "axis.toml", "--method", "rigid", *idle,
                 "--out", out)
    assert res.exit_code == 0, res.output
    force = read_recording(out)                               # netCDF, not CSV text under a .nc name
    assert out.read_bytes()[:4] in (b"\x89HDF", b"CDF\x01", b"CDF\x02")
    assert force.fs == scen.cut.fs and "force_x" in force.channels
    res = invoke("estimate", folder / "cut.nc", "--axis", folder / "axis.toml", *idle, "--out", folder / "f.txt")
    one_line_error(res, "--out", "f.txt", ".nc", ".csv")
    assert not (folder / "f.txt").exists()


def test_a_rate_that_cannot_resolve_the_vibration_mode_is_refused(feed_files):
    """50 Hz: the 411 Hz mode of Table 1 is far above Nyquist; the answer would be wrong even in sign."""
    import dataclasses

    import drivesense as ds

    folder, idle, scen = feed_files
    slow = decimated(scen.cut, 200)
    write_recording(slow, folder / "cut50.nc")
    axis = ds.table1_axis()
    signal = dataclasses.replace(ds.estimate.make("vibration", axis=axis).signal, lpf_hz=10.0)
    for method in ("vibration", "medob"):
        est = ds.estimate.make(method, axis=axis, signal=signal)
        with pytest.raises(SampleRateError, match="411 Hz") as err:
            est.estimate(slow)
        assert "identify nc" in str(err.value) and "--method model" in str(err.value)
    for method in ("current", "rigid"):                     # they do not model the mode: no refusal for it
        ds.estimate.make(method, axis=axis, signal=signal).check_rate(slow.fs)
    with pytest.raises(SampleRateError):                       # 2x the mode frequency is the least rate
        ds.estimate.make("vibration", axis=axis).check_rate(2 * axis.natural_frequency_hz * 0.99)
    ds.estimate.make("vibration", axis=axis).check_rate(10_000.0)
    res = invoke("estimate", folder / "cut50.nc", "--axis", folder / "axis.toml", "--method", "vibration",
                 "--out", folder / "f50.csv")
    one_line_error(res, "--method vibration", "vibration mode", "identify nc", "--method model")


def test_user_text_is_never_read_as_markup_or_emoji(feed_files):
    """``START:END`` once printed as ``START🔚``; ``[mm]`` would vanish as a markup tag."""
    folder, idle, scen = feed_files
    res = invoke("estimate", folder / "cut.nc", "--axis", folder / "axis.toml", "--method", "rigid",
                 "--out", folder / "raw.csv")
    assert res.exit_code == 0, res.output
    assert "--tare START:END" in res.output and "\U0001f51a" not in res.output
    from drivesense.cli.common import console, err_console

    with console.capture() as cap:
        console.print("window :end: and :smile:")
    assert cap.get().strip() == "window :end: and :smile:"
    with err_console.capture() as cap:
        err_console.print(":end:")
    assert cap.get().strip() == ":end:"
    assert np.isfinite(read_recording(folder / "raw.csv")["force_x"]).all()


def test_acknowledging_an_alarm_twice_keeps_the_first_acknowledgement(tmp_path):
    from drivesense.monitor.outputs import EventLog

    log = EventLog(tmp_path / "events.jsonl")
    log.append({"id": "m1/breakage/x/1", "machine": "m1", "kind": "breakage", "axis": "x", "time_s": 1.0,
                "detected": 0.0})
    first = log.acknowledge("m1/breakage/x/1", "night shift")
    again = log.acknowledge("m1/breakage/x/1", "someone else")
    assert again == first and again["by"] == "night shift"
    log.close()
    lines = (tmp_path / "events.jsonl").read_text().splitlines()
    assert sum('"ack"' in line for line in lines) == 1
