"""``drivesense plot``: one PNG with the time trace and the amplitude spectrum (Fig. 16), over wavelength on request."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.cli.plot_cmd import feed_speed_of
from drivesense.errors import ConfigError
from drivesense.io.xml_format import write_xml
from drivesense.plot import plot_trace_spectrum, save_figure
from drivesense.recording import Recording
from drivesense.io import write_recording

runner = CliRunner()
FEED = 0.002  # m/s (120 mm/min)
WAVE = 0.0005  # m: a ripple fixed in position


@pytest.fixture(scope="module")
def feed_rec() -> Recording:
    """An axis feeding at FEED after a 0.2 s dwell, with a current ripple of wavelength WAVE and a 50 Hz hum."""
    fs, n = 5000.0, 20_000
    t = np.arange(n) / fs
    x = np.where(t < 0.2, 0.0, FEED * (t - 0.2))
    cur = 0.3 + 0.05 * np.sin(2 * np.pi * x / WAVE) + 0.02 * np.sin(2 * np.pi * 50 * t)
    noise = np.random.default_rng(0).normal(0, 1e-7, n)
    return Recording.from_arrays({"x_current": cur, "x_table_position": x + noise, "spindle_speed": np.full(n, 104.7)},
                                 fs=fs, meta={"name": "ripple"})


def _png(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def test_feed_speed_from_the_position_while_moving(feed_rec):
    speed, how = feed_speed_of(feed_rec, "x_current")
    assert speed == pytest.approx(FEED, rel=1e-3) and "x_table_position" in how
    speed, _ = feed_speed_of(feed_rec, "spindle_speed")  # no axis in the name: the moving axis is found
    assert speed == pytest.approx(FEED, rel=1e-3)
    bare = feed_rec.select("spindle_speed").with_meta(condition={"feed_speed": 0.001})
    assert feed_speed_of(bare, "spindle_speed") == (0.001, "meta condition.feed_speed")
    with pytest.raises(ConfigError, match="give --feed"):
        feed_speed_of(feed_rec.select("spindle_speed"), "spindle_speed")


def test_wavelength_axis_puts_the_ripple_at_its_wavelength(feed_rec, tmp_path, monkeypatch):
    import matplotlib.axes

    seen = {}

    def spy(self, x, y, *a, **kw):
        seen["x"], seen["y"] = np.asarray(x), np.asarray(y)
        return orig(self, x, y, *a, **kw)

    orig = matplotlib.axes.Axes.loglog
    monkeypatch.setattr(matplotlib.axes.Axes, "loglog", spy)
    rec = feed_rec.slice_time(0.2, None)
    feed, how = feed_speed_of(rec, "x_current")
    fig = plot_trace_spectrum(rec, "x_current", wavelength=True, feed_speed=feed, feed_source=how)
    assert "x_table_position" in fig.axes[1].get_xlabel()
    path = save_figure(fig, tmp_path / "w.png")
    assert _png(path) == (1100, 770)
    peak = seen["x"][np.argmax(seen["y"])]
    assert peak == pytest.approx(WAVE * 1e3, rel=0.02)  # [mm]


def test_cli_plot_time_and_spectrum(feed_rec, tmp_path):
    write_recording(feed_rec, tmp_path / "r.nc")
    res = runner.invoke(app, ["plot", str(tmp_path / "r.nc"), "--channel", "x_current"])
    assert res.exit_code == 0, res.output
    assert _png(tmp_path / "r_x_current.png") == (1100, 770)
    res = runner.invoke(app, ["plot", str(tmp_path / "r.nc"), "-c", "x_current", "--wavelength", "--feed", "0.002",
                              "--out", str(tmp_path / "w.png")])
    assert res.exit_code == 0 and (tmp_path / "w.png").is_file()
    res = runner.invoke(app, ["plot", str(tmp_path / "r.nc"), "-c", "x_current", "--max-freq", "200",
                              "--out", str(tmp_path / "sub" / "f.png")])
    assert res.exit_code == 2 and "--out: folder" in res.output and not (tmp_path / "sub").exists()   # not created
    (tmp_path / "sub").mkdir()
    res = runner.invoke(app, ["plot", str(tmp_path / "r.nc"), "-c", "x_current", "--max-freq", "200",
                              "--out", str(tmp_path / "sub" / "f.png")])
    assert res.exit_code == 0 and (tmp_path / "sub" / "f.png").is_file()


def test_cli_plot_reads_experiment_files(feed_rec, tmp_path):
    write_xml([feed_rec, feed_rec.with_meta(name="second")], tmp_path / "e.xml")
    res = runner.invoke(app, ["plot", str(tmp_path / "e.xml"), "-c", "x_current", "--measurement", "second",
                              "--out", str(tmp_path / "e.png")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["plot", str(tmp_path / "e.xml"), "-c", "x_current"])
    assert res.exit_code == 2 and "choose one" in res.output


@pytest.mark.parametrize("args, message", [
    (["-c", "force_z"], "lacks channel(s) 'force_z'"),
    (["-c", "spindle_speed", "--wavelength"], None),  # the moving x axis gives the feed
    (["-c", "x_current", "--wavelength", "--feed", "-1"], "--feed must be a positive speed"),
    (["-c", "x_current", "--measurement", "1"], "--measurement applies to .xml"),
])
def test_cli_plot_bad_input_is_one_line(feed_rec, tmp_path, args, message):
    write_recording(feed_rec, tmp_path / "r.nc")
    res = runner.invoke(app, ["plot", str(tmp_path / "r.nc"), *args, "--out", str(tmp_path / "o.png")])
    if message is None:
        assert res.exit_code == 0, res.output
        return
    assert res.exit_code == 2 and message in res.output and "Traceback" not in res.output
    res = runner.invoke(app, ["plot", str(tmp_path / "missing.nc"), "-c", "x"])
    assert res.exit_code == 2


def test_cli_plot_takes_bare_channel_names_like_estimate(feed_rec, tmp_path):
    write_recording(feed_rec, tmp_path / "feed.nc")
    res = runner.invoke(app, ["plot", str(tmp_path / "feed.nc"), "-c", "current", "--out", str(tmp_path / "c.png")])
    assert res.exit_code == 0, res.output
    assert _png(tmp_path / "c.png")[0] > 500
    (tmp_path / "y.csv").write_text("time [ms],current_ref [A]\n" + "".join(f"{k},{k % 3}\n" for k in range(64)))
    res = runner.invoke(app, ["plot", str(tmp_path / "y.csv"), "-c", "current_ref", "--axis-name", "y",
                              "--out", str(tmp_path / "y.png")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["plot", str(tmp_path / "y.csv"), "-c", "position", "--out", str(tmp_path / "n.png")])
    assert res.exit_code == 2 and "x_position" in res.output


def test_all_zero_channel_plots_without_a_warning(tmp_path, recwarn):
    rec = Recording.from_arrays({"force_x": np.zeros(256), "x_table_position": np.linspace(0, 1e-3, 256)}, fs=1000.0)
    for wavelength in (False, True):
        fig = plot_trace_spectrum(rec, "force_x", wavelength=wavelength, feed_speed=0.01 if wavelength else None)
        save_figure(fig, tmp_path / f"zero_{wavelength}.png")
        low, high = fig.axes[1].get_ylim()
        assert low < 0 < high and np.isfinite([low, high]).all()
        assert any("constant" in t.get_text() for t in fig.axes[1].texts)
    assert not [w for w in recwarn if issubclass(w.category, UserWarning)], [str(w.message) for w in recwarn]
    write_recording(rec, tmp_path / "zero.nc")
    res = runner.invoke(app, ["plot", str(tmp_path / "zero.nc"), "-c", "force_x", "--out", str(tmp_path / "z.png")])
    assert res.exit_code == 0 and "Warning" not in res.output, res.output
