"""The teach-in's path meter: distance along the tool path without the table's vibration and the scale's noise.

Summing every sample's step adds the vibration's own length to the path (the table shakes by about a
micrometre at the tooth-pass frequency under the cut), more the longer a run takes: a run slowed by an
override then reads further than its taught runs at the same place of the part, and its taught band is
the wrong one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.errors import MissingChannelError
from drivesense.events.teach import PATH_CHORD_M, PathMeter, path_length

FS = 10_000.0


def _line(seconds, speed, noise=10e-9, seed=0, angle=0.3, shake=0.0):
    """A straight move with the scale's noise and a vibration of ``shake`` [m] at 388 Hz along it."""
    t = np.arange(int(seconds * FS)) / FS
    rng = np.random.default_rng(seed)
    s = speed * t + shake * np.sin(2 * math.pi * 388.0 * t)
    return [s * math.cos(angle) + rng.normal(0.0, noise, t.size), s * math.sin(angle) + rng.normal(0.0, noise, t.size)]


@pytest.mark.parametrize("speed", [2e-3, 10e-3])
def test_a_straight_move_reads_its_length_whatever_its_speed(speed):
    x, y = _line(4.0, speed, shake=1e-6)
    s = path_length([x, y])
    travel = speed * (x.size - 1) / FS
    assert abs(s[-1] - travel) < 3e-6                                         # within the vibration
    # the sum of every step reads the vibration's length on top where the table's vibration velocity
    # (2 pi 388 Hz x 1 um = 2.4 mm/s) outruns the feed: millimetres over a few seconds
    steps = np.sum(np.hypot(np.diff(x), np.diff(y)))
    if speed < 2.4e-3:
        assert steps - travel > 0.5e-3


def test_a_standing_table_does_not_travel():
    rng = np.random.default_rng(1)
    x = 5e-3 + rng.normal(0.0, 0.5e-6, 40_000)                              # 0.5 um of vibration, 4 s
    s = path_length([x])
    assert np.max(s) < PATH_CHORD_M


def test_an_arc_reads_its_length():
    t = np.arange(int(2.0 * FS)) / FS
    r, w = 5e-3, 1.0                                                          # 5 mm radius, 1 rad/s
    s = path_length([r * np.cos(w * t), r * np.sin(w * t)])
    assert s[-1] == pytest.approx(r * w * t[-1], rel=1e-4)


def test_the_path_never_runs_back():
    """A table shaking by 2 um while it creeps must not carry the path back over a bin's edge (a bin left and
    entered again is judged on a handful of samples of a force pulse)."""
    x, y = _line(3.0, 1e-3, shake=2e-6)
    s = path_length([x, y])
    assert np.all(np.diff(s) >= 0.0)


def test_chunks_read_as_the_whole_run():
    x, y = _line(2.0, 7e-3, noise=0.3e-6)
    whole = path_length([x, y])
    meter, parts, at = PathMeter(), [], 0
    for m in [1, 17, 0, 999, 4096, 3, 10_000]:
        parts.append(meter.advance([x[at:at + m], y[at:at + m]]))
        at += m
    parts.append(meter.advance([x[at:], y[at:]]))
    assert np.array_equal(np.concatenate(parts), whole)


def test_no_position_channel_is_refused():
    with pytest.raises(MissingChannelError, match="table-position"):
        PathMeter().advance([])
