"""Breakage named right: a full tooth loss reads as breakage with its edge loss near 1, a partial loss as
chipping near its truth, and the naming (one revolution after the detection) streams as it runs in batch."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from drivesense.bench.events_cases import Case
from drivesense.events.breakage import BreakageDetector
from drivesense.events.edge_loss import fit_edge_loss, pattern_bins
from drivesense.events.pipeline import detector_inputs
from drivesense.sim.process_events import ProcessEvent, simulate_event_cut

RPM = 5000.0


@functools.lru_cache(maxsize=None)
def _cut(teeth: int, kind: str, loss: float, runout: float = 0.0, ae: float = 6e-3, seed: int = 3):
    """Detector inputs (true force) of a cut with one damaged tooth, and the event's time [s]."""
    base = Case(kind, teeth, RPM, ae, "down", 1e-3, runout, seed, 0.0)
    t_ev = base.full_engagement_s + 0.4
    case = Case(kind, teeth, RPM, ae, "down", 1e-3, runout, seed, t_ev + 0.25,
                events=(ProcessEvent(kind, t_ev, flute=seed % teeth, edge_loss=loss),))
    rec = simulate_event_cut(case.condition(), events=case.events, settings=case.settings(), seed=seed)
    return detector_inputs(rec, rec.select("force_x", "force_y")), t_ev


def _first_after(events, t_ev):
    late = [e for e in events if e.time_s >= t_ev - 1e-9]
    assert late, "nothing detected after the damage"
    return late[0]


@pytest.mark.parametrize("teeth", [3, 6])
@pytest.mark.parametrize("axis", ["x", "y"])
def test_full_tooth_loss_in_a_slot_is_breakage(teeth, axis):
    inputs, t_ev = _cut(teeth, "breakage", 1.0)
    events = BreakageDetector(axis, teeth).detect(inputs)
    assert not [e for e in events if e.time_s < t_ev - 1e-9]
    ev = _first_after(events, t_ev)
    assert ev.kind == "breakage"
    assert abs(ev.evidence["edge_loss"] - 1.0) <= 0.2
    assert ev.evidence["edge_loss_from"] == "pulse fit"
    revs = (ev.time_s - t_ev) * RPM / 60.0
    assert 0.0 <= revs <= 2.0                                  # the detection's time, not the naming's
    assert 0.0 < ev.evidence["named_after_s"] <= 1.05 * 60.0 / RPM


def test_half_edge_lost_is_chipping():
    inputs, t_ev = _cut(3, "chipping", 0.5)
    ev = _first_after(BreakageDetector("y", 3).detect(inputs), t_ev)
    assert ev.kind == "chipping"
    assert abs(ev.evidence["edge_loss"] - 0.5) <= 0.2


def test_naming_streams_in_odd_chunks_as_in_batch():
    inputs, t_ev = _cut(3, "breakage", 1.0)
    det = BreakageDetector("x", 3)
    first = _first_after(det.detect(inputs), t_ev)
    # the NC's block changes between the detection and the naming a revolution later: the event carries the
    # block at its sample, in batch and streamed alike
    arrays = {c: inputs[c] for c in inputs.channels}
    at_block = int(round((first.time_s - inputs.t0) * inputs.fs)) + 5
    arrays["block_number"] = np.where(np.arange(inputs.n_samples) < at_block, 20.0, 30.0)
    batch = det.stream(inputs.fs, t0=inputs.t0).push_arrays(arrays).events
    assert _first_after(batch, t_ev).evidence["block_number"] == 20
    stream = det.stream(inputs.fs, t0=inputs.t0)
    n = inputs.n_samples
    sizes = [1, 7, 0, 333, 1, 1001, 59, 4096]
    streamed, at, k = [], 0, 0
    while at < n:
        m = sizes[k % len(sizes)]
        k += 1
        streamed += stream.push_arrays({c: v[at:at + m] for c, v in arrays.items()}).events
        at += m
    assert [(e.kind, e.time_s) for e in streamed] == [(e.kind, e.time_s) for e in batch]
    for s, b in zip(streamed, batch):
        assert s.evidence == b.evidence


def test_fit_reads_a_synthetic_loss_with_overlapping_pulses():
    # six teeth in a slot: every angle is cut by three teeth at once; tooth 0 loses 70 % of its edge
    teeth, nb = 6, pattern_bins(6)
    theta = (np.arange(nb) + 0.5) / nb * 2 * np.pi

    def pulse(shift, chip, edge):
        phi = (theta - shift) % (2 * np.pi)
        inside = phi <= np.pi
        return inside * (chip * np.sin(phi) * (-700 * np.cos(phi) - 250 * np.sin(phi))
                         + edge * (-20 * np.cos(phi) - 10 * np.sin(phi)))

    pitch = 2 * np.pi / teeth
    base = sum(pulse(m * pitch, 1.0, 1.0) for m in range(teeth))
    after = base - 0.7 * pulse(0.0, 1.0, 1.0) + 0.7 * pulse(pitch, 1.0, 0.0)
    fit = fit_edge_loss(base, np.ones(nb), after, np.ones(nb), teeth)
    assert fit is not None and abs(fit.edge_loss - 0.7) <= 0.1
