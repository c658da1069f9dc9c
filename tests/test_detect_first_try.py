"""``drivesense detect`` as a first-time user meets it: a breakage in a CSV trace that names no tool, a 50 Hz
trace, a negative force limit, the output it prints, and the plot it draws.

The tooth count is read from the force when nobody gives it (:mod:`drivesense.events.teeth`): here on
closed-form tooth pulses (known count, runout, spindle speed, a spindle ramp), on simulated cuts of the
ball-screw stage through the vibration estimator (2-6 teeth, 1000-10 000 min^-1, runout), and on traces
where it must refuse (no cut, noise, a line between the orders, one pulse per revolution, too short, no
spindle speed, a feed drive's current alone).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, SignalTooShortError
from drivesense.estimate.registry import make_from_files
from drivesense.io import write_csv
from drivesense.machine.milling import EndMill
from drivesense.events.chatter import ChatterDetector
from drivesense.events.pipeline import detect_in_trace, detector_inputs, run_detectors, tool_teeth
from drivesense.events.teeth import TEETH_SOURCES, infer_teeth, resolve_teeth
from drivesense.recording import Recording
from drivesense.sim.process_events import ProcessEvent, simulate_event_cut
from drivesense.sim.scenarios import CutCondition, ScenarioSettings, simulate_idle

runner = CliRunner()
MM = {"x_table_position": "mm", "y_table_position": "mm"}
FS = 10_000.0
INFERRED = TEETH_SOURCES[2]


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


# ============================================================================ closed-form tooth pulses
def _milling(z: int, rpm, *, seconds: float = 2.0, runout: float = 0.0, width: float = 0.12,
             air_s: float = 0.3, noise: float = 0.02, seed: int = 0) -> Recording:
    """A force of ``z`` equally spaced half-sine tooth pulses (``width`` of a revolution each), tooth ``j``
    at ``1 + runout cos(2 pi j / z + 0.4)``, after ``air_s`` of air; ``rpm`` a number or one per sample."""
    t = np.arange(int(seconds * FS)) / FS
    rpm = np.broadcast_to(np.asarray(rpm, dtype=float), t.shape)
    omega = rpm * 2 * math.pi / 60.0
    theta = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / FS)])
    span = 2 * math.pi * width
    force = np.zeros_like(t)
    for j in range(z):
        phase = np.mod(theta - 2 * math.pi * j / z, 2 * math.pi)
        force += np.where(phase < span, np.sin(math.pi * phase / span), 0.0) * (1 + runout * math.cos(
            2 * math.pi * j / z + 0.4))
    force = 40.0 * force * (t >= air_s) + np.random.default_rng(seed).normal(0.0, noise, t.size)
    return Recording.from_arrays({"force_x": force, "spindle_speed": omega}, fs=FS)


@pytest.mark.parametrize("z", [2, 3, 4, 6])
@pytest.mark.parametrize("rpm", [1500.0, 6000.0, 12_000.0])
@pytest.mark.parametrize("runout", [0.0, 0.5])
def test_the_tooth_count_is_read_from_the_tooth_passing_line(z, rpm, runout):
    choice = infer_teeth(_milling(z, rpm, runout=runout, seed=z))
    assert choice.teeth == z, choice.reason
    ev = choice.evidence
    assert choice.source == INFERRED and ev["channel"] == "force_x"
    assert ev["spindle_hz"] == pytest.approx(rpm / 60.0, rel=1e-3)
    assert ev["tooth_passing_hz"] == pytest.approx(z * rpm / 60.0, rel=1e-3)
    assert ev["line_to_floor"] >= 10 and ev["pitch_share"] >= 0.75
    assert len(ev["order_amplitudes"]) == 16 and ev["channels"] == {"force_x": z}


def test_a_spindle_ramp_keeps_the_orders_in_place():
    ramp = np.linspace(3000.0, 4500.0, int(3.0 * FS))
    choice = infer_teeth(_milling(3, ramp, seconds=3.0, runout=0.3))
    assert choice.teeth == 3, choice.reason
    assert 3000 / 60 < choice.evidence["spindle_hz"] < 4500 / 60


def test_a_fixed_spindle_speed_serves_a_trace_without_the_channel():
    rec = _milling(4, 3000.0)
    bare = Recording.from_arrays({"force_x": rec["force_x"]}, fs=FS)
    refused = infer_teeth(bare)
    assert refused.teeth is None and "--spindle-rpm" in refused.reason
    assert infer_teeth(bare, spindle_rpm=3000.0).teeth == 4


@pytest.mark.parametrize("case, words", [
    ("noise", "the noise between the orders"),
    ("tone between the orders", "no clear tooth-passing line"),
    ("one pulse per revolution", "the spindle frequency itself"),
    ("too short", "revolution(s) of cutting"),
    ("slow trace", "orders up to"),
])
def test_no_clear_line_is_refused_not_guessed(case, words):
    if case == "noise":
        rec = _milling(2, 3000.0, noise=0.0)                 # a noise that starts with the 'cut'
        rec = Recording.from_arrays({"force_x": np.random.default_rng(1).normal(0.0, 5.0, rec.n_samples)
                                     * np.where(rec.time > 0.3, 1.0, 0.05), "spindle_speed": rec["spindle_speed"]},
                                    fs=FS)
    elif case == "tone between the orders":        # a chatter-like line at 3.4 x the spindle frequency
        rec = _milling(2, 3000.0, noise=0.0)
        t = rec.time
        rec = Recording.from_arrays({"force_x": 30 * np.sin(2 * math.pi * 3.4 * 50.0 * t) * (t > 0.3)
                                     + np.random.default_rng(2).normal(0.0, 0.05, t.size),
                                     "spindle_speed": rec["spindle_speed"]}, fs=FS)
    elif case == "one pulse per revolution":
        rec = _milling(1, 3000.0)
    elif case == "too short":
        rec = _milling(2, 3000.0, seconds=0.5)       # 10 revolutions of cutting
    else:                                            # 12 000 min^-1 logged at 1 kHz: orders 1-2 only
        fast = _milling(4, 12_000.0)
        rec = Recording.from_arrays({c: fast[c][::10] for c in fast.channels}, fs=FS / 10)
    choice = infer_teeth(rec)
    assert choice.teeth is None and choice.source == INFERRED
    assert words in choice.reason, choice.reason
    assert "--teeth N turns it on" in choice.note and "breakage/chipping detection is off" in choice.note
    assert choice.to_json()["teeth"] is None and choice.to_json()["teeth_unknown"] == choice.reason


def test_a_feed_drives_current_alone_names_no_count():
    """A drive's response can lift a runout line above the tooth-passing one: without a force (or the
    spindle's power) to show the same line, the current is not enough."""
    rec = _milling(2, 3000.0)
    current = Recording.from_arrays({"x_current": rec["force_x"] / 50.0, "spindle_speed": rec["spindle_speed"]},
                                    fs=FS)
    choice = infer_teeth(current)
    assert choice.teeth is None and "feed drive's current alone" in choice.reason
    spindle = Recording.from_arrays({"spindle_power": 5 * rec["force_x"] + 300.0,
                                     "spindle_speed": rec["spindle_speed"]}, fs=FS)
    assert infer_teeth(spindle).teeth == 2


def test_teeth_come_from_the_option_the_tool_then_the_spectrum():
    rec = _milling(3, 3000.0)
    assert resolve_teeth(rec, 5).teeth == 5 and resolve_teeth(rec, 5).source == "--teeth"
    named = rec.with_meta(tool={"flutes": 4, "diameter_m": 6e-3})
    assert (resolve_teeth(named).teeth, resolve_teeth(named).source) == (4, "tool metadata")
    assert (resolve_teeth(rec).teeth, resolve_teeth(rec).source) == (3, INFERRED)
    assert tool_teeth(rec, None) == 3 and tool_teeth(named, None) == 4 and tool_teeth(rec, 2) == 2
    assert resolve_teeth(named).to_json() == {"teeth": 4, "teeth_source": "tool metadata"}


# ============================================================================ simulated cuts, estimated force
SETTINGS = replace(ScenarioSettings(), duration=3.5, t_contact=0.5)
FEED = 4e-3


@pytest.fixture(scope="module")
def estimator(tmp_path_factory):
    axis = tmp_path_factory.mktemp("axis") / "axis.toml"
    assert invoke("axis", "--out", axis).exit_code == 0
    est = make_from_files("vibration", axis_file=axis, axis_name="x")
    cond = CutCondition("idle", "feed", 1.5e-3, 4000.0, feed_speed=FEED, axial_depth=1e-3)
    est.fit(simulate_idle(cond, replace(SETTINGS, duration=3.7), repeats=2, seed=50))
    return est


@pytest.mark.parametrize("z, rpm, runout_um, radial_mm, mode", [
    (2, 1000.0, 2.0, 1.5, "down"),
    (2, 10_000.0, 2.0, 6.0, "down"),
    (3, 4000.0, 5.0, 0.5, "up"),
    (4, 2500.0, 2.0, 1.5, "down"),
    (4, 10_000.0, 0.0, 0.5, "up"),
    (6, 4000.0, 2.0, 1.5, "down"),
])
def test_simulated_cuts_through_the_estimator(estimator, z, rpm, runout_um, radial_mm, mode):
    cond = CutCondition("t", "feed", radial_mm * 1e-3, rpm, feed_speed=FEED, axial_depth=1e-3, mode=mode)
    tool = EndMill(6e-3, z, 30.0, runout=runout_um * 1e-6, runout_phase=0.4)
    rec = simulate_event_cut(cond, settings=replace(SETTINGS, tool=tool), seed=z + int(rpm))
    inputs = detector_inputs(rec, estimator.estimate(rec))
    choice = infer_teeth(rec, inputs, band_hz=estimator.signal.lpf_hz)
    assert choice.teeth == z, choice.reason
    assert choice.evidence["tooth_passing_hz"] == pytest.approx(z * rpm / 60.0, rel=0.01)


def test_an_air_cut_is_refused(estimator):
    cond = CutCondition("idle", "feed", 1.5e-3, 4000.0, feed_speed=FEED, axial_depth=1e-3)
    idle = simulate_idle(cond, SETTINGS, repeats=1, seed=77)[0]
    choice = infer_teeth(idle, detector_inputs(idle, estimator.estimate(idle)), band_hz=estimator.signal.lpf_hz)
    assert choice.teeth is None and choice.reason


# ============================================================================ the CLI, as the user met it
@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A 2-flute cut at 4000 min^-1 with 2 um runout and 11 um per tooth (runout lines almost as strong as the
    tooth-passing one) that breaks a tooth at 3.3 s, as a CSV in mm without its metadata sidecar (the tool is
    not named); two idle runs; the same stage idling as a 'trace' with no cut at all."""
    d = tmp_path_factory.mktemp("first_try")
    assert invoke("axis", "--out", d / "axis.toml").exit_code == 0
    cond = CutCondition("t", "feed", 1.5e-3, 4000.0, feed_speed=1.5e-3, axial_depth=1e-3)
    settings = replace(ScenarioSettings(), duration=4.5, t_contact=0.5)
    rec = simulate_event_cut(cond, events=(ProcessEvent("breakage", 3.3, flute=1),), settings=settings, seed=3)
    write_csv(rec, d / "broken.csv", units=MM)
    (d / "broken.csv.json").unlink()
    for k, idle in enumerate(simulate_idle(cond, replace(settings, duration=4.7), repeats=3, seed=50)):
        write_csv(idle, d / f"idle{k}.csv", units=MM)
    (d / "idle2.csv.json").unlink()
    return d


def _detect(work: Path, trace: str, *extra):
    return invoke("detect", work / trace, "--axis", work / "axis.toml", "--idle", work / "idle0.csv",
                  "--idle", work / "idle1.csv", *extra)


def test_a_breakage_is_found_without_teeth_given(work):
    res = _detect(work, "broken.csv", "--json", work / "broken.json")
    assert res.exit_code == 0, res.output
    doc = json.loads((work / "broken.json").read_text())
    assert doc["events"] and doc["events"][0]["kind"] == "breakage"
    assert 3.3 < doc["events"][0]["time_s"] < 3.3 + 2 * 60 / 4000.0
    assert doc["detectors"] == ["breakage", "chatter"]
    assert (doc["teeth"], doc["teeth_source"]) == (2, INFERRED) and "notes" not in doc
    ev = doc["teeth_evidence"]
    assert ev["tooth_passing_hz"] == pytest.approx(2 * 4000 / 60.0, rel=1e-3) and ev["teeth"] == 2
    assert "warning" not in res.stderr
    assert "teeth: 2 (inferred from the spectrum" in res.stdout
    assert res.stdout.count("wrote ") == 1 and "broken.json" in res.stdout          # said once


def test_teeth_that_cannot_be_read_say_so_and_how_to_turn_breakage_on(work):
    res = _detect(work, "idle2.csv", "--json", work / "air.json")
    assert res.exit_code == 0, res.output
    warning = [line for line in res.stderr.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and "breakage/chipping detection is off" in warning[0] and "--teeth N" in warning[0]
    doc = json.loads((work / "air.json").read_text())
    assert doc["teeth"] is None and doc["teeth_unknown"] and doc["detectors"] == ["chatter"]
    assert doc["notes"] == [warning[0].removeprefix("warning: ")]


def test_a_negative_force_limit_is_refused_before_any_work(work, tmp_path):
    missing = tmp_path / "not_there.csv"
    for args in (("detect", missing, "--axis", work / "axis.toml", "--json", tmp_path / "e.json"),
                 ("batch", "detect", work / "broken.csv", "--axis", work / "axis.toml", "--out", tmp_path / "b",
                  "--workers", 0)):
        res = invoke(*args, "--force-limit", -5)
        assert res.exit_code == 2, res.output
        assert res.output.strip() == "error: --force-limit must be > 0 [N], got -5.0"
        assert not (tmp_path / "b").exists()
    res = invoke("monitor", "--replay", work / "broken.csv", "--axis", work / "axis.toml", "--idle",
                 work / "idle0.csv", "--force-limit", -5)
    assert res.exit_code == 2 and "error: --force-limit must be > 0 [N], got -5.0" in res.output, res.output
    assert "limit_n" not in res.output and "force_limit" not in res.output


def test_batch_detect_reads_the_teeth_too(work, tmp_path):
    res = invoke("batch", "detect", work / "broken.csv", work / "idle2.csv", "--axis", work / "axis.toml", "--idle",
                 work / "idle0.csv", "--idle", work / "idle1.csv", "--out", tmp_path / "b", "--workers", 0)
    assert res.exit_code == 0, res.output
    docs = {p.name.split("-")[0]: json.loads(p.read_text()) for p in (tmp_path / "b").rglob("*.events.json")}
    assert (docs["broken"]["teeth"], docs["broken"]["teeth_source"]) == (2, INFERRED)
    assert docs["broken"]["events"][0]["kind"] == "breakage"
    assert docs["idle2"]["teeth"] is None and "--teeth N turns it on" in docs["idle2"]["notes"][0]
    warning = [line for line in res.stderr.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and "1 input(s) without a known tooth count" in warning[0] and "--teeth N" in warning[0]


# ============================================================================ a 50 Hz trace
def _slow_inputs(seconds: float = 20.0) -> Recording:
    t = np.arange(int(seconds * 50)) / 50.0
    return Recording.from_arrays({"force_x": 40 + 5 * np.sin(t), "spindle_speed": np.full(t.size, 5400 * math.pi / 30)},
                                 fs=50.0)


def test_the_chatter_detector_names_the_rate_it_needs():
    det = ChatterDetector("x")
    with pytest.raises(SignalTooShortError) as exc:
        det.stream(50.0)
    msg = str(exc.value)
    assert "above 500 Hz" in msg and "50 Hz" in msg and "highpass" not in msg and "--" not in msg
    assert det.unusable(1000.0) is None and "500 Hz" in det.unusable(50.0)
    assert "bandwidth" in ChatterDetector("x", highest_hz=200.0).unusable(10_000.0)


def test_detect_on_a_50_hz_trace_runs_what_can_run_and_says_what_cannot():
    inputs = _slow_inputs()
    found = detect_in_trace(inputs, inputs, force_limit_n=300.0, teeth=2)
    assert [d.name for d in found.detectors] == ["overload"]
    assert len(found.notes) == 2
    assert "breakage/chipping detection is off" in found.notes[0] and "400 Hz" in found.notes[0]
    assert "chatter detection is off" in found.notes[1] and "above 500 Hz" in found.notes[1]
    assert all("highpass" not in n and "_hz" not in n for n in found.notes)
    with pytest.raises(ConfigError) as exc:
        detect_in_trace(inputs, inputs)
    msg = str(exc.value)
    assert "--force-limit" in msg and "--limits" in msg and "50 Hz" in msg and "highpass" not in msg


def test_detect_cli_on_a_50_hz_controller_trace(tmp_path):
    from drivesense.io import write_recording
    from drivesense.io.axes_file import write_axes_file
    from drivesense.machine.linear_motor import linear_machine_model
    from drivesense.sim.machining import simulate_process

    groove = simulate_process("groove_+x-y", 2e-3, 10e-3, 0.01, 5400, seed=11)
    step = int(round(groove.fs / 50))
    slow = Recording.from_arrays({c: groove[c][::step] for c in groove.channels}, fs=groove.fs / step,
                                 meta={"nc_delay_s": groove.meta["nc_delay_s"]})
    write_recording(slow, tmp_path / "g50.nc")
    axes = write_axes_file(tmp_path / "AXES.toml", linear_machine_model())
    base = ("detect", tmp_path / "g50.nc", "--method", "model", "--axes", axes, "--json", tmp_path / "e.json")
    res = invoke(*base)
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "highpass" not in res.output and "--force-limit" in res.output and "above 500 Hz" in res.output
    res = invoke(*base, "--force-limit", 300, "--teeth", 2)
    assert res.exit_code == 0, res.output
    assert res.stderr.count("warning:") == 2 and "above 500 Hz" in res.stderr
    assert json.loads((tmp_path / "e.json").read_text())["detectors"] == ["overload"] * 3


# ============================================================================ the plot
def test_the_chatter_statistic_is_drawn_held_where_its_guards_hold_it(tmp_path):
    """A step of the force (a tooth breaks) passes the chatter comb for about two revolutions: its statistic
    jumps over the threshold, and the guards (hold, settling) keep that from being an event.  The detector
    reports where its guards held it; the plot draws those samples dashed on a shaded band."""
    import matplotlib

    matplotlib.use("Agg")
    from drivesense.plot import plot_events

    rec = _milling(2, 3000.0, seconds=3.0, runout=0.1)
    t = rec.time
    force = rec["force_x"] * np.where(t >= 2.0, 1.6, 1.0)              # a step of the force at 2 s
    inputs = Recording.from_arrays({"force_x": force, "spindle_speed": rec["spindle_speed"]}, fs=FS)
    report = run_detectors(inputs, [ChatterDetector("x")])
    stat, thr = report.statistics["chatter"]
    held = report.held["chatter"]
    assert not report.events
    over = np.flatnonzero(stat > thr)
    assert over.size and np.all(held[over] > 0)                        # every crossing was held
    assert np.any(held == 1) and set(np.unique(held)) <= {0.0, 1.0, 2.0, 3.0, 4.0}
    fig = plot_events(inputs, report)
    texts = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert any("held by the detector's guards" in s for s in texts)


def test_the_event_label_stands_beside_its_line():
    import matplotlib

    matplotlib.use("Agg")
    from drivesense.events.detector import Event
    from drivesense.events.pipeline import DetectionReport
    from drivesense.plot import plot_events

    rec = _milling(2, 3000.0, seconds=1.0)
    report = DetectionReport([Event("breakage", 0.5, "x", 1.0, 0.01, "breakage", {})], 0.01,
                             {"breakage": (np.zeros(rec.n_samples), np.full(rec.n_samples, 0.1))})
    fig = plot_events(rec, report)
    label = next(a for a in fig.axes[0].texts if a.get_text() == "breakage")
    assert label.get_ha() == "left" and label.get_anncoords() == "offset points" and label.xyann[0] > 0
