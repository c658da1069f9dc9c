"""A publisher that restarts (a new ``session`` on the wire, ``seq`` and often its clock from 0 again).

Before sessions, every chunk of the new run looked older than the last one and was refused, so the machine
went unwatched until the service restarted.  Now the machine's stream starts afresh -- exactly as a new
monitor would -- and a fleet worker that takes the machine over tells the runs apart in the claim's mark.
"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from drivesense.monitor.fleet import MachineClaim
from drivesense.monitor.mqtt import MQTTSource
from drivesense.monitor.wire import Chunk, StreamCursor, WireError, decode_chunk, encode_chunk


@pytest.fixture(scope="module")
def demo():
    """The demo machine's axes and a 4 s cut whose flute breaks at about 2.16 s, as drive-signal chunks."""
    from drivesense.monitor.demo import demo_machine
    from drivesense.monitor.sources import SimulatedSource

    rec = SimulatedSource("m", cut_s=4.0).simulate_cut(1)
    assert [e["kind"] for e in rec.meta["truth"]["events"]] == ["breakage"]
    signal = {c: rec[c] for c in rec.channels if not c.startswith("force_")}
    return demo_machine(speed=0.0).monitor.axes, signal, rec.fs


def _run(signal: dict, fs: float, session: str | None, n: int = 500) -> list[Chunk]:
    """The signal as one publisher run: seq and clock from 0."""
    size = len(next(iter(signal.values())))
    return [Chunk("m", k, i / fs, fs, {c: v[i:i + n] for c, v in signal.items()}, session=session)
            for k, i in enumerate(range(0, size, n))]


def test_the_session_travels_on_the_wire_and_a_bad_one_is_refused():
    arrays = {"x_current": np.arange(4.0)}
    assert decode_chunk(encode_chunk("m", 3, 0.0, 1e3, arrays, session="5f0c2a91d3e4")).session == "5f0c2a91d3e4"
    assert decode_chunk(encode_chunk("m", 3, 0.0, 1e3, arrays)).session is None       # optional
    with pytest.raises(WireError, match="session"):
        encode_chunk("m", 3, 0.0, 1e3, arrays, session="a b")
    msg = encode_chunk("m", 3, 0.0, 1e3, arrays, session="x" * 12).replace(b'"' + b"x" * 12 + b'"', b'"abcdef/ghijk"')
    with pytest.raises(WireError, match="'session' is invalid"):
        decode_chunk(msg)


def test_the_cursor_tells_next_old_and_restart():
    def c(seq, session=None):
        return Chunk("m", seq, 0.0, 1e3, {}, session=session)
    cur = StreamCursor()
    assert cur.place(c(5, "a")) == "next"
    cur.advance(c(5, "a"))
    assert [cur.place(x) for x in (c(6, "a"), c(5, "a"), c(0, "a"), c(0, "b"), c(0))] == [
        "next", "old", "old", "restart", "restart"]
    cur.advance(c(0, "b"))
    assert (cur.session, cur.seq, cur.restarts) == ("b", 0, 1)
    assert cur.place(c(9, "a")) == "old"                           # a late chunk of the run that ended
    plain = StreamCursor(None, 40)                                 # no sessions: seq 0 again is a repeat
    assert plain.place(c(0)) == "old" and plain.place(c(41)) == "next"


def test_a_restarted_publisher_is_monitored_afresh_with_its_own_event_ids(demo):
    from drivesense.monitor.machine import MachineMonitor

    axes, signal, fs = demo
    first, second = _run(signal, fs, "a"), _run(signal, fs, "b")    # the second run's clock starts at 0 again
    mon = MachineMonitor("m", axes)
    ids_a = [r["id"] for c in first for r in mon.process(c)]
    ids_b = [r["id"] for c in second[:5] for r in mon.process(c)]
    assert mon.process(first[-1]) == [] and mon.rejected == 1         # a late chunk of the ended run: refused
    ids_b += [r["id"] for c in second[5:] for r in mon.process(c)]
    fresh = MachineMonitor("m", axes)
    ids_fresh = [r["id"] for c in second for r in fresh.process(c)]
    assert ids_a and all(i.endswith("@a") for i in ids_a)
    assert ids_b == ids_fresh and all(i.endswith("@b") for i in ids_b)          # as a new monitor would
    assert [i.split("@")[0] for i in ids_b] == [i.split("@")[0] for i in ids_a]  # same signal, same times
    st = mon.status()
    assert (st["publisher_restarts"], st["session"], st["rejected"], st["gaps"]) == (1, "b", 1, 0)
    assert st["samples"] == 2 * len(signal["x_current"])


def test_without_sessions_seq_0_again_is_refused_and_the_message_says_why(demo):
    from drivesense.monitor.machine import MachineMonitor

    axes, signal, fs = demo
    chunks = _run(signal, fs, None)
    mon = MachineMonitor("m", axes)
    for c in chunks[:10]:
        mon.process(c)
    mon.process(chunks[0])
    assert mon.rejected == 1 and "must name a new 'session'" in mon.last_error


def test_a_claim_primes_only_the_marked_run(tmp_path):
    async def main():
        a = MachineClaim(tmp_path, "m", "w1")
        await a.acquire()
        a.release(57, "b")
        b = MachineClaim(tmp_path, "m", "w2")
        await b.acquire()
        assert (b.prime_through, b.prime_session) == (57, "b")
        chunk = lambda seq, session: Chunk("m", seq, 0.0, 1e3, {}, session=session)   # noqa: E731
        assert b.priming(chunk(50, "b")) and not b.priming(chunk(58, "b"))
        assert not b.priming(chunk(3, "c"))          # the publisher restarted since the mark: all of it is new
        b.release(None)
    asyncio.run(main())


class _Link:
    """Stands in for a broker connection: records acknowledgements."""

    def __init__(self) -> None:
        self.acked: list[int] = []

    def ack(self, mid: int) -> None:
        self.acked.append(mid)


def test_held_chunks_of_an_ended_run_are_acknowledged_once_processed():
    """Without this the old run's high seqs would never fall under the new run's mark: the held messages
    would pile up to the broker's receive maximum and stall the machine."""
    src = MQTTSource("m", "mqtt://127.0.0.1:1", hold_s=1.0)
    link = _Link()
    run_a = [Chunk("m", 100 + k, 50.0 + 0.05 * k, 1e4, {"x_current": np.zeros(500)}, session="a") for k in range(10)]
    run_b = [Chunk("m", k, 0.05 * k, 1e4, {"x_current": np.zeros(500)}, session="b") for k in range(5)]
    for mid, c in enumerate(run_a + run_b):
        assert src._hold(link, mid, c)
        src.processed()
    src.settle(4)                                    # the mark: run b's seq 4
    assert link.acked == list(range(10))             # all of run a; run b's last second stays held
    assert not src._hold(link, 99, run_a[3])         # a late copy of run a: dropped, acknowledged
    assert link.acked[-1] == 99
