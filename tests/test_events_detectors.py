"""Process-event detectors (drivesense.events: breakage, chatter, overload, teach-in) on closed-form signals.

Every force here is written down directly -- half-sine tooth pulses at a
constant spindle speed, a tone, a step, a ramp -- at 10 kHz, so the expected
event, its time and its evidence follow from the signal's definition (no
simulator, no estimator).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drivesense.errors import ConfigError, InvalidSignalError, MissingChannelError, SignalTooShortError
from drivesense.events.breakage import BreakageDetector
from drivesense.events.chatter import ChatterDetector
from drivesense.events.detector import EVENT_KINDS, Event, events_to_json
from drivesense.events.overload import OverloadDetector
from drivesense.events.pipeline import default_detectors, run_detectors
from drivesense.events.teach import TeachInDetector, TeachLimits, teach
from drivesense.recording import Recording

FS = 10_000.0
RPM = 3000.0
REV_S = 60.0 / RPM                    # 20 ms, 200 samples
FEED = 5e-3                           # feed speed [m/s]


def _time(duration: float) -> np.ndarray:
    return np.arange(int(round(duration * FS))) / FS


def _pulses(t: np.ndarray, amps, *, rpm: float = RPM, amp: float = 50.0, width: float = 1 / 6) -> np.ndarray:
    """Sum over teeth j of a half-sine of ``width`` of a revolution starting at angle ``j 2 pi / N``,
    of height ``amp * amps[j]`` (a scalar or one value per sample)."""
    theta = 2 * math.pi * rpm / 60.0 * t
    span = 2 * math.pi * width
    out = np.zeros_like(t)
    n = len(amps)
    for j, a in enumerate(amps):
        phase = np.mod(theta - j * 2 * math.pi / n, 2 * math.pi)
        out += np.where(phase < span, np.sin(math.pi * phase / span), 0.0) * amp * np.asarray(a, dtype=float)
    return out


def _rec(force: np.ndarray, *, rpm: float | None = RPM, feed: float | None = FEED, t0: float = 0.0) -> Recording:
    ch = {"force_x": force}
    if rpm is not None:
        ch["spindle_speed"] = np.full(force.size, rpm * 2 * math.pi / 60.0)
    if feed is not None:
        ch["feed_speed"] = np.full(force.size, feed)
    return Recording.from_arrays(ch, fs=FS, t0=t0)


def _noise(n: int, seed: int, sd: float = 0.3) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, sd, n)


def _damage_amps(t: np.ndarray, at: float, moved: float, base=(1.0, 0.97, 1.03)):
    """Tooth 1 loses ``moved`` of its pulse from ``at`` on; tooth 2 (the next) takes it from tooth 1's first
    pass after ``at`` on (the chip a damaged tooth leaves is there only once it has passed)."""
    rev = 60.0 / RPM
    start1 = (1.0 / 3.0) * rev                           # tooth 1's pulse starts a third of a turn in
    first_pass = at + np.mod(start1 - at, rev)           # tooth 1's first pulse start at or after `at`
    after = t >= at
    taken = t >= first_pass + rev / 3.0                   # tooth 2's next pulse after it
    return [np.full(t.size, base[0]),
            np.where(after, (1 - moved) * base[1], base[1]),
            np.where(taken, base[2] + moved * base[1], base[2])]


# ============================================================================= breakage
def test_breakage_of_one_tooth():
    t = _time(3.0)
    force = _pulses(t, _damage_amps(t, 2.0, 1.0)) + _noise(t.size, 0)
    events = BreakageDetector("x", 3).detect(_rec(force))
    assert len(events) == 1
    ev = events[0]
    assert ev.kind == "breakage" and ev.detector == "breakage" and ev.axis == "x"
    # tooth 1's first missing pulse starts a third of a revolution after 2.0 s
    assert 2.0 < ev.time_s <= 2.0 + 2 * REV_S
    assert 0.0 <= ev.evidence["tooth_angle_deg"] < 360.0
    assert ev.evidence["edge_loss"] > 0.8
    assert ev.evidence["statistic"] > ev.evidence["threshold"]
    assert 0.0 < ev.confidence <= 1.0
    json.dumps(ev.to_json(), allow_nan=False)


def test_no_breakage_without_damage():
    t = _time(3.0)
    force = _pulses(t, (1.0, 0.97, 1.03)) + _noise(t.size, 0)
    out = BreakageDetector("x", 3).stream(FS).push(_rec(force))
    assert out.events == []
    armed = np.isfinite(out.threshold)
    assert armed.any()
    assert np.nanmax(out.statistic[armed]) < 0.5 * np.nanmin(out.threshold)


def test_a_change_every_tooth_shares_is_no_breakage():
    """The part's edge notching every pulse alike (all teeth lose more and more of the middle of their pulse
    over 20 revolutions, as when the tool leaves the part, with a 12 % runout spread between them) moves no
    work from one tooth to another: no event."""
    t = _time(3.0)
    amps = (1.0, 0.88, 1.12)
    whole = _pulses(t, amps)
    theta = 2 * math.pi * RPM / 60.0 * t
    mid = np.zeros_like(t)
    for j, a in enumerate(amps):                          # the middle third of each pulse, removed from 2 s on
        phase = np.mod(theta - j * 2 * math.pi / 3, 2 * math.pi) - 2 * math.pi / 18
        mid += np.where((phase >= 0) & (phase < 2 * math.pi / 18), 50.0 * a * 0.7, 0.0)
    depth = np.clip((t - 2.0) / 0.4, 0.0, 1.0)
    force = whole - depth * mid + _noise(t.size, 9)
    assert [e for e in BreakageDetector("x", 3).detect(_rec(force)) if e.time_s >= 2.0] == []


def test_chipping_is_detected():
    t = _time(3.0)
    force = _pulses(t, _damage_amps(t, 2.0, 0.4)) + _noise(t.size, 1)
    events = BreakageDetector("x", 3).detect(_rec(force))
    assert len(events) >= 1
    ev = events[0]
    assert ev.kind in ("breakage", "chipping")
    assert 2.0 < ev.time_s <= 2.0 + 5 * REV_S
    assert 0.0 <= ev.evidence["tooth_angle_deg"] < 360.0


@pytest.mark.parametrize("amps", [(1.0, 0.8, 1.2), (0.9, 1.1, 1.0)])
def test_runout_alone_does_not_alarm(amps):
    t = _time(3.0)
    force = _pulses(t, amps) + _noise(t.size, 2)
    assert BreakageDetector("x", 3).detect(_rec(force)) == []


def test_breakage_with_fixed_spindle_rpm_equals_spindle_channel():
    t = _time(3.0)
    force = _pulses(t, _damage_amps(t, 2.0, 1.0)) + _noise(t.size, 0)
    with_channel = BreakageDetector("x", 3).detect(_rec(force))
    fixed = BreakageDetector("x", 3, spindle_rpm=RPM).detect(_rec(force, rpm=None))
    assert [(e.kind, e.time_s) for e in fixed] == [(e.kind, e.time_s) for e in with_channel]


def test_breakage_soon_after_the_detector_arms():
    t = _time(2.0)
    entry = np.clip((t - 0.5) / 0.02, 0.0, 1.0)
    force = _pulses(t, _damage_amps(t, 0.85, 1.0)) * entry + _noise(t.size, 0)
    events = BreakageDetector("x", 3).detect(_rec(force))
    assert events and events[0].kind == "breakage" and 0.85 < events[0].time_s <= 0.85 + 2 * REV_S


# ============================================================================= chatter
def _tooth_pass(t, seed=3):
    return _pulses(t, (1.0, 1.0), amp=40.0, width=1 / 4) + _noise(t.size, seed)


def _tone(t, freq=537.0, amp=8.0, start=1.5):
    return np.where(t >= start, amp * np.sin(2 * math.pi * freq * t), 0.0)


def test_chatter_on_a_non_harmonic_tone():
    t = _time(3.0)
    events = ChatterDetector("x").detect(_rec(_tooth_pass(t) + _tone(t)))
    assert len(events) >= 1
    ev = events[0]
    assert ev.kind == "chatter"
    # the hold (2.6 revolutions) plus the window: a few revolutions after the onset
    assert 1.5 < ev.time_s < 1.5 + 10 * REV_S
    assert ev.evidence["statistic"] > ev.evidence["threshold"]
    assert ev.evidence["forced_rms_n"] > 2.0


def test_chatter_frequency_is_the_tone():
    t = _time(3.0)
    events = ChatterDetector("x").detect(_rec(_tooth_pass(t) + _tone(t)))
    assert events
    assert abs(events[0].evidence["chatter_frequency_hz"] - 537.0) < 10.0


@pytest.mark.parametrize("freq", [713.0, 1012.0])
def test_chatter_on_other_tones(freq):
    """Tones between the spindle harmonics (50 Hz apart at 3000 rpm) anywhere in the band are chatter."""
    t = _time(3.0)
    events = ChatterDetector("x").detect(_rec(_tooth_pass(t) + _tone(t, freq=freq)))
    assert [e.kind for e in events][:1] == ["chatter"]
    assert abs(events[0].evidence["chatter_frequency_hz"] - freq) < 10.0


def test_a_tone_on_a_spindle_harmonic_is_forced_response():
    """700 Hz is the 14th harmonic of a 50 Hz spindle: it repeats every revolution, the comb cancels it."""
    t = _time(3.0)
    assert ChatterDetector("x").detect(_rec(_tooth_pass(t) + _tone(t, freq=700.0))) == []


def test_no_chatter_without_the_tone():
    t = _time(3.0)
    out = ChatterDetector("x").stream(FS).push(_rec(_tooth_pass(t)))
    assert out.events == []
    assert np.nanmax(out.statistic) < 0.05


def test_force_step_is_not_chatter():
    t = _time(3.0)
    force = _tooth_pass(t) * np.where(t >= 1.5, 0.6, 1.0)
    assert ChatterDetector("x").detect(_rec(force)) == []


# ============================================================================= overload
def test_collision_on_a_step():
    t = _time(2.0)
    force = np.where(t >= 1.0, 500.0, 20.0)
    events = OverloadDetector("x", limit_n=300.0).detect(_rec(force, rpm=None, feed=None, t0=12.5))
    assert len(events) == 1
    ev = events[0]
    first = int(np.flatnonzero(force > 300.0)[0])
    assert ev.kind == "collision"
    assert ev.time_s == 12.5 + first / FS
    assert ev.evidence["stop"] is True
    assert ev.evidence["force_n"] == 500.0 and ev.evidence["limit_n"] == 300.0
    assert ev.latency_s == 0.0


def test_overload_on_a_slow_ramp():
    t = _time(2.0)
    force = 20.0 + 480.0 * np.clip((t - 1.0) / 0.5, 0.0, 1.0)
    events = OverloadDetector("x", limit_n=300.0).detect(_rec(force, rpm=None, feed=None))
    assert len(events) == 1
    first = int(np.flatnonzero(force > 300.0)[0])
    assert events[0].kind == "overload"
    assert events[0].time_s == t[first]
    assert events[0].evidence["stop"] is True


def test_overload_rearms_after_the_force_falls():
    t = _time(3.0)
    force = np.where((t >= 0.5) & (t < 0.6), 500.0, 20.0) + np.where(t >= 2.0, 480.0, 0.0)
    events = OverloadDetector("x", limit_n=300.0, rearm_s=0.5).detect(_rec(force, rpm=None, feed=None))
    assert [(e.kind, e.time_s) for e in events] == [("collision", 0.5), ("collision", 2.0)]
    # negative forces count by magnitude
    assert OverloadDetector("x", limit_n=300.0).detect(_rec(-force, rpm=None, feed=None))[0].time_s == 0.5


# ============================================================================= stream == batch
def _breakage_trace():
    t = _time(3.0)
    return _rec(_pulses(t, _damage_amps(t, 2.0, 1.0)) + _noise(t.size, 0))


def _chatter_trace():
    t = _time(3.0)
    return _rec(_tooth_pass(t) + _tone(t))


def _overload_trace():
    t = _time(3.0)
    return _rec(np.where((t >= 0.5) & (t < 0.6), 500.0, 20.0) + 480.0 * np.clip((t - 2.0) / 0.5, 0, 1))


def _teach_case():
    runs = [_teach_run(s) for s in range(3)]
    return TeachInDetector(teach(runs)), _teach_run(10, zero_from=1.2)


def _assert_stream_equals_batch(det, rec, chunk=997, *, statistic=True):
    batch = det.stream(FS, t0=rec.t0).push(rec)
    stream = det.stream(FS, t0=rec.t0)
    names = list(rec.channels)
    arrays = {c: rec[c] for c in names}
    events, stats, thrs = [], [], []
    for a in range(0, rec.n_samples, chunk):
        out = stream.push({c: v[a:a + chunk] for c, v in arrays.items()})
        events += out.events
        stats.append(out.statistic)
        thrs.append(out.threshold)
    assert [(e.kind, e.time_s) for e in events] == [(e.kind, e.time_s) for e in batch.events]
    for e, b in zip(events, batch.events):
        assert e.evidence.keys() == b.evidence.keys()
    if statistic:
        np.testing.assert_allclose(np.concatenate(stats), batch.statistic, rtol=1e-9, atol=1e-12, equal_nan=True)
        np.testing.assert_allclose(np.concatenate(thrs), batch.threshold, rtol=1e-9, atol=1e-12, equal_nan=True)
    return batch


@pytest.mark.parametrize("case", ["breakage", "chatter", "overload", "teach-in"])
def test_stream_equals_batch(case):
    if case == "breakage":
        det, rec = BreakageDetector("x", 3), _breakage_trace()
    elif case == "chatter":
        det, rec = ChatterDetector("x"), _chatter_trace()
    elif case == "overload":
        det, rec = OverloadDetector("x", limit_n=300.0), _overload_trace()
    else:
        det, rec = _teach_case()
    # teach-in: events only (its statistic: test_teach_in_stream_statistic_equals_batch)
    batch = _assert_stream_equals_batch(det, rec, statistic=case != "teach-in")
    assert batch.events, "the trace should raise an event"
    assert batch.statistic.shape == (rec.n_samples,)


def test_teach_in_stream_statistic_equals_batch():
    det, rec = _teach_case()
    _assert_stream_equals_batch(det, rec)


def test_stream_uses_the_chunks_time():
    rec = _overload_trace()
    stream = OverloadDetector("x", limit_n=300.0).stream(FS)
    out = stream.push({"force_x": rec["force_x"], "time": rec.time + 100.0})
    assert out.events[0].time_s == pytest.approx(100.5, abs=1e-12)


# ============================================================================= teach-in
TEACH_S = 3.0


def _teach_run(seed: int, scale: float = 1.0, zero_from: float | None = None) -> Recording:
    """Air 0-0.5 s, a cut 0.5-2.5 s (20 ms ramps), air again; the level varies 3 % between runs."""
    t = _time(TEACH_S)
    rng = np.random.default_rng(seed)
    envelope = np.clip((t - 0.5) / 0.02, 0, 1) * np.clip((2.5 - t) / 0.02, 0, 1)
    force = _pulses(t, (1.0, 1.0, 1.0), amp=50.0 * (1 + 0.03 * rng.standard_normal())) * envelope * scale
    force = force + rng.normal(0.0, 0.3, t.size)
    if zero_from is not None:
        force = np.where(t >= zero_from, rng.normal(0.0, 0.3, t.size), force)
    return _rec(force)


@pytest.fixture(scope="module")
def limits():
    return teach([_teach_run(s) for s in range(3)])


def test_teach_bands(limits):
    assert limits.align == "time" and limits.runs == 3 and limits.channels == ("force_x",)
    assert limits.bins >= int(TEACH_S / 0.05) - 1
    assert np.all(limits.lower["force_x"] <= limits.mean["force_x"])
    assert np.all(limits.mean["force_x"] <= limits.upper["force_x"])
    assert limits.force_limit_n == pytest.approx(3.0 * max(np.max(np.abs(_teach_run(s)["force_x"]))
                                                           for s in range(3)))
    assert limits.feed is not None and np.allclose(limits.feed, FEED)


def test_teach_missing_tool(limits):
    events = TeachInDetector(limits).detect(_teach_run(20, zero_from=1.2))
    assert len(events) == 1
    ev = events[0]
    assert ev.kind in ("missing_tool", "limit")
    assert ev.kind == "missing_tool"
    assert ev.evidence["side"] == "low"
    # two bins (50 ms each) out of the band from 1.2 s: reported when the second closes
    assert 1.2 < ev.time_s <= 1.2 + 3 * 0.05


def test_teach_too_high(limits):
    events = TeachInDetector(limits).detect(_teach_run(21, scale=1.5))
    assert len(events) == 1
    ev = events[0]
    assert ev.kind == "limit" and ev.evidence["side"] == "high"
    assert ev.evidence["value"] > ev.evidence["band"]
    assert 0.5 < ev.time_s < 0.7


def test_teach_good_run(limits):
    assert TeachInDetector(limits).detect(_teach_run(22)) == []


def test_teach_limits_json_round_trip(limits):
    text = json.dumps(limits.to_json(), allow_nan=False)
    back = TeachLimits.from_json(json.loads(text))
    assert back.channels == limits.channels and back.align == limits.align and back.runs == limits.runs
    assert back.bin_width == limits.bin_width and back.force_limit_n == limits.force_limit_n
    for name in ("mean", "upper", "lower"):
        np.testing.assert_array_equal(getattr(back, name)["force_x"], getattr(limits, name)["force_x"])
    np.testing.assert_array_equal(back.feed, limits.feed)
    assert json.loads(limits.dumps()) == json.loads(text)
    # the detector built from the read limits behaves the same
    run = _teach_run(20, zero_from=1.2)
    assert [(e.kind, e.time_s) for e in TeachInDetector(back).detect(run)] == \
           [(e.kind, e.time_s) for e in TeachInDetector(limits).detect(run)]


# ============================================================================= pipeline, events
def test_run_detectors_adds_the_estimators_latency():
    t = _time(3.0)
    force = _pulses(t, _damage_amps(t, 2.0, 1.0)) + _noise(t.size, 0)
    ch = {"force_x": force, "spindle_speed": np.full(t.size, RPM * 2 * math.pi / 60), "feed_speed": np.full(t.size, FEED)}
    inputs = Recording.from_arrays(ch, fs=FS, meta={"name": "forces", "latency_s": 0.01})
    dets = default_detectors("x", teeth=3, force_limit_n=300.0)
    assert [d.name for d in dets] == ["breakage", "chatter", "overload"]
    report = run_detectors(inputs, dets)
    assert [e.kind for e in report.events] == ["breakage"]
    ev = report.events[0]
    assert ev.latency_s == pytest.approx(dets[0].latency_s(FS) + 0.01)
    assert report.latency_s >= ev.latency_s
    assert set(report.statistics) == {"breakage", "chatter", "overload"}
    doc = events_to_json(report.events, report.latency_s)
    json.dumps(doc, allow_nan=False)
    assert doc["events"][0]["kind"] == "breakage"


def test_event_kind_is_checked():
    assert "breakage" in EVENT_KINDS
    with pytest.raises(ConfigError):
        Event("explosion", 0.0, "x", 1.0, 0.0, "test")
    assert Event("limit", 1.0, "x", 7.0, 0.0, "test").confidence == 1.0


# ============================================================================= bad input
@pytest.mark.parametrize("make", [lambda: BreakageDetector("x", 3), lambda: ChatterDetector("x")])
def test_no_spindle_speed(make):
    t = _time(1.0)
    with pytest.raises(MissingChannelError, match="--spindle-rpm"):
        make().detect(_rec(_pulses(t, (1.0, 1.0, 1.0)), rpm=None))


def test_cut_too_short_for_a_baseline():
    t = _time(1.0)
    force = _pulses(t, (1.0, 1.0, 1.0)) * ((t >= 0.5) & (t < 0.6)) + _noise(t.size, 4)   # 5 revolutions
    with pytest.raises(SignalTooShortError, match="baseline"):
        BreakageDetector("x", 3).detect(_rec(force))
    # air alone (a missing tool) is no error: nothing to judge, no event
    assert BreakageDetector("x", 3).detect(_rec(_noise(t.size, 5))) == []


@pytest.mark.parametrize("make", [lambda: BreakageDetector("x", 3), lambda: ChatterDetector("x"),
                                  lambda: OverloadDetector("x", limit_n=300.0)])
def test_nan_chunk(make):
    stream = make().stream(FS)
    force = np.full(500, 10.0)
    force[100] = np.nan
    with pytest.raises(InvalidSignalError):
        stream.push({"force_x": force, "spindle_speed": np.full(500, 314.159)})


def test_missing_force_channel():
    with pytest.raises(MissingChannelError):
        OverloadDetector("y", limit_n=300.0).stream(FS).push({"force_x": np.zeros(10)})


def test_teach_needs_two_runs():
    with pytest.raises(SignalTooShortError):
        teach([_teach_run(0)])
