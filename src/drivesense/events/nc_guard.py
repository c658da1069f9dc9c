"""When the detectors may judge: the NC's word where the stream carries its context, the drive signals' guess
where it does not.

A feed-override turn, the next block, a tool change or a feed hold changes
the force pattern without anything going wrong.  Without the NC's context a
detector can only infer such changes, from the path speed
(:func:`~drivesense.events.detector.feed_steady`) and from the force itself
(the breakage detector's drift check, the chatter detector's level guard),
and an inference is late or wrong at times: most false alarms of a monitor
fall where the process changed on command.  With the context channels
(:mod:`drivesense.nc_context`) the controller says so:

* for ``CONTEXT_SETTLE_S`` after any change of ``block_number``,
  ``tool_number``, ``program_number``, ``feed_override`` or
  ``spindle_override`` the detectors hold (and re-learn what is normal);
* while ``execution`` is not ``ACTIVE`` (a feed hold, a stop) they hold;
* where an ``in_cut`` channel says the tool is out of the material they hold.

The path-speed check still applies on top (the axes follow an override over
their ramp).  :func:`process_steady` returns the combined mask and records in
the detector's state which guards it used (``"nc_context"``,
``"feed_speed"`` or ``"none"``), which the events' evidence reports.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from drivesense.events.detector import feed_steady
from drivesense.nc_context import ACTIVE, CHANGE_CHANNELS, has_context

__all__ = ["CONTEXT_SETTLE_S", "nc_steady", "process_steady", "guard_source"]

#: How long the detectors hold after a commanded change [s]: the axes' override ramp (about 0.1 s) and the
#: cut's settling after it.
CONTEXT_SETTLE_S = 0.25


def nc_steady(chunk: Mapping[str, np.ndarray], state: dict) -> np.ndarray:
    """1.0 per sample where the NC's context says the process runs as programmed, else 0.0.

    Zero for ``CONTEXT_SETTLE_S`` from every change of a change channel
    (:data:`~drivesense.nc_context.CHANGE_CHANNELS`; the state keeps the last
    values and the samples since the last change, so chunks join seamlessly),
    where ``execution`` is not ``ACTIVE`` and where ``in_cut`` is 0.  All ones
    for a chunk without context channels.

    Parameters
    ----------
    chunk : mapping of str to ndarray
        The chunk's arrays [SI unit of each channel; the context channels dimensionless].
    state : dict
        The detector's state (holds ``"fs"``; the context's history is kept in it).
    """
    n = len(next(iter(chunk.values()))) if chunk else 0
    ok = np.ones(n)
    if n == 0:
        return ok
    settle = max(1, int(round(CONTEXT_SETTLE_S * state["fs"])))
    last = state.setdefault("nc_last", {})
    since = int(state.get("nc_since", settle))
    changed = np.zeros(n, dtype=bool)
    for name in CHANGE_CHANNELS:
        if name not in chunk:
            continue
        values = np.asarray(chunk[name], dtype=float)
        before = last.setdefault(name, float(values[0]))
        if values[-1] == before and values[0] == before and (values == before).all():
            continue                        # held throughout, as mostly: one comparison
        changed[0] |= values[0] != before
        changed[1:] |= values[1:] != values[:-1]
        last[name] = float(values[-1])
    if changed.any():
        idx = np.flatnonzero(changed)
        # samples since the latest change at or before each sample (the carried count before the first)
        latest = np.maximum.accumulate(np.where(changed, np.arange(n), -1))
        age = np.where(latest >= 0, np.arange(n) - latest, since + 1 + np.arange(n))
        state["nc_since"] = int(n - 1 - idx[-1])
        ok[age < settle] = 0.0
    else:                                   # no change here: only the end of an earlier one's hold
        ok[:max(0, settle - since - 1)] = 0.0
        state["nc_since"] = since + n
    state["nc_hold"] = ok.copy()            # the commanded changes alone (no state, no in-cut flag)
    if "execution" in chunk:
        ok[np.asarray(chunk["execution"], dtype=float) != ACTIVE] = 0.0
    if "in_cut" in chunk:
        ok[np.asarray(chunk["in_cut"], dtype=float) < 0.5] = 0.0
    return ok


def process_steady(chunk: Mapping[str, np.ndarray], state: dict, *, measured_feed: bool = True) -> np.ndarray:
    """The detectors' mask: the path-speed check, and the NC's context where the chunk carries it.

    Parameters
    ----------
    chunk : mapping of str to ndarray
        The chunk's arrays [SI unit of each channel].
    state : dict
        The detector's state (``"fs"``; histories kept in it; ``"guards"`` set to the source used).
    measured_feed : bool
        With the NC's context, also hold where the measured path speed is not steady (False: the NC's word
        alone -- for a detector whose own event, chatter, shakes the measured speed).  Without context the
        path-speed check always applies.

    Returns
    -------
    ndarray
        1.0 where the detector may judge, 0.0 where it holds.  With the NC's context, ``state["nc_hold"]``
        is 0.0 only for the hold after a commanded change the NC reported (block, tool, program, an
        override): a chatter spectrum must not span one.  Not the measured feed, which chatter itself
        shakes, nor a cut's start.  Without context it is absent.
    """
    feed = feed_steady(chunk, state)
    if has_context(chunk):
        state["guards"] = "nc_context"
        return feed * nc_steady(chunk, state) if measured_feed else nc_steady(chunk, state)
    state["guards"] = "feed_speed" if "feed_speed" in chunk else "none"
    state.pop("nc_hold", None)
    return feed


def guard_source(state: dict) -> str:
    """Which guards the detector used last (for an event's evidence): ``nc_context``, ``feed_speed`` or ``none``.

    Parameters
    ----------
    state : dict
        The detector's state (:func:`process_steady` records the source in it).
    """
    return str(state.get("guards", "none"))
