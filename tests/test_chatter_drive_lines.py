"""The chatter detector against the drive's own lines and against a tool that cuts part of each turn.

Closed-form forces at 10 kHz: a 2-tooth (or 1-tooth) pulse train at 3000 min^-1
plus tones.  A measuring error that repeats every ``p`` of the axis's travel
(the motor encoder's signal period) puts a line at ``|v| / p`` into a force
estimate; a feed override moves it.  It passes the chatter comb like chatter
does, so without knowing ``p`` it reads as chatter; with the pitch
(:meth:`SignalParams.drive_pitches`) it must not, while a tool's own chatter
tone at the same time still must.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.events.chatter import ChatterDetector, drive_lines
from drivesense.events.pipeline import default_detectors, estimate_limits
from drivesense.estimate import make
from drivesense.machine.presets import table1_axis, table1_signal
from drivesense.machine.signal_chain import SignalParams
from drivesense.recording import Recording

FS = 10_000.0
RPM = 3000.0
PITCH = 5e-3 / 512                        # the paper's encoder: 512 signal periods on a 5 mm lead
TOP = 650.0                               # the estimate's band: the line at 8 mm/s (819 Hz) lies above it


def _detector(**kw):
    return ChatterDetector("x", teeth=2, highest_hz=TOP, **kw)


def _pulses(t, teeth=2, amp=40.0, width=0.25, rpm=RPM):
    theta = 2 * math.pi * rpm / 60.0 * t
    out = np.zeros_like(t)
    for j in range(teeth):
        phase = np.mod(theta - j * 2 * math.pi / teeth, 2 * math.pi)
        span = 2 * math.pi * width
        out += np.where(phase < span, np.sin(math.pi * phase / span), 0.0) * amp
    return out


def _trace(force, position, rpm=RPM):
    return Recording.from_arrays({"force_x": force, "x_table_position": position,
                                  "spindle_speed": np.full(force.size, rpm * 2 * math.pi / 60.0),
                                  "feed_speed": np.abs(np.gradient(position)) * FS}, fs=FS)


def _override_run(seconds=4.0, v0=8e-3, factor=0.6, at=1.5, seed=1):
    """The axis moves at v0, then (from ``at``) at factor * v0; the estimate holds the encoder's line at |v|/p."""
    t = np.arange(int(seconds * FS)) / FS
    v = np.where(t < at, v0, factor * v0)
    x = np.cumsum(v) / FS
    line = 6.0 * np.sin(2 * math.pi * x / PITCH)          # 6 N at the encoder's signal period, moved by the feed
    noise = np.random.default_rng(seed).normal(0.0, 0.3, t.size)
    return t, x, _pulses(t) + line + noise


def test_drive_lines_are_the_pitch_harmonics_and_their_tooth_pass_sidebands():
    bands = drive_lines(np.array([4e-3, 5e-3]), (PITCH,), 100.0, 2.0)
    centres = sorted(round((a + b) / 2) for a, b in bands)
    f1 = 4.5e-3 / PITCH                                   # 460.8 Hz at the mean speed
    expected = sorted(round(k * f1 + m) for k in (1, 2) for m in (-100.0, 0.0, 100.0))
    assert centres == expected
    widths = sorted(round(b - a, 1) for a, b in bands)
    assert widths[0] == pytest.approx(1e-3 / PITCH + 4.0, abs=0.1)      # the speed's range, padded
    assert drive_lines(np.array([4e-3]), (), 100.0, 2.0) == []


def test_an_override_moves_the_encoder_line_into_the_band_and_it_is_not_chatter():
    t, x, force = _override_run()
    rec = _trace(force, x)
    plain = _detector().detect(rec)
    assert [e.kind for e in plain][:1] == ["chatter"]                   # without the pitch: a false alarm
    assert abs(plain[0].evidence["chatter_frequency_hz"] - 0.6 * 8e-3 / PITCH) < 10.0
    assert _detector(pitches_m=(PITCH,)).detect(rec) == []


def test_chatter_beside_the_encoder_line_is_still_chatter():
    t, x, force = _override_run()
    tone = np.where(t >= 2.5, 8.0 * np.sin(2 * math.pi * 537.0 * t), 0.0)
    events = _detector(pitches_m=(PITCH,)).detect(_trace(force + tone, x))
    assert [e.kind for e in events][:1] == ["chatter"]
    assert 2.5 < events[0].time_s < 2.5 + 12 * 60.0 / RPM
    assert abs(events[0].evidence["chatter_frequency_hz"] - 537.0) < 10.0


def test_the_speed_comes_from_the_feed_when_the_axis_position_is_absent():
    t, x, force = _override_run()
    rec = _trace(force, x)
    rec = rec.select("force_x", "spindle_speed", "feed_speed")
    assert _detector(pitches_m=(PITCH,)).detect(rec) == []


def test_streamed_in_chunks_equals_batch():
    t, x, force = _override_run()
    tone = np.where(t >= 2.5, 8.0 * np.sin(2 * math.pi * 537.0 * t), 0.0)
    rec = _trace(force + tone, x)
    det = _detector(pitches_m=(PITCH,))
    batch = det.detect(rec)
    stream = det.stream(FS)
    got = []
    for a in range(0, rec.n_samples, 733):
        got += stream.push({c: rec[c][a:a + 733] for c in rec.channels}).events
    assert [(e.kind, e.time_s, e.evidence["chatter_frequency_hz"]) for e in got] == \
        [(e.kind, e.time_s, e.evidence["chatter_frequency_hz"]) for e in batch]


def test_a_one_tooth_cutter_in_half_of_each_turn_keeps_its_statistic_between_passes():
    """One tooth cuts half a revolution: a half-revolution RMS window would dip below the threshold while the
    tooth is out, resetting the hold every turn.  The window is whole tooth passes: chatter is found."""
    t = np.arange(int(3.0 * FS)) / FS
    theta = 2 * math.pi * RPM / 60.0 * t
    engaged = np.mod(theta, 2 * math.pi) < math.pi
    tone = np.where((t >= 1.5) & engaged, 10.0 * np.sin(2 * math.pi * 537.0 * t), 0.0)
    force = _pulses(t, teeth=1, width=0.5) + tone + np.random.default_rng(3).normal(0.0, 0.3, t.size)
    rec = _trace(force, np.cumsum(np.full(t.size, 5e-3)) / FS)
    det = ChatterDetector("x", teeth=1)
    assert det.window == 1.0 and ChatterDetector("x", teeth=2).window == 0.5
    assert ChatterDetector("x", teeth=3).window == pytest.approx(2 / 3)
    events = det.detect(rec)
    assert [e.kind for e in events][:1] == ["chatter"]
    assert events[0].time_s < 1.5 + 15 * 60.0 / RPM


def test_the_encoder_pitch_travels_from_the_axis_file_to_the_detectors():
    est = make("vibration", axis=table1_axis(), signal=table1_signal())
    limits = estimate_limits(est)
    assert limits["drive_pitches_m"] == pytest.approx((PITCH,))
    chatter = [d for d in default_detectors("x", teeth=3, **limits) if d.name == "chatter"][0]
    assert chatter.pitches_m == pytest.approx((PITCH,)) and chatter.teeth == 3
    unknown = make("vibration", axis=table1_axis(), signal=SignalParams())
    assert estimate_limits(unknown)["drive_pitches_m"] == ()


def test_a_fractional_encoder_period_count_is_refused():
    with pytest.raises(ConfigError, match="encoder_signal_periods"):
        SignalParams(encoder_signal_periods=512.5)
    with pytest.raises(ConfigError, match="pitches_m"):
        ChatterDetector("x", pitches_m=(-1.0,))
