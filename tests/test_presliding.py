"""Presliding (Dahl) friction state of the linear-motor model: closed forms, step 5 of the identification,
and what it does for a standing axis and at reversals."""

from __future__ import annotations

import numpy as np
import pytest

from drivesense.bench.linear_axis import score_process
from drivesense.errors import ConfigError
from drivesense.estimate.model_based import ModelBased
from drivesense.identify.presliding import fit_presliding
from drivesense.io.axes_file import read_axes_file, write_axes_file
from drivesense.machine.linear_motor import ThreeAxisModel, linear_machine_model
from drivesense.machine.presliding import presliding_direction
from drivesense.sim.machining import simulate_process

TRUE = linear_machine_model()
X_PRE = 12e-6
WITH_PRE = ThreeAxisModel(**{a: TRUE.axis(a).with_values(x_pre=X_PRE) for a in "xyz"})


def test_direction_follows_the_closed_form_whatever_the_steps():
    """Travel D from d = 0 gives 1 - exp(-D/x_pre); back R from d gives -1 + (d + 1) exp(-R/x_pre)."""
    x = 10e-6
    for n in (2, 5, 400):                      # rate independence: the split of the travel does not matter
        fwd = np.linspace(0.0, 7e-6, n)
        d = presliding_direction(fwd, x)
        assert d[0] == 0.0
        assert d[-1] == pytest.approx(1 - np.exp(-0.7), rel=1e-12)
        back = np.linspace(7e-6, 2e-6, n)
        d2 = presliding_direction(back, x, previous_position=7e-6, direction=d[-1])
        assert d2[-1] == pytest.approx(-1 + (d[-1] + 1) * np.exp(-0.5), rel=1e-12)
    # a long slide saturates; standing still holds the state
    d = presliding_direction(np.r_[0.0, 1e-3, 1e-3, 1e-3], x)
    assert d[1] == pytest.approx(1.0) and d[2] == d[1] == d[3]


def test_direction_streams_like_batch_and_rejects_bad_values():
    rng = np.random.default_rng(1)
    s = np.cumsum(rng.normal(0, 2e-6, 500))
    whole = presliding_direction(s, 5e-6, direction=0.3)
    prev, d, parts = None, 0.3, []
    for a, b in ((0, 1), (1, 77), (77, 500)):
        part = presliding_direction(s[a:b], 5e-6, previous_position=prev, direction=d)
        prev, d = s[b - 1], part[-1]
        parts.append(part)
    assert np.array_equal(np.concatenate(parts), whole)
    assert np.all(np.abs(whole) <= 1.0)
    with pytest.raises(ConfigError, match="x_pre"):
        presliding_direction(s, 0.0)
    with pytest.raises(ConfigError, match="direction"):
        presliding_direction(s, 1e-6, direction=1.5)
    with pytest.raises(ConfigError, match="x_pre"):
        TRUE.x.with_values(x_pre=-1e-6)


def _reversing_moves(x_pre, level=50.0):
    t = np.arange(0, 4.0, 1 / 250)
    positions = [20e-6 * np.sin(2 * np.pi * 1.3 * t), 1e-3 * np.sin(2 * np.pi * 0.4 * t)]
    forces = [presliding_direction(p, x_pre) * level for p in positions]
    return positions, forces, [np.full(t.size, level)] * 2


def test_step5_recovers_the_presliding_distance_exactly():
    pos, frc, lev = _reversing_moves(7e-6)
    fit = fit_presliding(pos, frc, lev)
    assert fit["determined"] and fit["x_pre"] == pytest.approx(7e-6, rel=1e-3)
    assert fit["rms_n"] < 1e-3 * 50 and fit["samples"] == 2000


def test_step5_says_when_the_moves_cannot_determine_it():
    """Only fast one-way moves: every x_pre below a step explains them; x_pre stays 0."""
    pos = [np.arange(200) * 1e-4]            # 100 um per sample, never reverses
    frc = [np.r_[0.0, np.full(199, 50.0)]]
    fit = fit_presliding(pos, frc, [np.full(200, 50.0)])
    assert not fit["determined"] and fit["x_pre"] == 0.0


def test_axes_file_keeps_x_pre_and_reads_files_without_it(tmp_path):
    path = write_axes_file(tmp_path / "AXES.toml", WITH_PRE)
    assert read_axes_file(path).y.x_pre == X_PRE
    old = tmp_path / "old.toml"
    old.write_text("\n".join(line for line in path.read_text().splitlines() if not line.startswith("x_pre")))
    assert read_axes_file(old).y.x_pre == 0.0


@pytest.fixture(scope="module")
def groove_y():
    return simulate_process("groove_+y", 2e-3, 10e-3, 700 / 60e3, 5000, seed=3)


def test_standing_axis_force_held_by_the_guides_is_recovered(groove_y):
    """x stands still in a +y groove: presliding gets its force, the paper's sgn(v) cannot."""
    ours = score_process(ModelBased(WITH_PRE).estimate(groove_y), groove_y, "x")
    paper = score_process(ModelBased(WITH_PRE, presliding=False).estimate(groove_y), groove_y, "x")
    assert ours["nrmse"] < 0.04 and paper["nrmse"] > 0.08, (ours, paper)
    moving = score_process(ModelBased(WITH_PRE).estimate(groove_y), groove_y, "y")
    assert moving["nrmse"] < 0.05


def test_pocket_reversals_improve_and_stream_equals_batch():
    rec = simulate_process("pocket_ccw", 2e-3, 2e-3, 0.01, 4500, seed=4)
    est = ModelBased(WITH_PRE)
    batch = est.estimate(rec)
    assert "presliding (Dahl) on xyz" in batch.meta["provenance"][-1]
    paper = ModelBased(WITH_PRE, presliding=False).estimate(rec)
    for ax in "xy":
        assert score_process(batch, rec, ax)["rmse_n"] < 0.6 * score_process(paper, rec, ax)["rmse_n"]
    stream = est.stream(rec.fs)
    edges = [0, 1, 5, 250, 251, 999, rec.n_samples]
    parts = {c: [] for c in est.output_channels}
    for a, b in zip(edges[:-1], edges[1:]):
        for c, v in stream.push({c: rec[c][a:b] for c in est.channel_names}).items():
            parts[c].append(v)
    for c in est.output_channels:
        assert np.array_equal(np.concatenate(parts[c]), batch[c])
