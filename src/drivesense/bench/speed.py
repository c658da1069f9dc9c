"""Speed benchmark, reported as ratios to baselines measured in the same run.

* estimator: a 60 s, 10 kHz trace through ``VibrationMode.estimate`` against
  one 4th-order ``scipy.signal.sosfilt`` pass over the same samples;
* streaming: the same trace pushed in 1 ms chunks, its deviation from batch,
  and the size of the carried state;
* simulator: simulated seconds per wall-clock second, sub-steps included;
* memory: the peak of batch estimation (tracemalloc).
"""

from __future__ import annotations

import time
import tracemalloc
from dataclasses import replace

import numpy as np
from scipy import signal as sps

from drivesense.estimate import SignalParams, make
from drivesense.estimate.design import lowpass_sos
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.sim.scenarios import ScenarioSettings, paper_conditions, simulate_cut

__all__ = ["run_speed"]


def _best(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run_speed(axis: BallScrewAxis, signal: SignalParams, *, duration: float = 60.0, repeats: int = 5) -> dict:
    """Measure the speed figures of the bench JSON.

    Parameters
    ----------
    axis, signal
        Estimator parameters.
    duration : float
        Length of the benchmark trace [s].
    repeats : int
        Timing repetitions (best is reported).

    Returns
    -------
    dict
        ``estimator_realtime_factor``, ``estimator_vs_sosfilt``,
        ``stream_realtime_factor`` (fast path), ``stream_push_realtime_factor`` (checked push), ``stream_max_dev_n``,
        ``simulator_realtime_factor``, ``estimator_peak_mb``,
        ``stream_state_bytes`` and the raw timings [s].
    """
    cond = next(c for c in paper_conditions() if c.direction == "feed")
    settings = replace(ScenarioSettings(), duration=duration)
    simulate_cut(cond, replace(settings, duration=1.0), seed=0)  # compile
    t_sim = _best(lambda: simulate_cut(cond, settings, seed=0), max(1, repeats // 2))
    rec = simulate_cut(cond, settings, seed=0)
    est = make("vibration", axis=axis, signal=signal)
    est.estimate(rec)  # warm-up
    t_est = _best(lambda: est.estimate(rec), repeats)
    sos = lowpass_sos(signal, rec.fs)
    x = rec["x_current_ref"]
    t_sos = _best(lambda: sps.sosfilt(sos, x), repeats)
    batch = est.estimate(rec)["force_x"]

    tracemalloc.start()
    est.estimate(rec)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    current, angle, table = (np.ascontiguousarray(rec[c]) for c in est.channel_names)
    chunk = int(round(rec.fs * 1e-3))
    n = current.size

    names = est.channel_names

    def stream_all():
        """The fast path: arrays in channel order, unchecked."""
        st = est.stream(rec.fs)
        out = np.empty(n)
        for k in range(0, n, chunk):
            out[k:k + chunk] = st.push_arrays(current[k:k + chunk], angle[k:k + chunk],
                                              table[k:k + chunk])["force_x"]
        return st, out

    def stream_checked():
        """The contract's push: a mapping per chunk, checked (channels, lengths, finite values)."""
        st = est.stream(rec.fs)
        out = np.empty(n)
        for k in range(0, n, chunk):
            out[k:k + chunk] = st.push({names[0]: current[k:k + chunk], names[1]: angle[k:k + chunk],
                                        names[2]: table[k:k + chunk]})["force_x"]
        return out

    stream_all()
    t0 = time.perf_counter()
    st, streamed = stream_all()
    t_stream = time.perf_counter() - t0
    t0 = time.perf_counter()
    checked = stream_checked()
    t_checked = time.perf_counter() - t0
    state = st.state
    state_bytes = int(state.hist.nbytes + state.zi.nbytes + state.scalars.nbytes)
    return {
        "trace_seconds": duration,
        "estimator_seconds": t_est,
        "sosfilt_seconds": t_sos,
        "estimator_realtime_factor": duration / t_est,
        "estimator_vs_sosfilt": t_est / t_sos,
        "stream_chunk_ms": 1.0,
        "stream_seconds": t_stream,
        "stream_realtime_factor": duration / t_stream,
        "stream_max_dev_n": float(np.max(np.abs(streamed - batch))),
        "stream_push_realtime_factor": duration / t_checked,
        "stream_push_max_dev_n": float(np.max(np.abs(checked - batch))),
        "stream_state_bytes": state_bytes,
        "simulator_seconds": t_sim,
        "simulator_realtime_factor": duration / t_sim,
        "estimator_peak_mb": peak / 2**20,
    }
