"""Cheap-sensor calibration (Sec. 3) on a simulated electret: ratio spectrum, linearity, deconvolution, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, IdentificationError
from drivesense.identify.sensor import (SensorCalibration, calibrate_sensor, check_linearity, deconvolution_residual,
                                        ratio_spectrum)
from drivesense.recording import Recording
from drivesense.sim.electret import ElectretSensor, simulate_machining_vibration, simulate_shaker_pair

FS = 22050.0
LEVELS = (1.3, 3.0, 6.6)
runner = CliRunner()


@pytest.fixture(scope="module")
def pairs():
    return [simulate_shaker_pair(a, fs=FS, duration=2.0, seed=k) for k, a in enumerate(LEVELS)]


@pytest.fixture(scope="module")
def cal(pairs):
    return calibrate_sensor(pairs, nperseg=2048)


def test_electret_response_is_not_flat():
    s = ElectretSensor()
    h = np.abs(s.frequency_response([500.0, s.resonance_hz, 4000.0], FS))
    assert h[1] > 3 * h[0] and h[2] < h[0]                    # resonance peak, roll-off above it
    assert h[0] == pytest.approx(s.sensitivity, rel=0.05)


def test_ratio_spectrum_recovers_the_sensor_response(pairs):
    rec = pairs[1]
    f, h, coh = ratio_spectrum(rec["electret"], rec["accel_ref"], FS, nperseg=2048)
    band = (f >= 100) & (f <= 4000)
    true = ElectretSensor().frequency_response(f[band], FS)
    np.testing.assert_allclose(np.abs(h[band]), np.abs(true), rtol=0.03)
    assert np.min(coh[band]) > 0.98


def test_linear_from_1_3_to_6_6_g_and_a_driven_too_hard_sensor_is_caught(pairs):
    lin = check_linearity(pairs, nperseg=2048)
    assert lin["linear"] and lin["spread"] < 0.01 and lin["rms_fit_r2"] > 0.999
    assert lin["amplitudes_g"] == pytest.approx(LEVELS, rel=0.02)
    soft = ElectretSensor(saturation_g=8.0, distortion=0.05)
    hard = [simulate_shaker_pair(a, fs=FS, duration=2.0, seed=k, sensor=soft) for k, a in enumerate(LEVELS)]
    assert not check_linearity(hard, nperseg=2048)["linear"]


def test_deconvolution_residual_below_5_percent_on_new_records(cal):
    milling = simulate_machining_vibration(fs=FS, duration=2.0, seed=5)
    assert deconvolution_residual(cal, milling["electret"], milling["accel_ref"]) < 0.05
    shaker = simulate_shaker_pair(2.2, fs=FS, duration=2.0, seed=42)
    assert deconvolution_residual(cal, shaker["electret"], shaker["accel_ref"]) < 0.05
    gain = np.median(np.abs(cal.response[(cal.freq > 100) & (cal.freq < 4000)]))
    naive = SensorCalibration(cal.fs, cal.band, cal.freq, cal.response, cal.coherence,
                              np.r_[np.zeros(1024), 1 / gain, np.zeros(1024)])
    assert deconvolution_residual(naive, milling["electret"], milling["accel_ref"]) > 0.2   # a gain is not enough


def test_apply_to_recording_and_file_roundtrip(tmp_path, cal):
    rec = simulate_machining_vibration(fs=FS, duration=1.0, seed=6)
    out = cal.apply(rec)
    assert out.units("acceleration") == "m/s^2" and "deconvolved" in out.meta["provenance"][-1]
    loaded = SensorCalibration.load(cal.save(tmp_path / "cal.json"))
    np.testing.assert_allclose(loaded.apply(rec["electret"], FS), out["acceleration"], rtol=1e-12, atol=1e-12)
    assert loaded.linearity["linear"] is True
    with pytest.raises(ConfigError, match="sampled at"):
        cal.apply(rec["electret"], 44100.0)


def test_bad_calibration_input(pairs):
    with pytest.raises(IdentificationError, match="no paired"):
        calibrate_sensor([])
    rng = np.random.default_rng(0)
    with pytest.raises(IdentificationError, match="not coherent"):
        calibrate_sensor([(rng.normal(size=20000), rng.normal(size=20000))], fs=FS, nperseg=2048)
    with pytest.raises(ConfigError, match=r"--band LOW:HIGH must satisfy .*got 100:20000"):   # the CLI option
        calibrate_sensor(pairs, band=(100.0, 20000.0), nperseg=2048)
    with pytest.raises(ConfigError, match="nperseg"):
        calibrate_sensor(pairs, nperseg=1001)
    with pytest.raises(KeyError):
        calibrate_sensor([Recording.from_arrays({"x": np.zeros(10)}, fs=FS)])


def test_cli_simulate_calibrate_apply(tmp_path):
    d = tmp_path / "s"
    res = runner.invoke(app, ["sensor", "simulate", "--out-dir", str(d), "--levels", "1.3,6.6"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["sensor", "calibrate", str(d / "shaker_1.3g.nc"), str(d / "shaker_6.6g.nc"),
                              "--out", str(tmp_path / "f.json"), "--plot", str(tmp_path / "fig6.png"),
                              "--json", str(tmp_path / "c.json")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "c.json").read_text())["linearity"]["linear"] is True
    res = runner.invoke(app, ["sensor", "apply", str(d / "milling.nc"), "--filter", str(tmp_path / "f.json"),
                              "--out", str(tmp_path / "acc.nc"), "--json", str(tmp_path / "a.json")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "a.json").read_text())["residual_vs_reference"] < 0.05
    res = runner.invoke(app, ["sensor", "calibrate", str(d / "milling.nc"), "--out", str(tmp_path / "g.json"),
                              "--band", "100-4000"])
    assert res.exit_code == 2 and "LOW:HIGH" in res.output
