"""ModelBased (Eq. 2) under the estimator protocol, and ``drivesense estimate --method model``."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drivesense.bench.linear_axis import score_process
from drivesense.cli import app
from drivesense.errors import ConfigError, InvalidSignalError, MissingChannelError, NotFittedError
from drivesense.estimate.model_based import ModelBased
from drivesense.io import read_csv, write_recording
from drivesense.io.axes_file import write_axes_file
from drivesense.machine.linear_motor import linear_machine_model
from drivesense.sim.machining import simulate_process

TRUE = linear_machine_model()


@pytest.fixture(scope="module")
def groove():
    return simulate_process("groove_+x-y", 2e-3, 10e-3, 0.01, 5400, seed=11)


@pytest.mark.parametrize("process", ["groove_+x", "side_-y", "pocket_ccw", "ramp_-y+z"])
def test_exact_on_data_from_its_own_model(process):
    """With the simulator reduced to Eq. 2 (and the paper's sgn friction) the force comes back exactly."""
    rec = simulate_process(process, 2e-3, 5e-3, 0.01, 4500, seed=5, ideal=True)
    out = ModelBased(TRUE, v_eps=0.0).estimate(rec)
    assert out.meta["latency_s"] == 0.0 and out.fs == rec.fs and out.t0 == rec.t0
    for ax in "xyz":
        np.testing.assert_allclose(out[f"force_{ax}"], rec[f"force_{ax}"], atol=1e-6)


def test_full_physics_constant_feed_within_ten_percent(groove):
    out = ModelBased(TRUE).estimate(groove)
    assert out.meta["latency_s"] == groove.meta["nc_delay_s"] > 0
    for ax in "xy":
        assert score_process(out, groove, ax)["nrmse"] < 0.10


def test_stream_equals_batch_to_the_bit(groove):
    est = ModelBased(TRUE)
    batch = est.estimate(groove)
    stream = est.stream(groove.fs, delay_s=groove.meta["nc_delay_s"])
    edges = [0, 1, 2, 7, 64, 65, 300, 901, groove.n_samples]
    parts = {c: [] for c in est.output_channels}
    for a, b in zip(edges[:-1], edges[1:]):
        chunk = {c: groove[c][a:b] for c in est.channel_names}
        for c, v in stream.push(chunk).items():
            parts[c].append(v)
    for c in est.output_channels:
        assert np.array_equal(np.concatenate(parts[c]), batch[c])
    assert stream.samples_seen == groove.n_samples
    half = groove.t0 + groove.duration / 2
    first = stream.push(groove.slice_time(None, half))
    second = stream.push(groove.slice_time(half, None))
    assert first.t0 == groove.t0 and first.meta["latency_s"] == pytest.approx(groove.meta["nc_delay_s"])
    assert np.array_equal(np.concatenate([first["force_y"], second["force_y"]]), batch["force_y"])


def test_clear_errors(groove):
    est = ModelBased(TRUE)
    lacking = groove.select(*[c for c in groove.channels if c != "y_velocity"])
    with pytest.raises(MissingChannelError, match="'y_velocity'"):
        est.estimate(lacking)
    assert set(ModelBased(TRUE, axes=("x",)).estimate(lacking).channels) == {"force_x"}
    stream = est.stream(groove.fs)
    chunk = {c: groove[c][:10] for c in est.channel_names}
    with pytest.raises(MissingChannelError, match="'z_current'"):
        stream.push({k: v for k, v in chunk.items() if k != "z_current"})
    with pytest.raises(InvalidSignalError, match="'x_position' holds NaN"):
        stream.push({**chunk, "x_position": np.full(10, np.nan)})
    with pytest.raises(InvalidSignalError, match="'y_current' has 9 samples"):
        stream.push({**chunk, "y_current": chunk["y_current"][:9]})
    with pytest.raises(NotFittedError, match="no model"):
        ModelBased().estimate(groove)
    with pytest.raises(ConfigError, match="axes must be some of x, y, z"):
        ModelBased(TRUE, axes=("w",))
    with pytest.raises(ConfigError, match="nc_delay_s"):
        est.estimate(groove.with_meta(nc_delay_s=-1.0))


def test_cli_estimate_method_model(groove, tmp_path):
    runner = CliRunner()
    axes = write_axes_file(tmp_path / "AXES.toml", TRUE)
    write_recording(groove, tmp_path / "groove.nc")
    out = tmp_path / "force.csv"
    res = runner.invoke(app, ["estimate", str(tmp_path / "groove.nc"), "--method", "model", "--axes", str(axes),
                              "--out", str(out), "--json", str(tmp_path / "est.json"),
                              "--plot", str(tmp_path / "est.png")])
    assert res.exit_code == 0, res.output
    force = read_csv(out)
    assert force.channels == ["force_x", "force_y", "force_z"] and force.n_samples == groove.n_samples
    assert out.read_text().splitlines()[0] == "time [s],force_x [N],force_y [N],force_z [N]"
    assert list(pd.read_csv(out).columns) == ["time [s]", "force_x [N]", "force_y [N]", "force_z [N]"]
    assert force.meta["latency_s"] == pytest.approx(0.02)       # the estimate's metadata travels in the CSV
    info = json.loads((tmp_path / "est.json").read_text())
    assert info["score_vs_reference"]["force_y"]["nrmse"] < 0.10 and info["latency_s"] == pytest.approx(0.02)
    assert (tmp_path / "est.png").stat().st_size > 10_000
    # bad input: one line, exit 2
    for args, text in (([], "needs --axes"),
                       (["--axes", str(axes), "--idle", str(tmp_path / "groove.nc")], "takes no --idle/--tare"),
                       (["--axes", str(tmp_path / "nope.toml")], "does not exist")):
        res = runner.invoke(app, ["estimate", str(tmp_path / "groove.nc"), "--method", "model",
                                  "--out", str(tmp_path / "bad.csv"), *args])
        assert res.exit_code == 2 and text in res.output and res.output.count("\n") == 1, res.output
    write_recording(groove.select("x_current", "x_position"), tmp_path / "thin.nc")
    res = runner.invoke(app, ["estimate", str(tmp_path / "thin.nc"), "--method", "model", "--axes", str(axes),
                              "--out", str(tmp_path / "bad.csv")])
    assert res.exit_code == 2 and "x_velocity" in res.output
    assert not (tmp_path / "bad.csv").exists()


def test_bench_in_the_shape_of_table_2(tmp_path):
    from drivesense.bench.linear_axis import run_linear_axis_bench

    labels = []
    res = run_linear_axis_bench(labels.append, cases=(("groove_+x", 10, 2, 800, 5400), ("pocket_ccw", 2, 2, 600, 4500)),
                                figure=tmp_path / "pocket.png")
    json.dumps(res)
    assert labels == ["identify", "groove_+x", "pocket_ccw"]
    rows = {(r["process"], r["axis"]): r for r in res["linear_axis"]}
    assert set(rows) == {("groove_+x", "x"), ("groove_+x", "y"), ("pocket_ccw", "x"), ("pocket_ccw", "y"),
                         ("pocket_ccw", "z")}
    assert rows[("groove_+x", "x")]["moving"] and not rows[("groove_+x", "y")]["moving"]
    assert {"rmse_n", "nrmse", "max_abs_force_n"} <= set(rows[("pocket_ccw", "x")])
    pocket_y = rows[("pocket_ccw", "y")]
    assert pocket_y["reversals"] == 2 and pocket_y["rmse_reversal_n"] > pocket_y["rmse_elsewhere_n"]
    assert res["linear_summary"]["constant_feed_within_target"] and res["linear_identify"]["all_within_targets"]
    assert res["linear_identify_seconds"]["x"] < 10.0
    assert (tmp_path / "pocket.png").stat().st_size > 10_000
