"""``drivesense.plot``: every figure is a pyplot-free Figure that saves to a PNG, the backend is never touched,
and no module outside the package draws (or imports matplotlib)."""

from __future__ import annotations

import ast
import inspect
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

import drivesense as ds
import drivesense.plot as ds_plot
from drivesense.errors import ConfigError
from drivesense.plot import save_figure
from drivesense.recording import Recording

SRC = Path(ds.__file__).parent
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == PNG_MAGIC
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


# ------------------------------------------------------------------ small inputs
def _force_recordings():
    """A 2 s trace with reference forces x, y and an estimate of x, y, z (2 ms late, 1 % off)."""
    fs, n = 1000.0, 2000
    t = np.arange(n) / fs
    rng = np.random.default_rng(0)
    fx, fy = 50 * np.sin(2 * np.pi * 7 * t), 20 * np.cos(2 * np.pi * 3 * t)
    trace = Recording.from_arrays({"force_x": fx, "force_y": fy}, fs=fs,
                                  meta={"name": "synthetic", "score_window": (0.5, 2.0)})
    lag = 2
    est = Recording.from_arrays({"force_x": 1.01 * np.roll(fx, lag) + rng.normal(0, 0.5, n),
                                 "force_y": np.roll(fy, lag), "force_z": rng.normal(0, 0.5, n)},
                                fs=fs, meta={"latency_s": lag / fs})
    return trace, est


def _estimates():
    trace, est = _force_recordings()
    return ds_plot.plot_estimates(trace, {"rigid": est, "vibration": est}, channel="force_x", zoom_s=0.5,
                                  max_freq=100.0)


def _force_estimate():
    trace, est = _force_recordings()
    return ds_plot.plot_force_estimate(trace, est, title="estimate vs reference")


def _pocket_estimate():
    return ds_plot.plot_pocket_estimate(*_force_recordings())


def _friction_maps():
    x = np.arange(400) * 1e-6
    rng = np.random.default_rng(1)
    base = 5 + 0.3 * np.sin(2 * np.pi * x / 50e-6)
    runs = base + rng.normal(0, 0.05, (3, x.size))
    runs[0, :3] = np.nan                                    # a run that missed the first bins
    fmap = ds.FrictionMap(x, np.nanmean(runs, axis=0), np.nanstd(runs, axis=0), runs, 1, "rigid")
    return ds_plot.plot_friction_maps({"rigid": fmap, "vibration": fmap}, title="friction")


def _frf_fit():
    from drivesense.identify.frf import MeasuredFRF, fit_frf, model_frf

    axis = ds.table1_axis()
    f = np.linspace(5.0, 2000.0, 200)
    gm, gt = model_frf(axis, f, T_a=0.2e-3, T_b=0.2e-3, omega_cc=5000.0, fs=1e4)
    coh = np.full(f.size, 0.9999)
    fit = fit_frf(MeasuredFRF(f, gm, gt, coh, coh, 10, 1e4, "excitation"), K_t=axis.K_t, lead=axis.lead)
    return ds_plot.plot_frf_fit(fit)


def _calibration():
    omega = 1068.0 * 2 * math.pi / 60
    cuts = [ds.CutConditions(12.7e-3, 1, 2.54e-3, omega, f, math.radians(a), math.pi)
            for a in (0, 60, 90, 120) for f in (19e-6, 28e-6, 33e-6, 40e-6)]
    fit = ds.calibrate_from_power(cuts, ds.cutting_power(2100e6, 35e3, cuts))
    return ds_plot.plot_calibration(fit, title="calibration")


def _identification():
    v = np.array([-8e-3, -3e-3, -1e-3, 1e-3, 3e-3, 8e-3])
    steps = {ax: {"friction": {"data": {"velocity_m_s": v.tolist(), "force_n": (20 * np.sign(v) + 500 * v).tolist()}}}
             for ax in "xyz"}
    steps["z"]["friction"] = {}                              # an axis without segment means
    return ds_plot.plot_identification(ds.IdentificationReport(ds.linear_machine_model(), steps))


def _feed_power():
    cuts = ds.read_feed_cuts(Path(__file__).parent / "data" / "feed_power_table3.csv")
    model = ds.fit_feed_power(cuts)
    return ds_plot.plot_feed_power(cuts, model, ds.per_speed_fits(cuts), title="feed power")


def _sensor_calibration():
    pairs = [ds.simulate_shaker_pair(a, fs=22050.0, duration=1.0, seed=k) for k, a in enumerate((1.3, 3.0))]
    return ds_plot.plot_sensor_calibration(ds.calibrate_sensor(pairs, nperseg=2048))


def _wear_track():
    life = ds.simulate_tool_life("A", 1)
    report = ds.track_wear(life.table, reference=life.reference_index)
    return ds_plot.plot_wear_track(report, failure_distance=float(report.states[-1].distance))


def _ripple():
    fs, n = 5000.0, 10_000
    t = np.arange(n) / fs
    return Recording.from_arrays({"x_current": 0.3 + 0.05 * np.sin(2 * np.pi * 120 * t)}, fs=fs, meta={"name": "r"})


def _trace_spectrum():
    return ds_plot.plot_trace_spectrum(_ripple(), "x_current", max_freq=500.0)


def _trace_wavelength():
    return ds_plot.plot_trace_spectrum(_ripple(), "x_current", wavelength=True, feed_speed=0.002,
                                       feed_source="test")


def _events():
    from drivesense.events import OverloadDetector, run_detectors

    fs = 10_000.0
    t = np.arange(int(fs)) / fs
    force = 20.0 * np.abs(np.sin(2 * np.pi * 50 * t)) + np.where(t > 0.6, 400.0, 0.0)
    rec = Recording.from_arrays({"force_x": force}, fs=fs, meta={"name": "f"})
    report = run_detectors(rec, [OverloadDetector("x", 300.0)])
    return ds_plot.plot_events(rec, report, truth=[{"kind": "collision", "time_s": 0.6}])


def _stability_lobes():
    from drivesense.machine.milling import CuttingCoefficients
    from drivesense.machine.stability import stability_lobes
    from drivesense.machine.tool_dynamics import ToolDynamics

    lobes = stability_lobes(ToolDynamics.symmetric(600.0, 0.03, 5e6), CuttingCoefficients.aluminium(), 2, 0.0,
                            np.pi, rpm_range=(2000.0, 12000.0), points=400)
    return ds_plot.plot_stability_lobes(lobes, cuts=[(4000.0, 2e-4, "stable"), (6000.0, 2e-3, "chatter")])


FIGURES = {
    "plot_events": (_events, None),
    "plot_stability_lobes": (_stability_lobes, (990, 660)),
    "plot_estimates": (_estimates, (1100, 990)),
    "plot_force_estimate": (_force_estimate, (990, 924)),
    "plot_pocket_estimate": (_pocket_estimate, (990, 638)),
    "plot_friction_maps": (_friction_maps, (1210, 704)),
    "plot_frf_fit": (_frf_fit, (990, 990)),
    "plot_calibration": (_calibration, (770, 550)),
    "plot_identification": (_identification, (1320, 715)),
    "plot_feed_power": (_feed_power, (1320, 550)),
    "plot_sensor_calibration": (_sensor_calibration, (990, 990)),
    "plot_wear_track": (_wear_track, (990, 990)),
    "plot_trace_spectrum": (_trace_spectrum, (1100, 770)),
    "plot_trace_spectrum_wavelength": (_trace_wavelength, (1100, 770)),
}


def test_every_public_plot_function_is_covered():
    public = {n for n in ds_plot.__all__ if n.startswith("plot_")}
    assert public <= set(FIGURES)
    assert set(ds_plot.__all__) == public | {"save_figure"}


@pytest.mark.parametrize("name", list(FIGURES))
def test_plot_returns_a_figure_that_saves_to_png(name, tmp_path):
    make, size = FIGURES[name]
    fig = make()
    assert isinstance(fig, Figure)
    assert fig.axes and all(ax.has_data() for ax in fig.axes)
    path = save_figure(fig, tmp_path / "out" / f"{name}.png")
    assert path == tmp_path / "out" / f"{name}.png"
    assert path.stat().st_size > 10_000
    if size is not None:
        assert _png_size(path) == size
    assert [p.name for p in path.parent.iterdir()] == [path.name]     # no temporary file left behind


def test_force_estimate_titles_carry_the_scores():
    fig = _force_estimate()
    titles = [ax.get_title() for ax in fig.axes]
    assert titles[0].startswith("x: RMSE") and "NRMSE" in titles[0] and titles[2] == "z"
    assert [ax.get_ylabel() for ax in fig.axes] == ["F_x [N]", "F_y [N]", "F_z [N]"]


def test_wavelength_spectrum_needs_a_feed_speed():
    with pytest.raises(ConfigError, match="positive feed speed"):
        ds_plot.plot_trace_spectrum(_ripple(), "x_current", wavelength=True)
    with pytest.raises(ConfigError, match="positive feed speed"):
        ds_plot.plot_trace_spectrum(_ripple(), "x_current", wavelength=True, feed_speed=-1.0)


# ------------------------------------------------------------------ save_figure
def test_save_figure_replaces_atomically_and_keeps_the_old_file_on_error(tmp_path):
    fig = _trace_spectrum()
    target = tmp_path / "a" / "b" / "f.png"
    assert save_figure(fig, target, dpi=50) == target and _png_size(target) == (500, 350)
    save_figure(fig, target)                                          # replaces an existing file
    assert _png_size(target) == (1100, 770)
    before = target.read_bytes()
    with pytest.raises(ValueError):
        save_figure(fig, target.with_suffix(".nosuchformat"))
    target.with_suffix(".nosuchformat").unlink(missing_ok=True)
    assert target.read_bytes() == before and sorted(p.name for p in target.parent.iterdir()) == ["f.png"]
    svg = save_figure(fig, tmp_path / "f.svg")
    assert svg.read_text().lstrip().startswith("<?xml")
    assert isinstance(save_figure(fig, str(tmp_path / "s.png")), Path)


# ------------------------------------------------------------------ the user's backend is left alone
_BACKEND_CODE = """
import sys
import matplotlib
{use}
import numpy as np
import drivesense
import drivesense.plot as P
from drivesense.recording import Recording

t = np.arange(5000) / 5000.0
rec = Recording.from_arrays({{"x_current": np.sin(2 * np.pi * 50 * t)}}, fs=5000.0)
fig = P.plot_trace_spectrum(rec, "x_current")
P.save_figure(fig, sys.argv[1])
assert "matplotlib.pyplot" not in sys.modules, "pyplot imported"
{check}
"""


@pytest.mark.parametrize("use, check", [
    ('matplotlib.use("svg")', 'assert matplotlib.get_backend() == "svg", matplotlib.get_backend()'),
    ("", ""),                                                         # no backend chosen: none is chosen for us
], ids=["svg-backend-set", "no-backend"])
def test_backend_is_unchanged_by_making_and_saving_a_figure(tmp_path, use, check):
    import os

    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    out = tmp_path / "f.png"
    res = subprocess.run([sys.executable, "-c", _BACKEND_CODE.format(use=use, check=check), str(out)],
                         capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    assert out.read_bytes()[:8] == PNG_MAGIC


# ------------------------------------------------------------------ docstrings
@pytest.mark.parametrize("name", ds_plot.__all__)
def test_public_plot_functions_are_documented(name):
    func = getattr(ds_plot, name)
    doc = inspect.getdoc(func) or ""
    assert "Parameters\n----------" in doc and "Returns\n-------" in doc, name
    for p in inspect.signature(func).parameters:
        assert f"{p} :" in doc, f"{name}: parameter {p!r} undocumented"


# ------------------------------------------------------------------ who may draw
def _modules():
    for path in sorted(SRC.rglob("*.py")):
        yield path, path.relative_to(SRC).parts


def _type_checking_nodes(tree) -> set[int]:
    """ids of the nodes inside ``if TYPE_CHECKING:`` blocks."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for stmt in node.body:
                skip.update(id(n) for n in ast.walk(stmt))
    return skip


def _imports(path: Path, parts: tuple[str, ...], *, runtime_only: bool = False, top_level: bool = False):
    """Absolute names of the modules `path` imports (``from a import b`` gives ``a`` and ``a.b``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _type_checking_nodes(tree) if runtime_only else set()
    package = ["drivesense", *parts[:-1]]
    nodes = tree.body if top_level else ast.walk(tree)
    for node in nodes:
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package[: len(package) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            yield base
            for a in node.names:
                yield f"{base}.{a.name}"


def test_only_the_plot_package_imports_matplotlib_and_nothing_imports_pyplot():
    offenders, pyplot = [], []
    for path, parts in _modules():
        names = set(_imports(path, parts))
        if any(n.startswith("matplotlib.pyplot") or n == "pylab" for n in names):
            pyplot.append(str(path))
        if parts[0] != "plot" and any(n == "matplotlib" or n.startswith("matplotlib.") for n in names):
            offenders.append(str(path))
    assert not pyplot, f"pyplot imported in {pyplot}"
    assert not offenders, f"matplotlib imported outside drivesense/plot/: {offenders}"


def test_plot_package_depends_only_on_the_core():
    allowed = ("numpy", "matplotlib", "drivesense.dsp", "drivesense.recording", "drivesense.units",
               "drivesense.errors", "drivesense.score", "drivesense.plot")
    bad = []
    for path, parts in _modules():
        if parts[0] != "plot":
            continue
        for name in _imports(path, parts, runtime_only=True):
            root = name.split(".")[0]
            if root in sys.stdlib_module_names or root == "__future__":
                continue
            if not any(name == a or name.startswith(a + ".") for a in allowed):
                bad.append(f"{path.name}: {name}")
    assert not bad, bad


def test_identify_monitor_bench_hold_no_plotting_code():
    for path, parts in _modules():
        if parts[0] not in ("identify", "monitor", "bench"):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        defs = [n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
        assert not [d for d in defs if d.startswith("plot_")], path
        names = set(_imports(path, parts, top_level=True)) if parts[0] == "bench" else set(_imports(path, parts))
        assert not [n for n in names if n == "drivesense.plot" or n.startswith("drivesense.plot.")], path


def test_estimates_without_a_reference_draw_no_truth_and_show_the_whole_trace():
    """Without a reference force the estimate used to be drawn as 'truth (filtered)' over the last 0.1 s only."""
    trace, est = _force_recordings()
    fig = ds_plot.plot_estimates(None, {"vibration": est}, channel="force_x", zoom=(1.0, 1.2))
    overview, close, spectrum = fig.axes
    labels = [line.get_label() for ax in fig.axes for line in ax.get_lines()]
    assert labels == ["vibration"] * 3
    assert overview.get_lines()[0].get_xdata().size == est.n_samples           # the whole trace
    assert close.get_lines()[0].get_xdata().min() >= 1.0 - 0.002 - 1e-9        # the close-up asked for
    assert close.get_lines()[0].get_xdata().max() < 1.2
    with_truth = ds_plot.plot_estimates(trace, {"vibration": est}, channel="force_x")
    assert "truth (filtered)" in [line.get_label() for line in with_truth.axes[1].get_lines()]


def test_default_close_up_is_a_few_tooth_periods_in_the_middle_of_the_cut():
    from drivesense.plot.estimates import cut_zoom_window

    fs, n = 1000.0, 4000
    spindle = Recording.from_arrays({"spindle_speed": np.full(n, 3000 * 2 * np.pi / 60)}, fs=fs,
                                    meta={"tool": {"flutes": 4}, "t_contact": 2.0})
    a, b = cut_zoom_window(spindle, (1.0, 4.0))
    assert b - a == pytest.approx(5 * 60 / 3000 / 4) and (a + b) / 2 == pytest.approx(3.0)
    from_meta = Recording.from_arrays({"force_x": np.zeros(n)}, fs=fs, meta={"n_rpm": 6000.0})
    a, b = cut_zoom_window(from_meta, (0.0, 4.0))
    assert b - a == pytest.approx(2.5 * 60 / 6000) and (a + b) / 2 == pytest.approx(2.0)
    none = Recording.from_arrays({"force_x": np.zeros(n)}, fs=fs)
    assert cut_zoom_window(none) == pytest.approx((1.95, 2.05))
