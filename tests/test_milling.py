"""Tests of the mechanistic end-milling model against closed forms (Altintas ch. 2).

Closed-form means used as references (zero runout, fully entered; derived from
h = c sin(phi), dF_t = (K_tc h + K_te) dz, dF_r = (K_rc h + K_re) dz,
dF_a = (K_ac h + K_ae) dz and the projection of ``milling.py``). Averaged over a
tooth period, N flutes each sweep [phi_st, phi_ex] once per revolution, so
``mean F = N/(2 pi) * integral_{phi_st}^{phi_ex} F_flute(phi) dphi`` with a the
axial depth, R = D/2:

  mean F_x = N a/(2 pi) [ c/4 (K_tc cos 2phi - K_rc (2phi - sin 2phi)) - K_te sin phi + K_re cos phi ]
  mean F_y = N a/(2 pi) [ c/4 (K_tc (2phi - sin 2phi) + K_rc cos 2phi) - K_te cos phi - K_re sin phi ]
  mean F_z = N a/(2 pi) [ -K_ac c cos phi + K_ae phi ]
  mean T   = N a R/(2 pi) [ -K_tc c cos phi + K_te phi ]

each evaluated as [.]_{phi_st}^{phi_ex} (Altintas Eq. 2.18; independent of the
helix). Hence the mean power T omega = K_tc Q + K_te A_c with Q = a_e a v_f and
A_c = a R (phi_ex - phi_st) N n (the second paper's Eq. 2).
"""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
from scipy.integrate import quad

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.machine import milling
from drivesense.machine.milling import (
    CuttingCoefficients,
    EndMill,
    MillingCut,
    average_chip_thickness,
    engagement_angles,
    feed_per_tooth,
    material_removal_rate,
    milling_forces,
    tooth_passing_frequency,
)

K = CuttingCoefficients.aluminium()
D = 0.012
C = 0.1e-3


def closed_form_means(k, n_flutes, a, d, c, st, ex):
    """Mean (F_x, F_y, F_z, T) over a tooth period, closed form (module docstring)."""
    def prim_x(p):
        return c / 4 * (k.Ktc * math.cos(2 * p) - k.Krc * (2 * p - math.sin(2 * p))) \
            - k.Kte * math.sin(p) + k.Kre * math.cos(p)

    def prim_y(p):
        return c / 4 * (k.Ktc * (2 * p - math.sin(2 * p)) + k.Krc * math.cos(2 * p)) \
            - k.Kte * math.cos(p) - k.Kre * math.sin(p)

    def prim_z(p):
        return -k.Kac * c * math.cos(p) + k.Kae * p

    def prim_t(p):
        return 0.5 * d * (-k.Ktc * c * math.cos(p) + k.Kte * p)

    scale = n_flutes * a / (2 * math.pi)
    return np.array([scale * (f(ex) - f(st)) for f in (prim_x, prim_y, prim_z, prim_t)])


def one_rev(samples=20000, revs=1):
    """Uniform angles over whole revolutions, half a step off the grid's edges."""
    m = samples * revs
    return (np.arange(m) + 0.5) * (2 * math.pi * revs / m)


def as_array(f):
    return np.array([f.feed, f.normal, f.axial, f.torque])


def reference_forces(tool, k, cut, angle, c, feed_progress=None):
    """Plain (slow, obvious) evaluation of the model, to cross-check the kernel."""
    st, ex = engagement_angles(tool.diameter, cut.radial_depth, cut.mode)
    r = 0.5 * tool.diameter
    dz = cut.axial_depth / cut.axial_slices
    z = (np.arange(cut.axial_slices) + 0.5) * dz
    j = np.arange(tool.flutes)
    rj = r + tool.runout * np.cos(tool.runout_phase - j * 2 * np.pi / tool.flutes)
    dr = rj - np.roll(rj, 1)
    phi = (angle[:, None, None] + j[None, :, None] * 2 * np.pi / tool.flutes
           - z[None, None, :] * np.tan(np.radians(tool.helix_deg)) / r)
    phi = np.mod(phi, 2 * np.pi)
    c = np.broadcast_to(np.asarray(c, float), angle.shape)[:, None, None]
    h = c * np.sin(phi) + dr[None, :, None]
    on = (phi >= st) & (phi <= ex) & (h > 0)
    if feed_progress is not None:
        on &= feed_progress[:, None, None] + r * np.sin(phi) >= 0
    ft = np.where(on, (k.Ktc * h + k.Kte) * dz, 0.0)
    fr = np.where(on, (k.Krc * h + k.Kre) * dz, 0.0)
    fa = np.where(on, (k.Kac * h + k.Kae) * dz, 0.0)
    fx = (-ft * np.cos(phi) - fr * np.sin(phi)).sum(axis=(1, 2))
    fy = (ft * np.sin(phi) - fr * np.cos(phi)).sum(axis=(1, 2))
    return np.array([fx, fy, fa.sum(axis=(1, 2)), (ft * rj[None, :, None]).sum(axis=(1, 2))])


# --- geometry -------------------------------------------------------------------------------

def test_engagement_angles_slot_and_quarter_immersion():
    for mode in ("up", "down"):
        assert engagement_angles(D, D, mode) == pytest.approx((0.0, math.pi))
    assert engagement_angles(D, D / 4, "up") == pytest.approx((0.0, math.pi / 3))
    assert engagement_angles(D, D / 4, "down") == pytest.approx((2 * math.pi / 3, math.pi))
    assert engagement_angles(D, D / 2, "up") == pytest.approx((0.0, math.pi / 2))
    assert engagement_angles(D, D / 2, "down") == pytest.approx((math.pi / 2, math.pi))


def test_helpers_feed_per_tooth_tpf_chip_thickness_mrr():
    assert tooth_passing_frequency(6000.0, 4) == pytest.approx(400.0)
    omega = 6000.0 * 2 * math.pi / 60
    assert feed_per_tooth(0.04, omega, 4) == pytest.approx(0.04 / (4 * 100.0))
    np.testing.assert_allclose(feed_per_tooth([0.0, 0.02], [omega, omega], 2), [0.0, 1e-4])
    # slot: h_avg = 2c/pi; quarter immersion up: c (1 - 1/2) / (pi/3)
    assert average_chip_thickness(C, D, D, "up") == pytest.approx(2 * C / math.pi)
    assert average_chip_thickness(C, D, D / 4, "down") == pytest.approx(C * 0.5 / (math.pi / 3))
    assert material_removal_rate(MillingCut(0.003, 0.002), 0.01) == pytest.approx(6e-8)


# --- mean forces ------------------------------------------------------------------------------

CUTS = [(D, "down"), (D / 4, "up"), (D / 4, "down"), (D / 2, "down"), (0.7 * D, "up")]


@pytest.mark.parametrize("ae, mode", CUTS)
def test_closed_form_matches_numerical_integration(ae, mode):
    """The derivation in the module docstring, checked by quadrature of the flute force."""
    st, ex = engagement_angles(D, ae, mode)
    a, n = 2e-3, 3

    def flute(p):
        h = C * math.sin(p)
        ft, fr, fa = K.Ktc * h + K.Kte, K.Krc * h + K.Kre, K.Kac * h + K.Kae
        return a * np.array([-ft * math.cos(p) - fr * math.sin(p), ft * math.sin(p) - fr * math.cos(p),
                             fa, ft * D / 2])

    numeric = [n / (2 * math.pi) * quad(lambda p: flute(p)[i], st, ex, epsabs=0, epsrel=1e-12)[0]
               for i in range(4)]
    np.testing.assert_allclose(closed_form_means(K, n, a, D, C, st, ex), numeric, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("helix", [0.0, 30.0])
@pytest.mark.parametrize("ae, mode", CUTS)
def test_mean_forces_equal_closed_form(ae, mode, helix):
    tool = EndMill(D, 3, helix_deg=helix)
    cut = MillingCut(ae, 2e-3, mode, axial_slices=1 if helix == 0 else 40)
    f = as_array(milling_forces(tool, K, cut, one_rev(), C)).mean(axis=1)
    ref = closed_form_means(K, 3, 2e-3, D, C, *engagement_angles(D, ae, mode))
    scale = np.abs(ref[:3]).max()
    np.testing.assert_allclose(f[:3], ref[:3], rtol=5e-3, atol=1e-3 * scale)
    assert f[3] == pytest.approx(ref[3], rel=5e-3)


def test_kernel_matches_plain_evaluation_with_helix_runout_and_entry():
    tool = EndMill(D, 3, helix_deg=35.0, runout=8e-6, runout_phase=0.4)
    cut = MillingCut(0.4 * D, 4e-3, "up", axial_slices=7)
    angle = np.linspace(0.0, 6 * math.pi, 1500)
    c = np.linspace(0.5, 1.5, angle.size) * C
    fp = np.linspace(-D, D, angle.size)
    got = as_array(milling_forces(tool, K, cut, angle, c, feed_progress=fp))
    ref = reference_forces(tool, K, cut, angle, c, fp)
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_sign_conventions_single_flute_quarter_point():
    """At phi = pi/2 (edge ahead of the tool, chip c) the tool is pushed back and outward."""
    tool = EndMill(D, 1, helix_deg=0.0)
    f = milling_forces(tool, K, MillingCut(D, 1e-3, axial_slices=1), [math.pi / 2], C)
    ft, fr = (K.Ktc * C + K.Kte) * 1e-3, (K.Krc * C + K.Kre) * 1e-3
    assert f.feed[0] == pytest.approx(-fr)     # -Ft cos - Fr sin
    assert f.normal[0] == pytest.approx(ft)    # +Ft sin - Fr cos
    assert f.axial[0] == pytest.approx((K.Kac * C + K.Kae) * 1e-3)
    assert f.torque[0] == pytest.approx(ft * D / 2)


# --- periodicity, runout, helix ---------------------------------------------------------------

def _spectrum(x, revs):
    amp = np.abs(np.fft.rfft(x)) / x.size
    return amp[revs], amp[2 * revs]        # once per rev, tooth passing (2 flutes)


def test_slot_two_flutes_periodic_at_tooth_pass_and_runout_adds_spindle_frequency():
    revs, spr = 8, 4096
    angle = one_rev(spr, revs)
    cut = MillingCut(D, 2e-3, axial_slices=1)
    clean = milling_forces(EndMill(D, 2, helix_deg=0.0), K, cut, angle, C)
    shifted = np.roll(clean.normal, -spr // 2)
    np.testing.assert_allclose(clean.normal, shifted, atol=1e-9 * np.abs(clean.normal).max())
    wobbly = milling_forces(EndMill(D, 2, helix_deg=0.0, runout=10e-6), K, cut, angle, C)
    for name in ("feed", "normal", "torque"):
        rev0, tooth0 = _spectrum(getattr(clean, name), revs)
        rev1, tooth1 = _spectrum(getattr(wobbly, name), revs)
        assert rev0 < 1e-9 * tooth0
        assert rev1 > 0.1 * tooth1


@pytest.mark.parametrize("mode", ["up", "down"])
def test_helix_reduces_peak_to_peak(mode):
    cut = MillingCut(D / 4, 10e-3, mode, axial_slices=40)
    angle = one_rev(4000)
    straight = milling_forces(EndMill(D, 2, helix_deg=0.0), K, cut, angle, C)
    helical = milling_forces(EndMill(D, 2, helix_deg=30.0), K, cut, angle, C)
    for name in ("feed", "normal", "axial", "torque"):
        p0, p1 = np.ptp(getattr(straight, name)), np.ptp(getattr(helical, name))
        assert p1 < 0.9 * p0, name
    # ... while the means stay those of Eq. 2.18
    assert helical.torque.mean() == pytest.approx(straight.torque.mean(), rel=2e-3)


# --- entry transient -------------------------------------------------------------------------

@pytest.mark.parametrize("ae, mode", [(D, "up"), (D / 2, "down"), (D / 4, "up")])
def test_entry_transient_builds_up_monotonically(ae, mode):
    n_flutes, spt, periods = 2, 400, 120      # samples per tooth period, tooth periods
    angle = (np.arange(spt * periods) + 0.5) * (2 * math.pi / n_flutes / spt)
    fp = np.linspace(-D, D, angle.size)
    tool = EndMill(D, n_flutes, helix_deg=30.0)
    cut = MillingCut(ae, 3e-3, mode, axial_slices=10)
    f = milling_forces(tool, K, cut, angle, C, feed_progress=fp)
    full = milling_forces(tool, K, cut, angle, C)
    before = fp < -D / 2
    for name in ("feed", "normal", "axial", "torque"):
        assert np.all(getattr(f, name)[before] == 0.0), name
    windows = f.torque.reshape(periods, spt).mean(axis=1)
    axial = f.axial.reshape(periods, spt).mean(axis=1)
    full_mean = full.torque.reshape(periods, spt).mean(axis=1)
    assert np.all(np.diff(windows) >= -1e-12 * full_mean.max())
    assert np.all(np.diff(axial) >= -1e-12 * np.abs(axial).max())
    assert windows[0] == 0.0 and windows.max() > 0
    entered = fp.reshape(periods, spt).min(axis=1) >= 0
    np.testing.assert_allclose(windows[entered], full_mean[entered], rtol=1e-12)
    for name in ("feed", "normal"):
        np.testing.assert_array_equal(getattr(f, name)[fp >= 0], getattr(full, name)[fp >= 0])


# --- power ----------------------------------------------------------------------------------

def test_power_flows_only_while_the_flute_cuts():
    """One straight flute, quarter-immersion up-milling: engaged for phi in [0, pi/3], and only there."""
    angle = one_rev(600)
    f = milling_forces(EndMill(D, 1, helix_deg=0.0), K, MillingCut(D / 4, 2e-3, "up", axial_slices=1), angle, C)
    p = f.power(800.0)
    engaged = np.mod(angle, 2 * math.pi) <= math.pi / 3
    assert 0 < engaged.sum() < angle.size
    assert np.all(p[engaged] > 0) and np.all(p[~engaged] == 0.0)       # the spindle does work on the chip
    np.testing.assert_array_equal(f.power(np.full(angle.size, 800.0)), p)   # a constant per-sample speed = a scalar


def test_slot_mean_power_closed_form():
    n, a, omega = 2, 3e-3, 1000.0
    f = milling_forces(EndMill(D, n, helix_deg=30.0), K, MillingCut(D, a), one_rev(20000), C)
    mean_torque = n * a * (D / 2) / (2 * math.pi) * (2 * K.Ktc * C + math.pi * K.Kte)
    assert f.power(omega).mean() == pytest.approx(mean_torque * omega, rel=5e-3)


@pytest.mark.parametrize("ae, mode", CUTS)
def test_mean_power_is_ktc_mrr_plus_kte_contact_rate(ae, mode):
    n, a, omega = 3, 2.5e-3, 900.0
    vf = C * n * omega / (2 * math.pi)
    st, ex = engagement_angles(D, ae, mode)
    cut = MillingCut(ae, a, mode, axial_slices=25)
    f = milling_forces(EndMill(D, n, helix_deg=40.0), K, cut, one_rev(20000), feed_per_tooth(vf, omega, n))
    contact_rate = a * (D / 2) * (ex - st) * n * omega / (2 * math.pi)       # [m^2/s]
    expected = K.Ktc * material_removal_rate(cut, vf) + K.Kte * contact_rate
    assert f.power(omega).mean() == pytest.approx(expected, rel=5e-3)


# --- validation -----------------------------------------------------------------------------

GOOD_TOOL, GOOD_CUT = EndMill(D, 2), MillingCut(D / 2, 1e-3)


@pytest.mark.parametrize("make, name", [
    (lambda: EndMill(0.0, 2), "diameter"),
    (lambda: EndMill(-D, 2), "diameter"),
    (lambda: EndMill(D, 0), "flutes"),
    (lambda: EndMill(D, 2.5), "flutes"),
    (lambda: EndMill(D, 2, helix_deg=90.0), "helix_deg"),
    (lambda: EndMill(D, 2, runout=-1e-6), "runout"),
    (lambda: EndMill(D, 2, runout_phase=math.nan), "runout_phase"),
    (lambda: MillingCut(0.0, 1e-3), "radial_depth"),
    (lambda: MillingCut(-1e-3, 1e-3), "radial_depth"),
    (lambda: MillingCut(1e-3, 0.0), "axial_depth"),
    (lambda: MillingCut(1e-3, 1e-3, mode="climb"), "mode"),
    (lambda: MillingCut(1e-3, 1e-3, axial_slices=0), "axial_slices"),
    (lambda: CuttingCoefficients(math.inf, 1, 1, 1, 1, 1), "Ktc"),
    (lambda: engagement_angles(D, 1.01 * D, "up"), "radial_depth"),
    (lambda: milling_forces(GOOD_TOOL, K, MillingCut(2 * D, 1e-3), [0.0, 1.0], C), "radial_depth"),
    (lambda: tooth_passing_frequency(1000.0, 0), "flutes"),
])
def test_bad_configuration_raises_config_error(make, name):
    with pytest.raises(ConfigError, match=name) as info:
        make()
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("kwargs, name", [
    (dict(feed_per_tooth=-1e-5), "feed_per_tooth"),
    (dict(feed_per_tooth=[C, C]), "feed_per_tooth"),
    (dict(spindle_angle=[0.0, math.nan, 1.0]), "spindle_angle"),
    (dict(spindle_angle=[0.0, math.inf, 1.0]), "spindle_angle"),
    (dict(spindle_angle=[0.0, 2.0, 1.0]), "spindle_angle"),
    (dict(spindle_angle=np.zeros((3, 2))), "spindle_angle"),
    (dict(feed_progress=[0.0, 0.0]), "feed_progress"),
    (dict(feed_progress=[0.0, math.nan, 0.0]), "feed_progress"),
])
def test_bad_signals_raise_invalid_signal_error(kwargs, name):
    args = dict(spindle_angle=[0.0, 1.0, 2.0], feed_per_tooth=C) | kwargs
    with pytest.raises(InvalidSignalError, match=name):
        milling_forces(GOOD_TOOL, K, GOOD_CUT, **args)


def test_bad_helper_signals():
    with pytest.raises(InvalidSignalError, match="spindle_speed"):
        feed_per_tooth(0.01, 0.0, 2)
    with pytest.raises(InvalidSignalError, match="feed_speed"):
        feed_per_tooth(-0.01, 100.0, 2)
    f = milling_forces(GOOD_TOOL, K, GOOD_CUT, [0.0, 1.0], C)
    with pytest.raises(InvalidSignalError, match="spindle_speed"):
        f.power(math.nan)
    with pytest.raises(InvalidSignalError, match="spindle_speed"):
        f.power([1.0, 2.0, 3.0])


# --- API documentation and speed ---------------------------------------------------------------

def test_public_api_documents_every_parameter():
    for name in milling.__all__:
        obj = getattr(milling, name)
        targets = [obj]
        if inspect.isclass(obj):
            targets += [m for m in vars(obj).values() if inspect.isfunction(m) and not m.__name__.startswith("_")]
            targets += [m.__func__ for m in vars(obj).values() if isinstance(m, classmethod)]
        for target in targets:
            doc = inspect.getdoc(target) or ""
            assert doc, f"{name}.{target.__name__} has no docstring"
            params = inspect.signature(target).parameters
            for p in params:
                if p not in ("self", "cls"):
                    assert p in doc, f"{name}: parameter '{p}' is undocumented"
