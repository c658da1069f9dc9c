"""The shared simulator physics against closed forms, and both simulators using it.

* LuGre (:func:`lugre_step`): exact exponential bristle integration; the steady
  state at constant velocity is the Stribeck curve; bristles hold at rest.
* Coulomb level (:func:`coulomb_level`): drift, ripple and load add up; the
  level is clamped at 0 N; the Stribeck level is floored at ``G_MIN``.
* Ripple sum: one component is ``A sin(2 pi x / lambda + phi)``.
* Quantisation: rounds to the nearest step, halves up, none for step 0.
* The ball-screw and linear-motor simulators call these same functions (no
  private copies left) and share one ideal-physics switch.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np
import pytest

from drivesense.machine import friction
from drivesense.machine.friction import (G_MIN, LuGreFriction, LuGreParams, Ripple, RippleParams, coulomb_level,
                                         lugre_step, ripple_params, ripple_sum, ripple_values)
from drivesense.machine.presets import table1_stage
from drivesense.sim import encoders, linear_machine, servo
from drivesense.sim.encoders import quantise
from drivesense.sim.machining import ProcessSettings, simulate_process
from drivesense.sim.scenarios import ScenarioSettings, paper_conditions, simulate_cut

FRICTION = LuGreFriction(F_c=40.0, F_s=55.0, v_s=4e-3, sigma0=2.0e6, sigma1=3.0e3, sigma2=700.0,
                         ripples=(Ripple(0.061, 1.2, 0.5), Ripple(0.0073, 0.6, 1.7)), drift_per_m=8.0,
                         load_coefficient=0.01)


def stribeck(p: LuGreParams, level: float, v: float) -> float:
    return math.copysign(level + (p.F_s - p.F_c) * math.exp(-(v / p.v_s) ** 2), v) + p.sigma2 * v


# ------------------------------------------------------------------ ripple sum
@pytest.mark.parametrize("x", [0.0, 1.3e-3, -0.021, 0.25])
def test_one_ripple_is_a_sine(x):
    r = ripple_params([Ripple(7.3e-3, 0.8, 1.1)])
    assert ripple_sum(r, x) == pytest.approx(0.8 * math.sin(2 * math.pi * x / 7.3e-3 + 1.1), abs=1e-15)
    assert ripple_sum(r, x, 5.0) == pytest.approx(5.0 + 0.8 * math.sin(2 * math.pi * x / 7.3e-3 + 1.1), abs=1e-14)


def test_ripple_sum_adds_components_and_vectorises():
    rip = (Ripple(5e-3, 4.0, 0.3), Ripple(1.25e-3, 1.5, 1.1), Ripple(83e-6, 1.0, 2.0))
    x = np.linspace(-0.01, 0.03, 501)
    expected = sum(r.amplitude * np.sin(2 * np.pi * x / r.wavelength + r.phase) for r in rip)
    np.testing.assert_allclose(ripple_values(rip, x), expected, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(ripple_values(rip, x.reshape(3, -1)), ripple_values(rip, x).reshape(3, -1))
    none = ripple_params(())
    assert isinstance(none, RippleParams) and none.wavelength.size == 0
    assert ripple_sum(none, 0.3) == 0.0 and ripple_sum(none, 0.3, 2.5) == 2.5


# ------------------------------------------------------------------ Coulomb level and its clamping rule
@pytest.mark.parametrize("x, load", [(0.0, 0.0), (0.12, 0.0), (0.31, 250.0), (-0.05, -300.0)])
def test_coulomb_level_adds_drift_ripple_and_load(x, load):
    p = FRICTION.params()
    expected = 40.0 + 8.0 * x + 0.01 * load + sum(r.amplitude * math.sin(2 * math.pi * x / r.wavelength + r.phase)
                                                  for r in FRICTION.ripples)
    assert coulomb_level(p, x, load) == pytest.approx(expected, rel=1e-14)
    assert FRICTION.coulomb_level(x, load) == coulomb_level(p, x, load)


def test_coulomb_level_is_clamped_at_zero():
    """An unloaded guide (negative normal load) lowers the level to 0 N, never below."""
    p = FRICTION.params()
    assert coulomb_level(p, 0.1, -3000.0) == pytest.approx(40.0 + 0.8 + (-30.0) + ripple_sum(p.ripple, 0.1), rel=1e-12)
    assert coulomb_level(p, 0.1, -5000.0) == 0.0 and coulomb_level(p, 0.1, -1e9) == 0.0
    levels = FRICTION.coulomb_level(np.linspace(0, 0.3, 7), -1e5)
    assert levels.shape == (7,) and np.all(levels == 0.0)
    # the static excess rides on the clamped level: at zero speed g = F_s - F_c
    z = 0.0
    for _ in range(20_000):
        z, f = lugre_step(p, z, 1e-3, 0.0, 1e-4)
    assert f == pytest.approx(stribeck(p, 0.0, 1e-3), rel=1e-9)


def test_stribeck_level_is_floored_at_g_min():
    """No friction left (level 0, no static excess): the bristles hold at most G_MIN."""
    p = LuGreFriction(F_c=0.0, F_s=0.0, v_s=1e-3, sigma0=1e6, sigma1=0.0).params()
    z, f = lugre_step(p, 0.0, 0.01, 0.0, 1e-4)
    assert z == pytest.approx(G_MIN / 1e6) and f == pytest.approx(G_MIN) and math.isfinite(f)


# ------------------------------------------------------------------ LuGre
@pytest.mark.parametrize("v", [-0.05, -4e-3, -1e-4, 2e-5, 1e-3, 4e-3, 0.02, 0.3])
@pytest.mark.parametrize("x, load", [(0.0, 0.0), (0.17, 120.0)])
def test_lugre_steady_state_is_the_stribeck_curve(v, x, load):
    p = FRICTION.params()
    level = coulomb_level(p, x, load)
    z, dt = 0.0, 50.0 / (p.sigma0 * abs(v))     # about one relaxation time per step (exact for any step)
    for _ in range(2000):
        z, force = lugre_step(p, z, v, level, dt)
    assert force == pytest.approx(stribeck(p, level, v), rel=1e-10)
    assert force == pytest.approx(FRICTION.steady_state(v, x, load), rel=1e-10)


def test_lugre_step_integrates_the_bristles_exactly():
    p = FRICTION.params()
    level, v, dt, z0 = 41.0, 2e-3, 3e-5, -1e-6
    g = level + (p.F_s - p.F_c) * math.exp(-(v / p.v_s) ** 2)
    z_ss = g / p.sigma0
    z1 = z_ss + (z0 - z_ss) * math.exp(-p.sigma0 * v * dt / g)
    z, f = lugre_step(p, z0, v, level, dt)
    assert z == pytest.approx(z1, rel=1e-14)
    assert f == pytest.approx(p.sigma0 * z1 + p.sigma1 * (z1 - z0) / dt + p.sigma2 * v, rel=1e-12)
    # two half steps = one step (exact for constant velocity)
    zh, _ = lugre_step(p, z0, v, level, dt / 2)
    zh, _ = lugre_step(p, zh, v, level, dt / 2)
    assert zh == pytest.approx(z1, rel=1e-12)
    # at rest the bristles hold: a spring of stiffness sigma0
    z, f = lugre_step(p, 3e-6, 0.0, level, dt)
    assert z == 3e-6 and f == pytest.approx(p.sigma0 * 3e-6)


def test_named_parameters():
    p = FRICTION.params()
    assert isinstance(p, LuGreParams) and p.F_c == 40.0 and p.sigma2 == 700.0 and p.load_coefficient == 0.01
    np.testing.assert_array_equal(p.ripple.wavelength, [0.061, 0.0073])
    sp = servo.StageParams.of(table1_stage())
    assert sp.has_motor_friction and sp.motor_friction.F_c == 95.0 and sp.cogging.amplitude.size == 3
    ideal = servo.StageParams.of(table1_stage().ideal())
    assert not ideal.has_motor_friction and not ideal.has_guide_friction and ideal.lead_error.wavelength.size == 0


# ------------------------------------------------------------------ quantisation
def test_quantise_rounds_to_the_step():
    step = 5e-9
    rng = np.random.default_rng(1)
    for v in rng.normal(0.0, 1e-6, 200):
        q = quantise(v, step)
        assert abs(q - v) <= step / 2 * (1 + 1e-9)
        assert abs(q / step - round(q / step)) < 1e-6
    assert quantise(2.5, 1.0) == 3.0 and quantise(-2.5, 1.0) == -2.0 and quantise(2.49, 1.0) == 2.0
    assert quantise(0.123456, 0.0) == 0.123456 and quantise(0.123456, -1.0) == 0.123456
    assert quantise(7.0 * 0.25, 0.25) == 1.75


# ------------------------------------------------------------------ one implementation, used by both simulators
def test_both_simulators_call_the_shared_functions():
    for mod in (servo, linear_machine):
        for private in ("_quantise", "_coulomb", "_ripple_sum", "_lugre_step"):
            assert not hasattr(mod, private), f"{mod.__name__} still defines {private}"
        assert mod.quantise is encoders.quantise
        assert mod.coulomb_level is friction.coulomb_level and mod.lugre_step is friction.lugre_step
    assert servo.ripple_sum is friction.ripple_sum
    # the compiled loops read these globals (and no flat parameter arrays)
    servo_names = set(servo._servo_loop.py_func.__code__.co_names)
    assert {"quantise", "coulomb_level", "lugre_step", "ripple_sum"} <= servo_names
    machine_names = set(linear_machine._machine_loop.py_func.__code__.co_names)
    assert {"quantise", "coulomb_level", "lugre_step"} <= machine_names


def test_one_ideal_switch_with_the_same_name_in_both_simulators():
    s, p = ScenarioSettings(), ProcessSettings()
    assert not s.ideal and not p.ideal
    si, pi_ = s.as_ideal(), p.as_ideal()
    assert si.ideal and pi_.ideal and pi_.physics.exact and pi_.servo.true_state
    assert si.stage.motor_friction is None and si.servo.current_noise == 0.0
    assert si.as_ideal() == si and pi_.as_ideal().physics.exact
    short = replace(ScenarioSettings(), duration=2.2)
    cond = paper_conditions()[0]
    assert simulate_cut(cond, short, seed=2, ideal=True).equals(simulate_cut(cond, short.as_ideal(), seed=2))
    a = simulate_process("groove_+x", 2e-3, 10e-3, 0.01, 4500, seed=3, ideal=True)
    b = simulate_process("groove_+x", 2e-3, 10e-3, 0.01, 4500, seed=3, settings=ProcessSettings().as_ideal())
    assert a.equals(b) and a.meta["physics"].startswith("ideal")


def test_compiled_loops_are_cached_against_the_shared_physics_source(tmp_path, monkeypatch):
    """numba re-validates a cached loop only against its own file: the loops close over the physics' digest."""
    from drivesense.machine import linear_motor
    from drivesense.sim.kernel_cache import source_digest

    assert servo._servo_loop.py_func.__closure__[0].cell_contents == source_digest(friction, encoders)
    assert linear_machine._machine_loop.py_func.__closure__[0].cell_contents == \
        source_digest(friction, encoders, linear_motor)
    (tmp_path / "fake_physics_mod.py").write_text("A = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import fake_physics_mod

    before = source_digest(fake_physics_mod)
    (tmp_path / "fake_physics_mod.py").write_text("A = 2\n")
    assert source_digest(fake_physics_mod) != before
    monkeypatch.delitem(sys.modules, "fake_physics_mod")
