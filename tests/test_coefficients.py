"""K_tc / K_te calibration from spindle power: exact recovery, the see-saw warning, tables, units, the CLI."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, IdentificationError, InvalidSignalError, UnitError
from drivesense.identify.coefficients import (CutTable, SeeSawWarning, average_power, calibrate_from_power, fit_cut_table,
                                              fit_tangential_coefficients, read_cut_table)
from drivesense.machine.cutting_power import CutConditions, cutting_power
from drivesense.recording import Recording

D, A, RPM = 12.7e-3, 2.54e-3, 1068.0
OMEGA = RPM * 2 * math.pi / 60
KTC, KTE = 2100e6, 35e3
FEEDS = (19e-6, 28e-6, 33e-6, 40e-6)
ANGLES = (0, 60, 90, 120)
runner = CliRunner()


def design(feeds=FEEDS, angles=ANGLES):
    return [CutConditions(D, 1, A, OMEGA, f, math.radians(a), math.pi) for a in angles for f in feeds]


def test_exact_recovery_on_exact_synthetic_data():
    cuts = design()
    fit = calibrate_from_power(cuts, cutting_power(KTC, KTE, cuts))
    assert fit.Ktc == pytest.approx(KTC, rel=1e-10)
    assert fit.Kte == pytest.approx(KTE, rel=1e-10)
    assert fit.Ktc_se == pytest.approx(0.0, abs=1e-6 * KTC) and fit.r2 == pytest.approx(1.0)
    assert not fit.see_saw and fit.warnings == ()
    assert fit.predict_power(cuts[3]) == pytest.approx(cutting_power(KTC, KTE, cuts[3]))


def test_correlation_is_the_design_closed_form_and_standard_errors_cover_the_noise():
    rng = np.random.default_rng(1)
    h = np.array([c.average_chip_thickness for c in design()])
    errs = []
    for _ in range(300):
        y = KTC * h + KTE + rng.normal(0, 1e3, h.size)
        fit = fit_tangential_coefficients(h, y, warn=False)
        errs.append(((fit.Ktc - KTC) / fit.Ktc_se, (fit.Kte - KTE) / fit.Kte_se))
    assert fit.correlation == pytest.approx(-h.mean() / math.sqrt(np.mean(h ** 2)), rel=1e-9)
    z = np.array(errs)
    assert 0.8 < z[:, 0].std() < 1.25 and 0.8 < z[:, 1].std() < 1.25      # SEs are honest
    assert np.corrcoef(z.T)[0, 1] < -0.9                                   # the see-saw, seen in the errors


def test_see_saw_warning_when_cuts_span_little_h_avg():
    cuts = design(feeds=(50e-6, 52e-6, 54e-6), angles=(0,))
    rng = np.random.default_rng(0)
    p = cutting_power(KTC, KTE, cuts) * (1 + rng.normal(0, 0.01, len(cuts)))
    with pytest.warns(SeeSawWarning) as caught:
        fit = calibrate_from_power(cuts, p)
    assert any("see-saw" in str(w.message) for w in caught)
    assert fit.see_saw and fit.correlation < -0.99
    assert any("see-saw" in w for w in fit.warnings)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SeeSawWarning)
        calibrate_from_power(cuts, p, warn=False)                      # silenced on request
        calibrate_from_power(design(), cutting_power(KTC, KTE, design()))  # a wide span does not warn


def test_simulated_noisy_calibration_recovers_within_5_percent():
    from drivesense.sim.tool_life import section4_calibration, simulate_calibration

    table, (ktc, kte) = simulate_calibration(section4_calibration(), seed=3, repeats=10, runout=0.0)
    fit = fit_cut_table(table, warn=False)
    assert abs(fit.Ktc / ktc - 1) < 0.05 and abs(fit.Kte / kte - 1) < 0.05


@pytest.mark.parametrize("h, y, match", [
    ([], [], "no calibration cuts"),
    ([2e-5], [80e3], "two or more chip thicknesses"),
    ([2e-5, 2e-5, 2e-5], [80e3, 81e3, 79e3], "all have h_avg"),
])
def test_unidentifiable_calibrations(h, y, match):
    with pytest.raises(IdentificationError, match=match):
        fit_tangential_coefficients(h, y)


def test_bad_fit_input():
    with pytest.raises(InvalidSignalError, match="h_avg"):
        fit_tangential_coefficients([1e-5, -1e-5, 2e-5], [1, 2, 3])
    with pytest.raises(InvalidSignalError, match="force_per_depth"):
        fit_tangential_coefficients([1e-5, 2e-5], [1.0, math.nan])
    with pytest.raises(IdentificationError):
        calibrate_from_power([], [])


# ----------------------------------------------------------------------------- tables and units
HEADER = "diameter [in],flutes,axial_depth [in],spindle_speed [rpm],feed_speed [in/min],entry_angle [deg]," \
         "exit_angle [deg],spindle_power [hp],air_power [W]\n"


def write_table(path, cuts, power_w, air_w=300.0):
    rows = [HEADER]
    for c, p in zip(cuts, power_w):
        rows.append(f"{c.diameter / 0.0254!r},{c.flutes},{c.axial_depth / 0.0254!r},{RPM!r},"
                    f"{float(c.feed_speed) * 60 / 0.0254!r},{math.degrees(c.entry_angle)!r},180,"
                    f"{float(p + air_w) / 745.69987158227022!r},{air_w!r}\n")
    path.write_text("# calibration cuts in shop units\n" + "".join(rows), encoding="utf-8")
    return path


def test_read_cut_table_converts_units_and_recovers_the_coefficients(tmp_path):
    cuts = design()
    table = read_cut_table(write_table(tmp_path / "cuts.csv", cuts, cutting_power(KTC, KTE, cuts)))
    assert len(table) == 16 and table.calibration is None
    assert table.cuts[5].feed_per_tooth == pytest.approx(cuts[5].feed_per_tooth, rel=1e-12)
    fit = fit_cut_table(table)
    assert fit.Ktc == pytest.approx(KTC, rel=1e-9) and fit.Kte == pytest.approx(KTE, rel=1e-9)


def test_read_cut_table_radial_depth_and_options(tmp_path):
    path = tmp_path / "ae.csv"
    path.write_text("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n"
                    "2.54,1068,0.04,12.7,50\n2.54,1068,0.02,6.35,20\n", encoding="utf-8")
    t = read_cut_table(path, diameter=12.7e-3, flutes=2, mode="up")
    assert t.cuts[1].mode == "up" and t.cuts[1].exit_angle == pytest.approx(math.pi / 2)
    assert t.cuts[0].flutes == 2
    with pytest.raises(ConfigError, match="diameter"):
        read_cut_table(path)


@pytest.mark.parametrize("text, error, match", [
    ("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n"
     "2.54,1068,-0.04,12.7,50\n", ConfigError, "row 1.*feed_per_tooth"),
    ("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n"
     "2.54,1068,0.04,13.0,50\n", ConfigError, "row 1.*radial_depth.*exceeds the tool diameter"),
    ("axial_depth [N],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n"
     "2.54,1068,0.04,12.7,50\n", UnitError, "axial_depth"),
    ("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n",
     InvalidSignalError, "no data rows"),
    ("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],spindle_power [W]\n"
     "2.54,1068,0.04,12.7,50\n", ConfigError, "air_power"),
    ("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n"
     "2.54,1068,abc,12.7,50\n", InvalidSignalError, "line 2.*abc"),
])
def test_bad_tables(tmp_path, text, error, match):
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(error, match=match):
        read_cut_table(path, diameter=12.7e-3, flutes=1)


def test_empty_cut_table():
    with pytest.raises(InvalidSignalError, match="no cuts"):
        CutTable((), [])


def test_average_power_over_a_window():
    rec = Recording.from_arrays({"spindle_power": np.r_[np.full(100, 300.0), np.full(100, 350.0)]}, fs=100.0)
    assert average_power(rec, 1.2, 2.0) - average_power(rec, 0.1, 0.9) == pytest.approx(50.0)
    with pytest.raises(ConfigError, match="no sample"):
        average_power(rec, 5.0, 6.0)


# ----------------------------------------------------------------------------- CLI
def test_cli_calibrate_json_and_plot(tmp_path):
    cuts = design()
    path = write_table(tmp_path / "cuts.csv", cuts, cutting_power(KTC, KTE, cuts))
    res = runner.invoke(app, ["wear", "calibrate", str(path), "--json", str(tmp_path / "fit.json"),
                              "--plot", str(tmp_path / "fit.png")])
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "fit.json").read_text())
    assert info["Ktc_n_mm2"] == pytest.approx(2100.0, rel=1e-9) and info["Kte_n_mm"] == pytest.approx(35.0)
    assert (tmp_path / "fit.png").stat().st_size > 10_000


def test_cli_calibrate_bad_input_exits_2(tmp_path):
    path = tmp_path / "neg.csv"
    path.write_text("axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],radial_depth [mm],cutting_power [W]\n"
                    "2.54,1068,-0.04,12.7,50\n", encoding="utf-8")
    res = runner.invoke(app, ["wear", "calibrate", str(path), "--diameter", "12.7", "--flutes", "1"])
    assert res.exit_code == 2 and "feed_per_tooth" in res.output and "Traceback" not in res.output
    res = runner.invoke(app, ["wear", "calibrate", str(tmp_path / "missing.csv")])
    assert res.exit_code == 2


def test_runout_free_bases_are_eq_2_and_measured_runout_removes_the_bias():
    """Without runout the mechanistic bases are Q and A_c; with runout, giving it to the fit removes the K_te bias."""
    from drivesense.machine.tool_runout import ToolRunout, power_bases
    from drivesense.machine.milling import CuttingCoefficients, milling_forces
    from drivesense.sim.tool_life import section4_calibration

    cuts = section4_calibration().calibration_cuts()       # 4 flutes, 0.04-0.10 mm/tooth, 7-100 % immersion
    b_c, b_e = power_bases(cuts, ToolRunout(0.0))
    np.testing.assert_allclose(b_c, [c.material_removal_rate for c in cuts], rtol=2e-3)
    np.testing.assert_allclose(b_e, [c.contact_area_rate for c in cuts], rtol=2e-3)
    # noise-free power of a 4-flute tool with 6 um runout, from the force model itself
    runout = ToolRunout(6e-6, 0.4)
    angle = np.linspace(0, 2 * math.pi, 720, endpoint=False)
    power = []
    for c in cuts:
        f = milling_forces(c.end_mill(30.0, runout.offset, runout.phase), CuttingCoefficients(KTC, 0, 0, KTE, 0, 0),
                           c.milling_cut(16), angle, c.feed_per_tooth)
        power.append(float(np.mean(f.torque)) * c.spindle_speed)
    plain = calibrate_from_power(cuts, power, warn=False)
    aware = calibrate_from_power(cuts, power, warn=False, runout=runout)
    assert abs(plain.Kte / KTE - 1) > 0.02                                 # Eq. 2 reads lost contact as less K_te
    assert aware.Ktc == pytest.approx(KTC, rel=1e-6) and aware.Kte == pytest.approx(KTE, rel=1e-6)
    with pytest.raises(ConfigError, match="offset"):
        ToolRunout(-1e-6)


def test_cli_calibrate_with_a_measured_runout(tmp_path):
    from drivesense.sim.tool_life import section4_calibration, simulate_calibration

    table, (ktc, kte), measured = simulate_calibration(section4_calibration(), seed=8, repeats=10,
                                                       measured_runout=0.5e-6)
    path = tmp_path / "cuts.csv"
    rows = ["diameter [mm],flutes,axial_depth [mm],spindle_speed [rpm],feed_per_tooth [mm],entry_angle [deg],"
            "exit_angle [deg],cutting_power [W]"]
    for c, p in zip(table.cuts, table.cutting_power):
        rows.append(f"{c.diameter * 1e3},{c.flutes},{c.axial_depth * 1e3},{c.spindle_speed * 30 / math.pi},"
                    f"{c.feed_per_tooth * 1e3},{math.degrees(c.entry_angle)},{math.degrees(c.exit_angle)},{p}")
    path.write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(app, ["wear", "calibrate", str(path), "--json", str(tmp_path / "f.json"),
                                   "--runout-um", str(measured.offset * 1e6),
                                   "--runout-phase-deg", str(math.degrees(measured.phase))])
    assert res.exit_code == 0, res.output
    fit = json.loads((tmp_path / "f.json").read_text())
    assert abs(fit["Kte_n_m"] / kte - 1) < 0.04 and abs(fit["Ktc_n_m2"] / ktc - 1) < 0.02, fit
