"""Once-per-revolution amplitude and phase (Sec. 1.4): synthetic signals, the milling model with runout, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivesense.errors import ConfigError, SignalTooShortError
from drivesense.machine.milling import CuttingCoefficients, EndMill, MillingCut, milling_forces
from drivesense.condition.runout import estimate_runout
from drivesense.recording import Recording

FS = 20000.0


def synthetic(amp=2.0, phase=0.7, rpm=3000.0, seconds=1.0, flutes=4, noise=0.5, vary=0.0, seed=0):
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    omega = 2 * math.pi * rpm / 60 * (1 + vary * np.sin(2 * math.pi * 0.7 * t))
    theta = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / FS)])
    y = amp * np.cos(theta - phase) + 3.0
    for k in range(1, 3):
        y += 5.0 / k * np.cos(k * flutes * theta + 0.3 * k)
    return y + rng.normal(0, noise, n), omega, theta


@pytest.mark.parametrize("vary", [0.0, 0.05])
def test_amplitude_and_phase_with_tooth_harmonics_noise_and_varying_speed(vary):
    y, omega, _ = synthetic(vary=vary)
    est = estimate_runout(y, FS, omega, kind="force")
    assert est.amplitude == pytest.approx(2.0, rel=0.01)
    assert est.phase == pytest.approx(0.7, abs=0.01)
    assert est.amplitude_se < 0.02 and est.displacement is None
    assert est.harmonics[3] == pytest.approx(5.0, rel=0.01)              # the tooth-passing order, not leaked
    assert est.frequency == pytest.approx(omega.mean() / (2 * math.pi), rel=1e-3) and est.revolutions > 40


def test_units_micrometres_from_acceleration_and_from_force_with_stiffness():
    y, omega, theta = synthetic(amp=10.0, noise=0.0)
    w = omega[0]
    acc = estimate_runout(y, FS, omega, kind="acceleration")
    assert acc.displacement == pytest.approx(10.0 / w ** 2, rel=1e-3)
    force = estimate_runout(y, FS, omega, kind="force", stiffness=2e6)
    assert force.to_dict()["displacement_um"] == pytest.approx(10.0 / 2e6 * 1e6, rel=1e-3)
    enc = estimate_runout(y, FS, spindle_angle=theta + 1.0, kind="displacement")     # encoder zero shifted
    assert enc.phase == pytest.approx(0.7 + 1.0, abs=1e-3) and enc.displacement == pytest.approx(10.0, rel=1e-3)


def test_runout_of_the_milling_model_shows_at_once_per_revolution():
    omega = 2 * math.pi * 3000 / 60
    angle = omega * np.arange(int(0.2 * FS)) / FS
    amps = []
    for e in (0.0, 2e-6, 4e-6):                       # small enough that no flute loses contact
        tool = EndMill(10e-3, 2, 30.0, runout=e)
        f = milling_forces(tool, CuttingCoefficients.aluminium(), MillingCut(5e-3, 2e-3, "down"), angle, 0.05e-3)
        amps.append(estimate_runout(f.feed, FS, omega, kind="force").amplitude)
    assert amps[0] < 1e-6 * amps[2]
    assert amps[2] == pytest.approx(2 * amps[1], rel=0.02)                # linear in the runout


def test_recording_input():
    y, omega, _ = synthetic()
    rec = Recording.from_arrays({"force_x": y, "spindle_speed": omega}, fs=FS)
    est = estimate_runout(rec, stiffness=1e6)
    assert est.kind == "force" and est.amplitude == pytest.approx(2.0, rel=0.01)


def test_bad_input():
    y, omega, _ = synthetic(seconds=0.03)
    with pytest.raises(SignalTooShortError, match="revolutions"):
        estimate_runout(y, FS, omega, kind="force")
    y, omega, _ = synthetic()
    with pytest.raises(ConfigError, match="kind"):
        estimate_runout(y, FS, omega, kind="velocity")
    with pytest.raises(ConfigError, match="spindle_speed"):
        estimate_runout(y, FS, kind="force")
    with pytest.raises(ConfigError, match="stiffness"):
        estimate_runout(y, FS, omega, kind="force", stiffness=-1.0)
