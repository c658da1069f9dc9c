"""Dual-inertia ball-screw model (first paper, Eq. 1-4) against closed forms.

References used below (translational form, ``R = lead / 2 pi``):

* ``M_r = J_r / R^2``, ``C_r = D_r / R^2``, ``alpha = M_t / M_r`` (Table 1: 0.080).
* ``[phi] = [[1, 1], [1, -1/alpha]]``;  with proportional damping
  (``C_r / M_r == C_t / M_t``) ``[phi]^T [M|C|K] [phi]`` is diagonal:
  ``M_rigid = M_r + M_t``, ``M_vib = (1 + 1/alpha) M_r``, ``K_rigid = 0``,
  ``K_vib = (1 + 1/alpha)^2 K_r``, ``C_modal = alpha_c M_modal + beta_c K_modal``.
* A force F on the table projects onto the modes as ``[phi]^T {0, F} = {F, -F/alpha}``,
  so the spring deflection ``x_m - x_t = (1 + 1/alpha) x_vib`` is
  ``-(1 + 1/alpha)/alpha * F / (K_vib - M_vib w^2 + j w C_vib)``, and far below the
  resonance the table moves like the free rigid body ``1 / (-M_rigid w^2 + j w C_rigid)``.
* Anti-resonances: the motor does not move under motor thrust at ``sqrt(K_r / M_t)``;
  the table does not move under a table force at ``sqrt(K_r / M_r)``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from drivesense.errors import ConfigError
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.presets import table1_axis

FIELDS = ("J_r", "M_t", "C_t", "C_k", "D_r", "K_r", "lead", "K_t")


@pytest.fixture(scope="module")
def ax() -> BallScrewAxis:
    return table1_axis()


@pytest.fixture(scope="module")
def prop(ax) -> BallScrewAxis:
    """Table 1 with exactly proportional damping: C_t = alpha * C_r (= alpha_c M_t)."""
    return replace(ax, C_t=ax.alpha * ax.C_r)


@pytest.fixture(scope="module")
def light(ax) -> BallScrewAxis:
    """Table 1 masses and stiffness, damping cut 1000-fold (sharp (anti-)resonances)."""
    return replace(ax, C_t=ax.C_t * 1e-3, C_k=ax.C_k * 1e-3, D_r=ax.D_r * 1e-3)


# ------------------------------------------------------------- derived values
def test_table1_derived_values(ax):
    R = 5e-3 / (2 * math.pi)
    assert ax.R == pytest.approx(R, rel=1e-15)
    assert ax.M_r == pytest.approx(5.18e-5 / R**2, rel=1e-12)
    assert ax.M_r == pytest.approx(81.80, abs=0.01)
    assert ax.C_r == pytest.approx(6.50e-3 / R**2, rel=1e-12)
    assert round(ax.alpha, 3) == 0.080  # Table 1: inertia ratio 0.080
    assert ax.alpha == pytest.approx(6.55 / (5.18e-5 / R**2), rel=1e-12)
    assert ax.force_per_amp == pytest.approx(0.45 * 2 * math.pi / 5e-3, rel=1e-12)  # K_t = 0.45 N*m/A, 5 mm lead
    assert ax.alpha_c == pytest.approx(6.50e-3 / 5.18e-5, rel=1e-12)  # D_r / J_r [1/s], R cancels
    assert ax.beta_c == pytest.approx(1.76e3 / 40.5e6)
    # Table 1 is proportionally damped to about 0.1 %
    assert ax.proportional_damping_mismatch < 2e-3


def test_natural_frequency_is_sqrt_kvib_over_mvib(ax):
    wn = math.sqrt(ax.K_vib / ax.M_vib)
    assert ax.natural_frequency_hz == pytest.approx(wn / (2 * math.pi), rel=1e-14)
    # same thing from the physical parameters: two masses on one spring
    wn_phys = math.sqrt(ax.K_r * (1 / ax.M_r + 1 / ax.M_t))
    assert ax.natural_frequency_hz == pytest.approx(wn_phys / (2 * math.pi), rel=1e-12)
    assert 405 < ax.natural_frequency_hz < 420  # "near 411 Hz"


def test_physical_matrices_eq2(ax):
    """Properties of Eq. 2 rather than its entries: what a rigid translation and a stretch of the screw cost."""
    m = ax.matrices()
    for mat in (m.M, m.C, m.K):
        np.testing.assert_array_equal(mat, mat.T)                          # reciprocity
    rigid = np.array([1.0, 1.0])                                          # both sides move together
    np.testing.assert_allclose(m.K @ rigid, 0.0, atol=1e-9 * ax.K_r)       # ... store no spring energy
    np.testing.assert_allclose(m.C @ rigid, [ax.C_r, ax.C_t], rtol=1e-12)  # ... only the dampers to ground act
    assert rigid @ m.M @ rigid == pytest.approx(ax.M_r + ax.M_t, rel=1e-12)  # ... and the whole mass moves
    stretch = np.array([1e-6, 0.0])                                       # motor side 1 um ahead of the table
    np.testing.assert_allclose(m.K @ stretch, [40.5, -40.5], rtol=1e-12)   # K_r = 40.5 N/um, equal and opposite
    assert np.all(np.linalg.eigvalsh(m.M) > 0) and np.all(np.linalg.eigvalsh(m.C) > 0)
    assert np.linalg.eigvalsh(m.K)[1] == pytest.approx(2 * ax.K_r, rel=1e-12)  # the one elastic mode


# ------------------------------------------------------------------- modal
def test_modal_matrices_closed_forms_eq4_proportional(prop):
    a = prop.alpha
    assert prop.proportional_damping_mismatch < 1e-12
    mm = prop.modal_matrices()
    # diagonal (relative to the diagonal's scale)
    for mat in (mm.M, mm.C, mm.K):
        scale = np.abs(np.diag(mat)).max()
        assert abs(mat[0, 1]) <= 1e-12 * scale and abs(mat[1, 0]) <= 1e-12 * scale
    M_rigid = prop.M_r + prop.M_t
    M_vib = (1 + 1 / a) * prop.M_r
    K_vib = (1 + 1 / a) ** 2 * prop.K_r
    assert mm.M[0, 0] == pytest.approx(M_rigid, rel=1e-12)
    assert mm.M[1, 1] == pytest.approx(M_vib, rel=1e-12)
    assert mm.K[0, 0] == 0.0 or abs(mm.K[0, 0]) <= 1e-12 * K_vib
    assert mm.K[1, 1] == pytest.approx(K_vib, rel=1e-12)
    # C_modal = alpha_c M_modal + beta_c K_modal
    ac, bc = prop.alpha_c, prop.beta_c
    assert mm.C[0, 0] == pytest.approx(ac * M_rigid, rel=1e-12)
    assert mm.C[1, 1] == pytest.approx(ac * M_vib + bc * K_vib, rel=1e-12)
    # and the scalar properties agree with the matrices
    assert prop.M_rigid == pytest.approx(M_rigid, rel=1e-14)
    assert prop.M_vib == pytest.approx(M_vib, rel=1e-14)
    assert prop.K_vib == pytest.approx(K_vib, rel=1e-14)
    assert prop.C_rigid == pytest.approx(mm.C[0, 0], rel=1e-12)
    assert prop.C_vib == pytest.approx(mm.C[1, 1], rel=1e-12)
    # M_rigid = (1 + alpha) M_r (Appendix, Eq. 8)
    assert prop.M_rigid == pytest.approx((1 + a) * prop.M_r, rel=1e-12)


def test_modal_mass_and_stiffness_diagonal_for_any_damping(ax):
    mm = ax.modal_matrices()
    assert abs(mm.M[0, 1]) < 1e-12 * mm.M[1, 1]
    assert abs(mm.K[0, 0]) < 1e-6 * mm.K[1, 1]  # rigid-body mode has no stiffness
    assert abs(mm.K[0, 1]) < 1e-6 * mm.K[1, 1]
    # Table 1 damping is not exactly proportional: small but non-zero coupling
    assert 0 < abs(mm.C[0, 1]) < 1e-2 * mm.C[0, 0]


def test_modal_transform_matrix_and_inverse(ax):
    a = ax.alpha
    phi = ax.modal_transform()
    np.testing.assert_allclose(phi, [[1, 1], [1, -1 / a]])
    rng = np.random.default_rng(3)
    x_m, x_t = rng.normal(size=50), rng.normal(size=50)
    x_rigid, x_vib = ax.to_modal(x_m, x_t)
    # closed form of Eq. 3
    np.testing.assert_allclose(x_rigid, (x_m + a * x_t) / (1 + a), rtol=1e-13)
    np.testing.assert_allclose(x_vib, a * (x_m - x_t) / (1 + a), rtol=1e-12, atol=1e-15)
    # to_modal inverts [phi]: {x} = [phi] {x_modal}
    back = phi @ np.vstack([x_rigid, x_vib])
    np.testing.assert_allclose(back[0], x_m, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(back[1], x_t, rtol=1e-12, atol=1e-14)
    # and the other way round
    q = rng.normal(size=(2, 20))
    x = phi @ q
    np.testing.assert_allclose(np.vstack(ax.to_modal(x[0], x[1])), q, rtol=1e-11, atol=1e-13)


def test_to_modal_rigid_translation_has_no_vibration(ax):
    x_rigid, x_vib = ax.to_modal(np.full(3, 2e-3), np.full(3, 2e-3))
    np.testing.assert_allclose(x_rigid, 2e-3)
    np.testing.assert_array_equal(x_vib, 0.0)


# --------------------------------------------------------------------- FRF
def test_frf_is_inverse_dynamic_stiffness(ax):
    f = np.array([3.0, 77.0, 411.0, 1500.0])
    G = ax.frf(f)
    m = ax.matrices()
    for i, fi in enumerate(f):
        w = 2 * math.pi * fi
        Z = -(w**2) * m.M + 1j * w * m.C + m.K
        x = np.linalg.solve(Z, [1.0, 0.0])  # unit motor thrust
        y = np.linalg.solve(Z, [0.0, 1.0])  # unit table force
        np.testing.assert_allclose([G["xm_per_thrust"][i], G["xt_per_thrust"][i]], x, rtol=1e-10)
        np.testing.assert_allclose([G["xm_per_force"][i], G["xt_per_force"][i]], y, rtol=1e-10)


def test_frf_reciprocity_and_shape(ax):
    f = np.linspace(1, 2000, 12).reshape(3, 4)
    G = ax.frf(f)
    for v in G.values():
        assert v.shape == (3, 4) and np.iscomplexobj(v)
    # Maxwell-Betti: table motion per motor thrust == motor motion per table force
    np.testing.assert_allclose(G["xt_per_thrust"], G["xm_per_force"], rtol=1e-12)


def test_frf_low_frequency_is_free_rigid_body(ax, light):
    # lightly damped: x / F ~ -1 / ((M_r + M_t) w^2) between the damping corner and the resonance
    for f in (5.0, 10.0):
        w = 2 * math.pi * f
        G = light.frf([f])
        for key in ("xt_per_force", "xm_per_force", "xt_per_thrust", "xm_per_thrust"):
            assert G[key][0] == pytest.approx(-1 / ((light.M_r + light.M_t) * w**2), rel=1e-2), key
    # ... and exactly the undamped modal superposition {x} = [phi] diag(1/(k - m w^2)) [phi]^T {F}
    phi = light.modal_transform()
    for f in (5.0, 10.0, 60.0, 200.0):
        w = 2 * math.pi * f
        G = light.frf([f])
        modal = phi @ np.diag([1 / (-light.M_rigid * w**2), 1 / (light.K_vib - light.M_vib * w**2)]) @ phi.T
        np.testing.assert_allclose([[G["xm_per_thrust"][0], G["xm_per_force"][0]],
                                    [G["xt_per_thrust"][0], G["xt_per_force"][0]]], modal, rtol=5e-3)
    # Table 1 damping: the rigid mode is a damped free mass, 1 / (-M_rigid w^2 + j w C_rigid), plus
    # the (quasi-static) vibration mode's share of the table force, 1 / (alpha^2 Z_vib)
    a = ax.alpha
    for f in (1.0, 5.0, 20.0):
        w = 2 * math.pi * f
        G = ax.frf([f])
        rigid = 1 / (-ax.M_rigid * w**2 + 1j * w * ax.C_rigid)
        vib = 1 / (a**2 * (ax.K_vib - ax.M_vib * w**2 + 1j * w * ax.C_vib))
        assert G["xt_per_force"][0] == pytest.approx(rigid + vib, rel=3e-3)
        assert abs(G["xt_per_force"][0] / rigid - 1) < 0.05


def test_frf_deflection_matches_vibration_mode(prop):
    a = prop.alpha
    f = np.linspace(20, 2000, 400)
    w = 2 * math.pi * f
    G = prop.frf(f)
    defl = G["xm_per_force"] - G["xt_per_force"]
    closed = -(1 + 1 / a) / a / (prop.K_vib - prop.M_vib * w**2 + 1j * w * prop.C_vib)
    np.testing.assert_allclose(defl, closed, rtol=1e-9)
    # static deflection: the whole force goes through the spring K_r, times M_r/(M_r+M_t)
    G0 = prop.frf([1e-3])
    static = -(prop.M_r / (prop.M_r + prop.M_t)) / prop.K_r
    assert (G0["xm_per_force"] - G0["xt_per_force"])[0].real == pytest.approx(static, rel=1e-3)


@pytest.mark.parametrize("which", ["table1", "light"])
def test_frf_deflection_peaks_at_natural_frequency(which, ax, light):
    axis = ax if which == "table1" else light
    f = np.linspace(100, 1000, 9001)
    G = axis.frf(f)
    defl = np.abs(G["xm_per_force"] - G["xt_per_force"])
    f_peak = f[np.argmax(defl)]
    mm = axis.modal_matrices()
    zeta = mm.C[1, 1] / (2 * math.sqrt(mm.K[1, 1] * mm.M[1, 1]))
    # peak of a displacement FRF: w_n sqrt(1 - 2 zeta^2)
    expected = axis.natural_frequency_hz * math.sqrt(1 - 2 * zeta**2)
    assert f_peak == pytest.approx(expected, rel=5e-3)
    assert f_peak == pytest.approx(axis.natural_frequency_hz, rel=0.02)
    # phase of the deflection passes -90 deg relative to its static value at w_n (modal quadrature)
    Gn = axis.frf([axis.natural_frequency_hz])
    d_n = (Gn["xm_per_force"] - Gn["xt_per_force"])[0]
    d_0 = (lambda g: (g["xm_per_force"] - g["xt_per_force"])[0])(axis.frf([1e-3]))
    assert abs(np.degrees(np.angle(d_n / d_0)) + 90) < 1.0


def test_frf_antiresonances(light):
    f = np.linspace(50, 800, 15001)
    G = light.frf(f)
    # motor does not move under motor thrust where the table alone resonates on the spring
    f_a1 = math.sqrt(light.K_r / light.M_t) / (2 * math.pi)
    assert f[np.argmin(np.abs(G["xm_per_thrust"]))] == pytest.approx(f_a1, rel=2e-3)
    # table does not move under a table force where the motor side alone resonates
    f_a2 = math.sqrt(light.K_r / light.M_r) / (2 * math.pi)
    assert f[np.argmin(np.abs(G["xt_per_force"]))] == pytest.approx(f_a2, rel=2e-3)
    # and both transfer functions peak at the coupled natural frequency, above both anti-resonances
    for key in ("xm_per_thrust", "xt_per_force", "xt_per_thrust"):
        assert f[np.argmax(np.abs(G[key]) * (f > 200))] == pytest.approx(light.natural_frequency_hz, rel=3e-3)
    assert f_a2 < f_a1 < light.natural_frequency_hz


# ------------------------------------------------------------- persistence
def test_to_dict_from_dict_roundtrip(ax):
    d = ax.to_dict()
    assert set(d) == set(FIELDS)
    assert all(type(v) is float for v in d.values())
    assert BallScrewAxis.from_dict(d) == ax


def test_from_dict_names_missing_keys(ax):
    d = ax.to_dict()
    del d["K_r"], d["lead"]
    with pytest.raises(ConfigError) as exc:
        BallScrewAxis.from_dict(d, source="x.axis.json")
    msg = str(exc.value)
    assert "x.axis.json" in msg and "missing" in msg and "K_r" in msg and "lead" in msg


def test_from_dict_names_unknown_keys(ax):
    d = {**ax.to_dict(), "Kr": 1.0, "mass": 2.0}
    with pytest.raises(ConfigError) as exc:
        BallScrewAxis.from_dict(d)
    msg = str(exc.value)
    assert "unknown" in msg and "Kr" in msg and "mass" in msg


def test_from_dict_bad_value_names_field_and_source(ax):
    d = {**ax.to_dict(), "M_t": -1.0}
    with pytest.raises(ConfigError, match=r"(?s)x\.json.*M_t"):
        BallScrewAxis.from_dict(d, source="x.json")


@pytest.mark.parametrize("name", FIELDS)
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), -1.0])
def test_bad_values_raise_config_error_naming_field(ax, name, bad):
    with pytest.raises(ConfigError, match=rf"'{name}'"):
        replace(ax, **{name: bad})


@pytest.mark.parametrize("name", ["J_r", "M_t", "K_r", "lead", "K_t"])
def test_zero_not_allowed_for_masses_stiffness_geometry(ax, name):
    with pytest.raises(ConfigError, match=rf"'{name}'"):
        replace(ax, **{name: 0.0})


@pytest.mark.parametrize("name", ["C_t", "C_k", "D_r"])
def test_zero_damping_is_allowed(ax, name):
    axis = replace(ax, **{name: 0.0})
    assert getattr(axis, name) == 0.0


@pytest.mark.parametrize("bad", ["1.0", None, True, [1.0]])
def test_non_numbers_raise_config_error(ax, bad):
    with pytest.raises(ConfigError, match="'M_t'"):
        replace(ax, M_t=bad)


def test_config_error_is_a_value_error(ax):
    with pytest.raises(ValueError):
        replace(ax, K_r=0.0)
