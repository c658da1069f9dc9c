"""FRF identification of the ball-screw axis: excitation, measurement, fit, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import drivesense as ds
from drivesense.cli import app
from drivesense.errors import ConfigError, IdentificationError
from drivesense.identify.frf import MeasuredFRF, fit_frf, measure_frf, model_frf
from drivesense.sim.excitation import chirp, make_excitation, multisine, prbs
from drivesense.sim.scenarios import ScenarioSettings, simulate_frf_excitation
from drivesense.io import write_recording

AXIS = ds.table1_axis()
TRUE_TB = 0.2e-3


def _analytic(lo=5.0, hi=2000.0, n=400, noise=0.0, seed=0):
    f = np.linspace(lo, hi, n)
    gm, gt = model_frf(AXIS, f, T_a=0.2e-3, T_b=TRUE_TB, omega_cc=5000.0, fs=1e4)
    if noise:
        rng = np.random.default_rng(seed)
        gm = gm * (1 + noise * (rng.standard_normal(n) + 1j * rng.standard_normal(n)))
        gt = gt * (1 + noise * (rng.standard_normal(n) + 1j * rng.standard_normal(n)))
    coh = np.full(n, 0.999 if noise else 0.9999)
    return MeasuredFRF(f, gm, gt, coh, coh, 10, 1e4, "excitation")


def test_fit_on_analytic_frf_recovers_exactly():
    fit = fit_frf(_analytic(), K_t=AXIS.K_t, lead=AXIS.lead)
    for name, true in AXIS.to_dict().items():
        if name in fit.free:
            assert fit.values[name] == pytest.approx(true, rel=1e-6), name
    assert fit.values["T_b"] == pytest.approx(TRUE_TB, abs=1e-9)
    assert fit.signal.T_comp == pytest.approx(0.4e-3, abs=1e-9)
    assert fit.normalised_rms < 1e-3


def test_fit_reports_confidence_intervals_that_cover_the_truth_under_noise():
    fit = fit_frf(_analytic(noise=0.01, seed=3), K_t=AXIS.K_t, lead=AXIS.lead)
    for name in ("J_r", "M_t", "K_r", "C_k", "D_r", "C_t"):
        lo, hi = fit.ci95[name]
        true = getattr(AXIS, name)
        assert lo < fit.values[name] < hi
        assert abs(fit.values[name] / true - 1) < 0.05, name


def test_fixed_parameters_are_kept():
    fit = fit_frf(_analytic(), K_t=AXIS.K_t, lead=AXIS.lead, fixed={"K_r": AXIS.K_r, "T_b": TRUE_TB})
    assert "K_r" not in fit.free and fit.values["K_r"] == AXIS.K_r
    assert fit.values["M_t"] == pytest.approx(AXIS.M_t, rel=1e-5)


def test_band_below_resonance_cannot_determine_stiffness():
    with pytest.raises(IdentificationError, match="cannot determine.*K_r"):
        fit_frf(_analytic(5.0, 100.0, noise=0.01), K_t=AXIS.K_t, lead=AXIS.lead)


def test_band_without_low_frequencies_cannot_determine_mass():
    with pytest.raises(IdentificationError, match="mass cannot be determined"):
        fit_frf(_analytic(300.0, 2000.0), K_t=AXIS.K_t, lead=AXIS.lead)


def test_band_and_length_messages_name_the_cli_options():
    with pytest.raises(IdentificationError, match=r"raise --fmax / the excitation band"):
        fit_frf(_analytic(5.0, 40.0), K_t=AXIS.K_t, lead=AXIS.lead)
    with pytest.raises(IdentificationError, match=r"lower --fmin / the excitation band"):
        fit_frf(_analytic(300.0, 2000.0), K_t=AXIS.K_t, lead=AXIS.lead)
    short = ds.Recording.from_arrays({f"x_{c}": np.zeros(1000) for c in ("current_ref", "motor_angle",
                                                                        "table_position")}, fs=1e4)
    with pytest.raises(ds.errors.InvalidSignalError, match=r"record longer or lower --nperseg"):
        measure_frf(short, K_t=AXIS.K_t, lead=AXIS.lead)


def test_unknown_fixed_parameter():
    with pytest.raises(ConfigError, match="Kt"):
        fit_frf(_analytic(), K_t=AXIS.K_t, lead=AXIS.lead, fixed={"Kt": 1.0})


@pytest.fixture(scope="module")
def chirp_trace():
    return simulate_frf_excitation("chirp", seed=5)


def test_simulated_excitation_identifies_within_the_targets(chirp_trace):
    true = chirp_trace.meta["true_axis"]
    measured = measure_frf(chirp_trace, K_t=true["K_t"], lead=true["lead"])
    assert measured.reference == "excitation"
    fit = fit_frf(measured, K_t=true["K_t"], lead=true["lead"])
    for name, tol in (("J_r", 0.02), ("M_t", 0.02), ("K_r", 0.02), ("C_t", 0.1), ("C_k", 0.1), ("D_r", 0.1)):
        assert fit.values[name] == pytest.approx(true[name], rel=tol), name
    assert fit.values["T_b"] == pytest.approx(chirp_trace.meta["true_signal"]["T_b"], abs=0.02e-3)


def test_ideal_simulation_matches_the_model():
    rec = simulate_frf_excitation("multisine", ScenarioSettings().as_ideal(), seed=1)
    m = measure_frf(rec, K_t=AXIS.K_t, lead=AXIS.lead, window=(1.6, 8.0))
    gm, gt = model_frf(AXIS, m.freq, T_a=0.2e-3, T_b=0.2e-3, omega_cc=5000.0, fs=1e4)
    sel = (m.freq > 20) & (m.freq < 1500)
    assert np.median(np.abs(m.motor[sel] / gm[sel] - 1)) < 0.005
    assert np.median(np.abs(m.table[sel] / gt[sel] - 1)) < 0.005


def test_h1_on_current_reference_without_excitation_channel(chirp_trace):
    rec = chirp_trace.select("x_current_ref", "x_motor_angle", "x_table_position")
    m = measure_frf(rec, K_t=AXIS.K_t, lead=AXIS.lead, window=tuple(chirp_trace.meta["excitation_window"]))
    assert m.reference == "current_ref" and np.median(m.coherence_table) > 0.9


@pytest.mark.parametrize("gen", [
    lambda a, lim: chirp(1.0, 1e4, 5, 2000, a, limit=lim),
    lambda a, lim: multisine(1.0, 1e4, 5, 2000, a, limit=lim),
    lambda a, lim: prbs(1.0, 1e4, a, limit=lim),
])
def test_excitation_amplitude_and_limit(gen):
    x = gen(0.3, 1.0)
    assert np.max(np.abs(x)) == pytest.approx(0.3, rel=1e-3)
    with pytest.raises(ConfigError, match="exceeds the limit"):
        gen(2.0, 1.0)


def test_multisine_is_flat_in_band():
    x = multisine(1.0, 1e4, 10, 1000, 1.0)
    spec = np.abs(np.fft.rfft(x))
    band = spec[10:1001]
    assert band.min() / band.max() > 0.999
    assert spec[1001:].max() < 1e-9 * band.max()
    with pytest.raises(ConfigError, match="unknown excitation"):
        make_excitation("noise", 1.0, 1e4, 0.1)


def test_cli_identify_frf_writes_a_usable_axis_file(tmp_path, chirp_trace):
    runner = CliRunner()
    write_recording(chirp_trace, tmp_path / "frf.nc")
    res = runner.invoke(app, ["identify", "frf", str(tmp_path / "frf.nc"), "--fix", "K_t=0.45,lead=0.005",
                              "--out", str(tmp_path / "axis.toml"), "--json", str(tmp_path / "fit.json"),
                              "--plot", str(tmp_path / "frf.png")])
    assert res.exit_code == 0, res.output
    axis, signal = ds.read_axis_file(tmp_path / "axis.toml")
    assert axis.K_r == pytest.approx(AXIS.K_r, rel=0.02)
    assert signal.T_comp == pytest.approx(signal.T_a + signal.T_b)
    info = json.loads((tmp_path / "fit.json").read_text())
    assert set(info["free"]) == {"J_r", "M_t", "C_t", "C_k", "D_r", "K_r", "T_b"}
    assert (tmp_path / "frf.png").stat().st_size > 10_000


@pytest.mark.parametrize("fix, expect", [("lead=0.005", "K_t"), ("K_t=0.45,lead", "NAME=VALUE"),
                                         ("K_t=abc,lead=0.005", "not a number")])
def test_cli_identify_frf_bad_fix(tmp_path, chirp_trace, fix, expect):
    write_recording(chirp_trace, tmp_path / "frf.nc")
    res = CliRunner().invoke(app, ["identify", "frf", str(tmp_path / "frf.nc"), "--fix", fix,
                                   "--out", str(tmp_path / "axis.toml")])
    assert res.exit_code == 2 and expect in " ".join(res.output.split())


def test_cli_identify_frf_on_a_cut_without_excitation(tmp_path):
    """A cutting trace (no excitation) drove a parameter to exp(huge): OverflowError, now a one-line refusal."""
    from dataclasses import replace

    from drivesense.sim.scenarios import paper_conditions, simulate_cut

    cond = next(c for c in paper_conditions() if c.name.startswith("cross"))
    cut = simulate_cut(cond, replace(ScenarioSettings(), duration=2.5, t_contact=1.2), seed=3)
    write_recording(cut, tmp_path / "cut.nc")
    res = CliRunner().invoke(app, ["identify", "frf", str(tmp_path / "cut.nc"), "--fix", "K_t=0.45,lead=0.005",
                                   "--out", str(tmp_path / "AXIS.toml")])
    assert res.exit_code == 2 and "cannot determine" in res.output, res.output
    assert "Traceback" not in res.output and not (tmp_path / "AXIS.toml").exists()
