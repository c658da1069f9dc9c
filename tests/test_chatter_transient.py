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


def _trace(kind: str, seed: int = 3) -> Recording:
    t = np.arange(int(4.0 * FS)) / FS
    theta = 2 * math.pi * RPM / 60.0 * t
    pulses = np.zeros_like(t)
    for j in range(3):
        phase = np.mod(theta - j * 2 * math.pi / 3, 2 * math.pi)
        pulses += np.where(phase < 1.2, np.sin(math.pi * phase / 1.2), 0.0) * 40.0
    after = np.clip(t - ONSET, 0.0, None) / REV_S                    # revolutions since the onset
    if kind == "transient":
        amp = np.where(t >= ONSET, 12.0 * np.exp(-after / TAU), 0.0)   # jumps in, dies away
    else:
        amp = np.where(t >= ONSET, 12.0 * (1.0 - np.exp(-after / 3.0)), 0.0)   # grows and holds
    noise = np.random.default_rng(seed).normal(0.0, 0.3, t.size)
    force = pulses + amp * np.sin(2 * math.pi * 217.0 * t) + noise
    return Recording.from_arrays({"force_x": force, "spindle_speed": np.full(t.size, RPM * 2 * math.pi / 60.0)},
                                 fs=FS)


def test_a_line_that_jumps_in_and_dies_away_is_no_chatter_but_was_without_the_check():
    rec = _trace("transient")
    assert [e.kind for e in ChatterDetector("x", teeth=3, transient_decay=0.0).detect(rec)] == ["chatter"]
    assert ChatterDetector("x", teeth=3).detect(rec) == []


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
