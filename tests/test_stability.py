"""Milling stability lobes by the zeroth-order approximation (drivesense.machine.stability) against closed forms.

No published numeric lobe diagram (e.g. Altintas' book examples) could be
verified while writing these tests, so none is quoted: the checks are the
single-degree-of-freedom closed form of the ZOA, the symmetric-slot closed
form, the averaged directional matrix computed independently from the force
law of :mod:`drivesense.machine.milling`, and scaling laws.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from drivesense.errors import ConfigError
from drivesense.machine.milling import CuttingCoefficients, engagement_angles
from drivesense.machine.stability import (StabilityLobes, absolute_depth_limit, critical_depth,
                                          directional_factors, stability_lobes)
from drivesense.machine.tool_dynamics import ToolDynamics, ToolMode
from drivesense.plot.figure import save_figure
from drivesense.plot.stability import plot_stability_lobes

CC = CuttingCoefficients.aluminium()          # Ktc = 796 N/mm^2, Krc = 168 N/mm^2
KR = CC.Krc / CC.Ktc                          # 0.211
N = 4
F_N, ZETA, K = 600.0, 0.03, 5.0e6             # one tool mode [Hz], [-], [N/m]
SLOT = (0.0, math.pi)
UP_HALF = engagement_angles(0.01, 0.005, "up")        # (0, pi/2)
DOWN_HALF = engagement_angles(0.01, 0.005, "down")    # (pi/2, pi)
DOWN_QUARTER = engagement_angles(0.01, 0.0025, "down")  # (2 pi/3, pi)
CASES = {"slot": SLOT, "up_half": UP_HALF, "down_half": DOWN_HALF, "down_quarter": DOWN_QUARTER}


def _tooth_matrix(phi, kr):
    """d F / d(dx, dy) per unit ``a K_tc`` for one tooth at ``phi``, from the force law of milling.py.

    ``h = dx sin phi + dy cos phi``, ``F_t = a K_tc h``, ``F_r = K_r F_t``,
    ``F_x = -F_t cos phi - F_r sin phi``, ``F_y = F_t sin phi - F_r cos phi``.
    """
    b = np.array([-np.cos(phi) - kr * np.sin(phi), np.sin(phi) - kr * np.cos(phi)])
    s = np.array([np.sin(phi), np.cos(phi)])
    return np.einsum("i...,j...->...ij", b, s)


def _sdof_receptance(f, fn=F_N, zeta=ZETA, k=K):
    r = f / fn
    return 1.0 / (k * (1 - r ** 2 + 2j * zeta * r))


# ----------------------------------------------------------------------- directional factors
@pytest.mark.parametrize("case", list(CASES))
def test_directional_factors_are_the_integrals_of_the_force_law(case):
    st, ex = CASES[case]
    alpha = directional_factors(st, ex, KR)
    # F = (a K_tc / 2) a(phi) d  =>  the integral of a(phi) = 2 * integral of the tooth matrix
    num = np.array([[2 * quad(lambda p: _tooth_matrix(p, KR)[i, j], st, ex, epsabs=1e-13, epsrel=1e-13)[0]
                     for j in range(2)] for i in range(2)])
    np.testing.assert_allclose(alpha, num, rtol=0, atol=1e-11)


@pytest.mark.parametrize("case", list(CASES))
def test_mean_of_the_time_varying_directional_matrix_is_n_over_2pi_alpha(case):
    st, ex = CASES[case]
    flutes, m = 3, 1 << 17
    theta = (np.arange(m) + 0.5) * 2 * np.pi / m            # one spindle revolution, midpoint samples
    total = np.zeros((m, 2, 2))
    for j in range(flutes):
        phi = np.mod(theta + j * 2 * np.pi / flutes, 2 * np.pi)
        gate = ((phi >= st) & (phi <= ex))[:, None, None]
        total += gate * 2 * _tooth_matrix(phi, KR)          # Altintas' A(t) = sum_j g_j a(phi_j)
    np.testing.assert_allclose(total.mean(axis=0), flutes / (2 * np.pi) * directional_factors(st, ex, KR),
                               rtol=0, atol=2e-4)


def test_slot_directional_factors_closed_form():
    np.testing.assert_allclose(directional_factors(*SLOT, KR), np.pi * np.array([[-KR, -1.0], [1.0, -KR]]),
                               rtol=0, atol=1e-14)


# ----------------------------------------------------------------------- single-DOF closed form
def _sdof_minimum(alpha_dd, k=K, zeta=ZETA, fn=F_N):
    """(a_lim,min [m], chatter frequency [Hz]) of a single mode with directional factor alpha_dd.

    The eigenvalue of ``alpha_dd G`` is ``lambda = alpha_dd G``, ``Lambda = -1 / lambda`` and
    ``a_lim = -2 pi Lambda_R (1 + kappa^2) / (N K_tc) = 2 pi / (N K_tc alpha_dd Re G)``, positive
    only where ``alpha_dd Re G > 0``.  ``Re G`` of a mode ranges over
    ``[-1 / (4 k zeta (1 + zeta)), 1 / (4 k zeta (1 - zeta))]``, reached at ``r^2 = 1 + 2 zeta``
    and ``r^2 = 1 - 2 zeta``, so for alpha_dd < 0 (e.g. a slot in x) the minimum is
    ``a = 8 pi k zeta (1 + zeta) / (N K_tc |alpha_dd|)`` above the resonance, and for
    alpha_dd > 0 ``a = 8 pi k zeta (1 - zeta) / (N K_tc alpha_dd)`` below it.
    """
    if alpha_dd < 0:
        return 8 * np.pi * k * zeta * (1 + zeta) / (N * CC.Ktc * -alpha_dd), fn * math.sqrt(1 + 2 * zeta)
    return 8 * np.pi * k * zeta * (1 - zeta) / (N * CC.Ktc * alpha_dd), fn * math.sqrt(1 - 2 * zeta)


@pytest.mark.parametrize("case, direction", [("slot", "x"), ("down_half", "x"), ("up_half", "y"),
                                             ("down_quarter", "y")])
def test_single_mode_absolute_limit_is_the_closed_form(case, direction):
    st, ex = CASES[case]
    mode = ToolMode(F_N, ZETA, K)
    dyn = ToolDynamics(**{direction: (mode,)})                  # the other direction rigid
    alpha = directional_factors(st, ex, KR)
    a_dd = alpha[0, 0] if direction == "x" else alpha[1, 1]
    expected, _ = _sdof_minimum(a_dd)
    assert absolute_depth_limit(dyn, CC, N, st, ex) == pytest.approx(expected, rel=1e-6)
    lobes = stability_lobes(dyn, CC, N, st, ex, rpm_range=(2000.0, 20000.0))
    assert np.all(np.isfinite(lobes.depth_limit))
    assert np.min(lobes.depth_limit) == pytest.approx(expected, rel=1e-2)
    assert np.min(lobes.depth_limit) >= expected * (1 - 1e-9)


def test_slot_x_mode_numbers():
    """The worked numbers of the x-only slot (k = 5e6 N/m, zeta = 0.03, 4 flutes, Al7075)."""
    alpha_xx = directional_factors(*SLOT, KR)[0, 0]
    assert alpha_xx == pytest.approx(-np.pi * KR)               # -0.6630
    expected = 8 * K * ZETA * (1 + ZETA) / (N * CC.Ktc * KR)   # = 1.839 mm
    assert expected == pytest.approx(1.8393e-3, rel=1e-4)
    assert absolute_depth_limit(ToolDynamics(x=(ToolMode(F_N, ZETA, K),)), CC, N, *SLOT) == pytest.approx(
        expected, rel=1e-6)


@pytest.mark.parametrize("case", ["slot", "down_half"])
def test_lobe_bottoms_sit_at_the_closed_form_speeds(case):
    st, ex = CASES[case]
    dyn = ToolDynamics(x=(ToolMode(F_N, ZETA, K),))
    alpha_xx = directional_factors(st, ex, KR)[0, 0]
    a_min, fc = _sdof_minimum(alpha_xx)
    g = _sdof_receptance(fc)
    psi = math.atan2(g.imag, g.real)                  # phase of G at the chatter frequency
    # epsilon = pi - 2 atan(kappa) = pi + 2 arg(alpha_xx G): 3 pi + 2 psi for alpha_xx < 0, pi + 2 psi for > 0
    eps = 3 * math.pi + 2 * psi if alpha_xx < 0 else math.pi + 2 * psi
    assert 0 < eps < 2 * math.pi
    lobes = stability_lobes(dyn, CC, N, st, ex, rpm_range=(1500.0, 20000.0), points=4000)
    for k in (1, 2, 3):
        n_k = 60 * 2 * math.pi * fc / (N * (eps + 2 * k * math.pi))
        assert lobes.spindle_rpm[0] < n_k < lobes.spindle_rpm[-1]
        # the k-th lobe's bottom: a local sweep of the speed has its minimum, a_lim,min, at n_k
        width = 0.3 / (k + 1)
        speeds = n_k * (1 + np.linspace(-width, width, 21))
        depths = np.array([critical_depth(dyn, CC, N, st, ex, n) for n in speeds])
        assert int(np.argmin(depths)) == 10
        assert depths[10] == pytest.approx(a_min, rel=1e-4)
        assert min(depths[0], depths[-1]) > 1.2 * a_min
        i = int(np.argmin(np.abs(lobes.spindle_rpm - n_k)))
        assert lobes.depth_limit[i] == pytest.approx(a_min, rel=1e-2)
        assert lobes.chatter_frequency_hz[i] == pytest.approx(fc, rel=1e-2)


def test_symmetric_slot_closed_form():
    """Slot, the same mode in x and y: [alpha] = pi [[-K_r, -1], [1, -K_r]], eigenvalues pi (-K_r +- i) G.

    ``Re(lambda) = pi (-K_r Re G -+ Im G)``, so ``a_lim,min = 2 / (N K_tc max(|Im G| - K_r Re G))``.
    """
    f = np.linspace(0.5 * F_N, 1.5 * F_N, 2_000_001)
    g = _sdof_receptance(f)
    expected = 2 / (N * CC.Ktc * np.max(np.abs(g.imag) - KR * g.real))
    dyn = ToolDynamics.symmetric(F_N, ZETA, K)
    assert absolute_depth_limit(dyn, CC, N, *SLOT) == pytest.approx(expected, rel=1e-6)


# ----------------------------------------------------------------------- scaling and consistency
def test_limit_scales_with_stiffness_and_damping():
    st, ex = SLOT
    base = ToolDynamics(x=(ToolMode(F_N, 0.02, K),))
    stiff = ToolDynamics(x=(ToolMode(F_N, 0.02, 2.5 * K),))
    damped = ToolDynamics(x=(ToolMode(F_N, 0.04, K),))
    a0 = absolute_depth_limit(base, CC, N, st, ex)
    assert absolute_depth_limit(stiff, CC, N, st, ex) == pytest.approx(2.5 * a0, rel=1e-9)
    assert absolute_depth_limit(damped, CC, N, st, ex) == pytest.approx(a0 * 0.04 * 1.04 / (0.02 * 1.02), rel=1e-6)
    l0 = stability_lobes(base, CC, N, st, ex, rpm_range=(3000.0, 15000.0), points=500)
    l1 = stability_lobes(stiff, CC, N, st, ex, rpm_range=(3000.0, 15000.0), points=500)
    np.testing.assert_allclose(l1.depth_limit, 2.5 * l0.depth_limit, rtol=1e-9)
    np.testing.assert_allclose(l1.chatter_frequency_hz, l0.chatter_frequency_hz, rtol=1e-9)


@pytest.mark.parametrize("case", ["slot", "up_half", "down_quarter"])
def test_envelope_agrees_with_critical_depth_for_coupled_modes(case):
    st, ex = CASES[case]
    dyn = ToolDynamics(x=(ToolMode(600.0, 0.03, 5e6), ToolMode(1100.0, 0.02, 2e7)),
                       y=(ToolMode(750.0, 0.04, 8e6),))
    lobes = stability_lobes(dyn, CC, 3, st, ex, rpm_range=(3000.0, 30000.0), points=3000)
    assert isinstance(lobes, StabilityLobes)
    assert lobes.spindle_rpm.shape == lobes.depth_limit.shape == lobes.chatter_frequency_hz.shape == (3000,)
    assert np.all(np.isfinite(lobes.depth_limit)) and np.all(lobes.depth_limit > 0)
    assert np.min(lobes.depth_limit) == pytest.approx(absolute_depth_limit(dyn, CC, 3, st, ex), rel=1e-3)
    for i in (100, 777, 1500, 2400):
        assert lobes.depth_limit[i] == pytest.approx(
            critical_depth(dyn, CC, 3, st, ex, lobes.spindle_rpm[i]), rel=1e-3)


def test_too_few_lobes_leave_low_speeds_uncovered():
    dyn = ToolDynamics(x=(ToolMode(F_N, ZETA, K),))
    lobes = stability_lobes(dyn, CC, N, *SLOT, rpm_range=(500.0, 20000.0), lobes=range(3), points=500)
    assert np.isnan(lobes.depth_limit[0]) and np.isfinite(lobes.depth_limit[-1])


# ----------------------------------------------------------------------- errors
DYN = ToolDynamics(x=(ToolMode(F_N, ZETA, K),))


@pytest.mark.parametrize("call, name", [
    (lambda: stability_lobes(DYN, CC, 0, *SLOT), "flutes"),
    (lambda: stability_lobes(DYN, CC, 2.5, *SLOT), "flutes"),
    (lambda: stability_lobes(DYN, CC, N, *SLOT, rpm_range=(5000.0, 1000.0)), "rpm_range"),
    (lambda: stability_lobes(DYN, CC, N, *SLOT, rpm_range=(0.0, 1000.0)), "rpm_range"),
    (lambda: stability_lobes(DYN, CC, N, *SLOT, rpm_range=5000.0), "rpm_range"),
    (lambda: stability_lobes(DYN, CC, N, *SLOT, lobes=[-1, 2]), "lobes"),
    (lambda: stability_lobes(DYN, CC, N, *SLOT, points=3), "points"),
    (lambda: stability_lobes(DYN, CC, N, 1.0, 1.0), "phi_ex"),
    (lambda: stability_lobes(DYN, CC, N, 1.0, 0.5), "phi_ex"),
    (lambda: stability_lobes(DYN, CC, N, -0.5, 1.0), "phi_st"),
    (lambda: stability_lobes(DYN, CC, N, 0.0, 4.0), "phi_ex"),
    (lambda: stability_lobes("dyn", CC, N, *SLOT), "dynamics"),
    (lambda: stability_lobes(DYN, {"Ktc": 1}, N, *SLOT), "coefficients"),
    (lambda: stability_lobes(DYN, CuttingCoefficients(0.0, 1.0, 0.0, 0.0, 0.0, 0.0), N, *SLOT), "Ktc"),
    (lambda: critical_depth(DYN, CC, N, *SLOT, 0.0), "spindle_rpm"),
    (lambda: absolute_depth_limit(DYN, CC, 0, *SLOT), "flutes"),
    (lambda: directional_factors(0.0, math.pi, float("nan")), "radial_ratio"),
])
def test_bad_input_raises_config_error_naming_the_argument(call, name):
    with pytest.raises(ConfigError, match=name):
        call()


# ----------------------------------------------------------------------- figure
def test_plot_writes_a_png(tmp_path):
    lobes = stability_lobes(DYN, CC, N, *SLOT, rpm_range=(2000.0, 20000.0), points=500)
    a = float(np.min(lobes.depth_limit))
    fig = plot_stability_lobes(lobes, cuts=[(9000.0, 0.5 * a, "stable"), (9000.0, 3 * a, "chatter"),
                                            (12000.0, 2 * a, "chatter")], title="x-only slot")
    assert fig.axes and all(ax.has_data() for ax in fig.axes)
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "stable cut" in labels and "chatter" in labels
    path = save_figure(fig, tmp_path / "out" / "lobes.png")
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert (int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")) == (990, 660)
    assert [p.name for p in path.parent.iterdir()] == ["lobes.png"]
    with pytest.raises(ConfigError, match="cuts"):
        plot_stability_lobes(lobes, cuts=[(9000.0, a, "maybe")])
