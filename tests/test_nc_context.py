"""The NC's context as channels, and the detectors' guards that use it (closed-form cases)."""

from __future__ import annotations

import numpy as np
import pytest

from drivesense.errors import InvalidSignalError
from drivesense.events.detector import feed_steady
from drivesense.events.nc_guard import CONTEXT_SETTLE_S, guard_source, nc_steady, process_steady
from drivesense.nc_context import (ACTIVE, CONTEXT_CHANNELS, EXECUTION_STATES, context_value, execution_code,
                                   program_code)
from drivesense.units import quantity_of_channel, to_si


def test_context_channels_are_dimensionless_and_overrides_read_percent():
    assert all(quantity_of_channel(c) == "dimensionless" for c in CONTEXT_CHANNELS)
    values, unit = to_si([100.0, 85.0], "%", name="feed_override")
    np.testing.assert_allclose(values, [1.0, 0.85])
    assert unit == "1"


def test_execution_states_and_program_names_code_stably():
    assert execution_code("ACTIVE") == ACTIVE == 1.0
    assert execution_code("feed hold") == EXECUTION_STATES.index("FEED_HOLD")
    assert execution_code(4) == 4.0
    with pytest.raises(InvalidSignalError, match="channel 'execution': unknown state 'RUNNING'"):
        execution_code("RUNNING")
    with pytest.raises(InvalidSignalError, match="channel 'execution': code 12"):
        execution_code(12)
    assert program_code("4711") == 4711.0
    code = program_code("PART_A.MPF")
    assert code == program_code(" PART_A.MPF ") and code != program_code("PART_B.MPF")
    assert 2**20 <= code < 2**24 and float(np.float32(code)) == code       # exact wherever it travels
    with pytest.raises(InvalidSignalError, match="channel 'program_number': an empty cell is no program"):
        program_code("  ")
    assert context_value("feed_override", "0.8") == 0.8
    with pytest.raises(InvalidSignalError, match="channel 'tool_number': 'T5' is not a number"):
        context_value("tool_number", "T5")
    with pytest.raises(InvalidSignalError, match="'spindle_load' is not an NC context channel"):
        context_value("spindle_load", 3)


def _chunks(arrays, size):
    n = len(next(iter(arrays.values())))
    for a in range(0, n, size):
        yield {k: v[a:a + size] for k, v in arrays.items()}


def test_guard_holds_for_the_settle_time_after_each_commanded_change_in_any_chunking():
    fs = 1000.0
    n = 3000
    block = np.full(n, 10.0)
    block[1000:] = 20.0                      # the next block at 1.0 s
    override = np.ones(n)
    override[2200:] = 1.2                    # the override turned at 2.2 s
    arrays = {"block_number": block, "feed_override": override, "execution": np.full(n, ACTIVE)}
    whole = nc_steady(arrays, {"fs": fs})
    settle = int(round(CONTEXT_SETTLE_S * fs))
    expected = np.ones(n)
    expected[1000:1000 + settle] = 0.0
    expected[2200:2200 + settle] = 0.0
    np.testing.assert_array_equal(whole, expected)
    for size in (1, 7, 250, 999):
        state = {"fs": fs}
        parts = np.concatenate([nc_steady(c, state) for c in _chunks(arrays, size)])
        np.testing.assert_array_equal(parts, expected)


def test_guard_holds_outside_the_cut_and_while_the_program_is_not_active():
    fs = 100.0
    execution = np.full(500, ACTIVE)
    execution[300:350] = execution_code("FEED_HOLD")
    in_cut = np.ones(500)
    in_cut[:50] = 0.0
    in_cut[450:] = 0.0
    ok = nc_steady({"execution": execution, "in_cut": in_cut}, {"fs": fs})
    assert ok[:50].sum() == 0 and ok[450:].sum() == 0 and ok[300:350].sum() == 0
    assert ok[50:300].all() and ok[350:450].all()


def test_process_steady_combines_the_feed_check_and_says_which_guards_it_used():
    fs = 1000.0
    feed = np.full(1000, 0.01)
    feed[500:] = 0.015                       # the axis follows an override: the feed check holds too
    state = {"fs": fs}
    plain = process_steady({"feed_speed": feed}, state)
    assert guard_source(state) == "feed_speed"
    np.testing.assert_array_equal(plain, feed_steady({"feed_speed": feed}, {"fs": fs}))
    state = {"fs": fs}
    override = np.ones(1000)
    override[400:] = 1.5
    both = process_steady({"feed_speed": feed, "feed_override": override}, state)
    assert guard_source(state) == "nc_context"
    assert both[400:400 + int(CONTEXT_SETTLE_S * fs)].sum() == 0        # the NC's word, before the axis moves
    assert np.all(both <= plain)
    state = {"fs": fs}
    process_steady({"force_x": np.zeros(10)}, state)
    assert guard_source(state) == "none"


def _program_run(dwell_s: float, seed: int, force_scale: float = 1.0):
    """A run of a three-block program without table positions: N10 stands for 0.3 s plus a dwell, N20 cuts
    for 1 s at 100 N, N30 leaves the part (0.5 s of air); tool 3 throughout."""
    from drivesense.recording import Recording

    fs = 1000.0
    rng = np.random.default_rng(seed)
    n10, n20, n30 = int((0.3 + dwell_s) * fs), 1000, 500
    block = np.r_[np.full(n10, 10.0), np.full(n20, 20.0), np.full(n30, 30.0)]
    force = np.r_[np.zeros(n10), 100.0 * force_scale * (1 + 0.02 * rng.standard_normal(n20)), np.zeros(n30)]
    return Recording.from_arrays({"force_x": force, "block_number": block, "tool_number": np.full(block.size, 3.0)},
                                 fs=fs)


def test_teach_in_per_block_is_not_shifted_by_a_dwell_and_streams_as_it_detects():
    from drivesense.events.teach import TeachInDetector, TeachLimits, teach

    runs = [_program_run(0.0, 1), _program_run(0.2, 2), _program_run(0.05, 3)]
    limits = teach(runs, ["force_x"])                       # auto: the runs carry block_number
    assert limits.align == "block" and limits.within == "time" and limits.unit == "s"
    assert [g[:3] for g in limits.segments] == [(3.0, 10.0, 0), (3.0, 20.0, 0), (3.0, 30.0, 0)]
    back = TeachLimits.from_json(limits.to_json())
    assert back.segments == limits.segments and back.within == "time"
    late = _program_run(0.7, 4)                              # a long dwell: every block after it starts later
    assert TeachInDetector(back).detect(late) == []
    assert TeachInDetector(teach(runs, ["force_x"], align="time")).detect(late) != []   # time bins: alarms
    weak = _program_run(0.4, 5, force_scale=0.4)             # a worn or chipped tool cuts at 40 %
    events = TeachInDetector(back).detect(weak)
    assert [e.kind for e in events] == ["limit"] and events[0].evidence["block_number"] == 20
    assert events[0].evidence["tool_number"] == 3
    stream = TeachInDetector(back).stream(1000.0)
    chunked = [e for a in range(0, weak.n_samples, 137)
               for e in stream.push({c: weak[c][a:a + 137] for c in weak.channels}).events]
    assert [(e.kind, e.time_s) for e in chunked] == [(e.kind, e.time_s) for e in events]


def test_bench_events_scores_false_alarms_with_and_without_the_context():
    from drivesense.bench.events import score_programs

    chatter = {"kind": "chatter", "detector": "chatter", "time_s": 5.0, "chatter_frequency_hz": 790.0}
    rows = [{"duration_s": 1800.0, "cutting_s": 1500.0, "overrides": [[4.7, 0.5]], "exit_length_mm": None,
             "teach_in": True, "teeth": 2, "spindle_rpm": 6000.0, "seed": k, "run": 3, "detected": [chatter],
             "detected_by_context": {"none": [chatter], "nc": [chatter] if k == 0 else [], "nc_in_cut": []}}
            for k in range(2)]
    out = score_programs(rows)
    assert out["false_alarms_per_10_h"] == 20.0 and out["by_context"]["none"]["false_alarms"] == 2   # 2 in 1 h
    assert out["by_context"]["nc"]["false_alarms_per_10_h"] == 10.0
    assert out["by_context"]["nc_in_cut"]["false_alarms"] == 0
    assert out["examples"][0]["chatter_frequency_hz"] == 790.0 and out["examples"][0]["overrides"] == [[4.7, 0.5]]


def test_a_csv_export_carries_the_context_as_text_percent_and_counts(tmp_path):
    from drivesense.io.csv import read_csv

    path = tmp_path / "trace.csv"
    path.write_text("time [s],x_current [A],execution,program_number,block_number,feed_override [%],tool_number\n"
                    "0.000,0.1,READY,PART_A.MPF,10,100,3\n"
                    "0.0011,0.2,ACTIVE,PART_A.MPF,10,100,3\n"
                    "0.0019,0.3,ACTIVE,PART_A.MPF,20,80,3\n"
                    "0.0030,0.4,FEED_HOLD,PART_A.MPF,20,80,3\n")
    rec = read_csv(path, resample=1000.0)              # irregular stamps: resampled, the context held
    np.testing.assert_allclose(rec["x_current"], [0.1, 0.1 + 0.1 / 1.1, 0.3 + 0.1 * 0.1 / 1.1, 0.4])
    np.testing.assert_array_equal(rec["block_number"], [10, 10, 20, 20])        # not 10.5 anywhere
    np.testing.assert_array_equal(rec["execution"], [0, 0, 1, 3])                # READY until 1.1 ms
    np.testing.assert_allclose(rec["feed_override"], [1.0, 1.0, 0.8, 0.8])
    assert np.all(rec["program_number"] == program_code("PART_A.MPF")) and np.all(rec["tool_number"] == 3)
    assert "the NC's context held" in " ".join(rec.meta["provenance"])
    path.write_text("time [s],x_current [A],execution\n0.000,0.1,ACTIVE\n0.001,0.2,RUNNING\n")
    with pytest.raises(InvalidSignalError, match="line 3, column 'execution': channel 'execution': unknown state"):
        read_csv(path)
