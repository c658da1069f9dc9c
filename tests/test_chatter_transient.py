"""The chatter detector against a transient: a line that jumps in and dies away is no chatter.

Where the tool leaves the part, the force pattern changes abruptly and then keeps
changing for a few revolutions: the double comb's output jumps within one
revolution and dies away.  At low spindle speed its spectrum holds what reads as a
line between the spindle harmonics, and without a look at how the comb's power
evolves it was called chatter (bench events: every chatter false alarm with the
NC's context fell 4 revolutions into a part's exit).  Chatter grows from the noise
and holds.  Closed-form forces at 10 kHz: a 3-tooth pulse train at 1400 min^-1
plus a 217 Hz tone that either jumps in and decays (a transient) or grows and
holds (chatter).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.events.chatter import ChatterDetector
from drivesense.recording import Recording

FS = 10_000.0
RPM = 1400.0
REV_S = 60.0 / RPM
ONSET = 2.5
TAU = 1.5           # the transient's decay [revolutions]


def _pulses(t, lost_from=None):
    """A 3-tooth pulse train of 40 N (tooth 1 gone from ``lost_from`` [s] on)."""
    theta = 2 * math.pi * RPM / 60.0 * t
    force = np.zeros_like(t)
    for j in range(3):
        phase = np.mod(theta - j * 2 * math.pi / 3, 2 * math.pi)
        gain = np.where((j == 1) & (t >= lost_from), 0.0, 40.0) if lost_from is not None else 40.0
        force += np.where(phase < 1.2, np.sin(math.pi * phase / 1.2), 0.0) * gain
    return force


def _trace(kind: str, seed: int = 3) -> Recording:
    t = np.arange(int(4.0 * FS)) / FS
    pulses = _pulses(t)
    after = np.clip(t - ONSET, 0.0, None) / REV_S                    # revolutions since the onset
    if kind == "transient":
        amp = np.where(t >= ONSET, 12.0 * np.exp(-after / TAU), 0.0)   # jumps in, dies away
    else:
        amp = np.where(t >= ONSET, 12.0 * (1.0 - np.exp(-after / 3.0)), 0.0)   # grows and holds
    noise = np.random.default_rng(seed).normal(0.0, 0.3, t.size)
    force = pulses + amp * np.sin(2 * math.pi * 217.0 * t) + noise
    return Recording.from_arrays({"force_x": force, "spindle_speed": np.full(t.size, RPM * 2 * math.pi / 60.0)},
                                 fs=FS)


def test_a_line_that_jumps_in_and_dies_away_is_no_chatter():
    rec = _trace("transient")
    assert ChatterDetector("x", teeth=3).detect(rec) == []
    assert ChatterDetector("x", teeth=3, transient_decay=0.0).detect(rec) == []    # the jump rule alone holds it


def test_the_transient_is_held_with_its_own_guard_code():
    det = ChatterDetector("x", teeth=3)
    rec = _trace("transient")
    _, _, _, held = det.process(det.new_state(FS), {c: rec[c] for c in rec.channels}, 0)
    assert np.any(held == 4.0)
    assert 4 in ChatterDetector.GUARDS


def test_chatter_that_grows_and_holds_is_still_found_at_the_same_time():
    rec = _trace("chatter")
    with_check = ChatterDetector("x", teeth=3).detect(rec)
    without = ChatterDetector("x", teeth=3, transient_decay=0.0).detect(rec)
    assert [e.kind for e in with_check] == ["chatter"]
    assert with_check[0].time_s == pytest.approx(without[0].time_s, abs=1e-9)
    assert abs(with_check[0].evidence["chatter_frequency_hz"] - 217.0) < 5.0
    assert with_check[0].time_s - ONSET < 10 * REV_S


@pytest.mark.parametrize("bad", [1.0, 1.5, -0.1])
def test_a_decay_outside_0_to_1_is_refused_by_name(bad):
    with pytest.raises(ConfigError, match="transient_decay"):
        ChatterDetector("x", transient_decay=bad)


def _growing(level_fall: float = 0.0, context: bool = False, shaken_feed: bool = False) -> Recording:
    """Chatter growing 1.6x per revolution from 0.1 N at ONSET (saturating at 12 N), on a pattern whose level
    falls by ``level_fall`` over 10 revolutions from ONSET - 5 revolutions (a gradual change of engagement)."""
    t = np.arange(int(4.0 * FS)) / FS
    pulses = _pulses(t)
    k = np.clip((t - (ONSET - 5 * REV_S)) / (10 * REV_S), 0.0, 1.0)
    pulses *= 1.0 - level_fall * k
    revs = np.clip(t - ONSET, 0.0, None) / REV_S
    amp = np.where(t >= ONSET, np.minimum(0.1 * 1.6 ** revs, 12.0), 0.0)
    noise = np.random.default_rng(5).normal(0.0, 0.3, t.size)
    arrays = {"force_x": pulses + amp * np.sin(2 * math.pi * 217.0 * t) + noise,
              "spindle_speed": np.full(t.size, RPM * 2 * math.pi / 60.0),
              "feed_speed": np.full(t.size, 2e-3)}
    if shaken_feed:         # the measured path speed shaken by the vibration, from the onset on
        arrays["feed_speed"] = arrays["feed_speed"] * (1 + np.where(t >= ONSET, 0.5, 0.0) * np.sin(2 * math.pi * 217.0 * t))
    if context:
        n = t.size
        arrays.update({"tool_number": np.ones(n), "program_number": np.full(n, 7.0), "block_number": np.full(n, 20.0),
                       "feed_override": np.ones(n), "spindle_override": np.ones(n), "execution": np.ones(n),
                       "in_cut": np.ones(n)})
    return Recording.from_arrays(arrays, fs=FS)


def test_chatter_that_grows_from_the_noise_is_confirmed_a_turn_after_the_first_check():
    """No jump: confirmed at the recheck, about two turns after the statistic crossed the threshold (a step would
    wait three turns and the RMS window)."""
    det = ChatterDetector("x", teeth=3)
    rec = _growing()
    events, stat, thr, _ = det.process(det.new_state(FS), {c: rec[c] for c in rec.channels}, 0)
    assert [e[1] for e in events] == ["chatter"]
    crossed = int(np.flatnonzero(stat > thr)[0])
    assert (events[0][0] - crossed) / FS <= (det.hold_revs + 1.0 + det.window + 0.3) * REV_S


def test_a_step_of_the_pattern_is_no_chatter():
    """A tooth's loss: the pattern changes at once and then repeats; the double comb passes it for two turns."""
    t = np.arange(int(4.0 * FS)) / FS
    force = _pulses(t, lost_from=ONSET) + np.random.default_rng(2).normal(0.0, 0.3, t.size)
    rec = Recording.from_arrays({"force_x": force, "spindle_speed": np.full(t.size, RPM * 2 * math.pi / 60.0)},
                                fs=FS)
    assert ChatterDetector("x", teeth=3).detect(rec) == []


def test_with_the_nc_context_a_falling_level_and_a_shaken_feed_hold_nothing():
    """Without the NC's word the detector holds where the forced level falls (an exit?) or the measured feed
    is unsteady (a feed change?); the context says the program runs as written, so it judges there."""
    plain = ChatterDetector("x", teeth=3).detect(_growing(level_fall=0.3, shaken_feed=True))
    with_nc = ChatterDetector("x", teeth=3).detect(_growing(level_fall=0.3, shaken_feed=True, context=True))
    assert [e.kind for e in with_nc] == ["chatter"]
    assert with_nc[0].evidence["guards"] == "nc_context"
    steady = ChatterDetector("x", teeth=3).detect(_growing(context=True))
    assert with_nc[0].time_s <= steady[0].time_s + 0.5 * REV_S      # no later than if nothing changed
    assert not plain or plain[0].time_s > with_nc[0].time_s + REV_S
