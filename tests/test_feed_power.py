"""Feed-drive power to average x-force (Sec. 6) on the paper's real Tables 2-3, exact synthetic data and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, CoverageError, IdentificationError, MissingChannelError, UnitError
from drivesense.identify.feed_power import (FeedCuts, FeedPowerModel, cross_validate, fit_feed_power, per_speed_fits,
                                            read_feed_cuts)

DATA = Path(__file__).parent / "data"
TABLE3 = DATA / "feed_power_table3.csv"
IN_MIN, LBF, HP = 0.0254 / 60, 4.4482216152605, 745.69987158227022
runner = CliRunner()


@pytest.fixture(scope="module")
def paper() -> FeedCuts:
    return read_feed_cuts(TABLE3)


def test_table3_is_read_in_si(paper):
    assert len(paper) == 14 and paper.labels[0] == "1" and paper.labels[-1] == "14"
    assert paper.slide_speed[0] == pytest.approx(30 * IN_MIN) and paper.slide_speed[-1] == pytest.approx(60 * IN_MIN)
    assert paper.force_x[10] == pytest.approx(-133 * LBF)
    assert paper.total_power[10] == pytest.approx(0.038 * 0.01875 * HP)        # volts x 0.01875 HP/V
    assert paper.power()[2] == pytest.approx(0.007 * 0.01875 * HP)             # the paper's own difference column


def _rows(path):
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    head = lines[0].split(",")
    return {h: [r.split(",")[k] for r in lines[1:]] for k, h in enumerate(head)}


def test_tables_2_and_3_describe_the_same_cuts():
    t2, t3 = _rows(DATA / "feed_power_table2.csv"), _rows(TABLE3)
    assert t2["cut"] == t3["cut"] == [str(k) for k in range(1, 15)]
    assert t2["slide_speed [in/min]"] == t3["slide_speed [in/min]"]
    assert set(t2["spindle_speed [rpm]"]) == {"2122", "2653", "3183"}
    # the [hp] columns are exactly the printed volts x 0.01875 HP/V
    for a, b in (("total_power [hp]", "total_sensor [V]"), ("cutting_power [hp]", "cutting_sensor [V]")):
        np.testing.assert_allclose(np.array(t3[a], float), np.array(t3[b], float) * 0.01875, rtol=1e-12)


def test_paper_per_speed_lines_are_straight(paper):
    fits = per_speed_fits(paper)
    assert [round(f.speed / IN_MIN) for f in fits] == [30, 40, 50, 60]
    assert [f.cuts for f in fits] == [4, 3, 4, 3]
    assert min(f.r2 for f in fits) >= 0.98                                       # Fig. 14
    assert all(f.slope < 0 for f in fits)                                        # force opposes the feed
    # from the rounded total and tare readings (3 decimals of a volt) the 30 in/min line is visibly worse
    diff = FeedCuts(paper.slide_speed, paper.total_power, paper.tare_power, None, paper.force_x)
    r2 = [f.r2 for f in per_speed_fits(diff)]
    assert 0.95 < r2[0] < 0.98 and min(r2[1:]) > 0.99


def test_paper_cross_validation(paper):
    cv = cross_validate(paper)
    assert cv["loco_mean_error"] <= 0.06
    loso = {round(x["speed_m_s"] / IN_MIN): x["mean_error"] for x in cv["loso"]}
    assert set(loso) == {40, 50} and max(loso.values()) <= 0.10
    model = fit_feed_power(paper)
    eta = model.efficiency([30 * IN_MIN, 60 * IN_MIN])
    assert np.all(eta > 1)                 # not a motor efficiency: the printed sensitivity is not watts per volt
    assert model.predict(paper) == pytest.approx(paper.force_x, rel=0.08)


def test_exact_recovery_on_synthetic_data():
    v = np.repeat([0.01, 0.015, 0.02, 0.025], 3)
    p = np.tile([0.5, 1.0, 1.5], 4)
    a0, a1, f0 = -0.6, -8.0, -12.0
    cuts = FeedCuts(v, p + 3.0, np.full(12, 3.0), force_x=(a0 + a1 * v) * p / v + f0)
    m = fit_feed_power(cuts)
    assert (m.a0, m.a1, m.f0) == pytest.approx((a0, a1, f0), rel=1e-9)
    assert m.efficiency(0.02) == pytest.approx(abs(a0 + a1 * 0.02))
    assert m.rms_error == pytest.approx(0.0, abs=1e-9)
    mid = FeedCuts([0.0175], [4.0], [3.0])
    assert m.predict(mid)[0] == pytest.approx((a0 + a1 * 0.0175) / 0.0175 + f0)
    no_tare = FeedCuts([0.02], total_power=[4.0])                                 # tare from the model's table
    assert m.predict(no_tare)[0] == pytest.approx((a0 + a1 * 0.02) / 0.02 + f0)


def test_refuses_outside_the_calibrated_range(paper):
    model = fit_feed_power(paper)
    with pytest.raises(CoverageError, match="cut x.*outside the calibrated range 762-1524 mm/min"):
        model.predict(FeedCuts([70 * IN_MIN], [0.3], [0.2], labels=["x"]))
    with_pos = FeedCuts(paper.slide_speed, paper.total_power, paper.tare_power, paper.cutting_power, paper.force_x,
                        slide_position=np.linspace(0, 0.1, 14))
    model = fit_feed_power(with_pos)
    with pytest.raises(CoverageError, match="slide position 150 mm"):
        model.predict(FeedCuts([40 * IN_MIN], [0.3], [0.2], slide_position=[0.15]))


def test_units_in_and_si_agree(tmp_path):
    si = tmp_path / "si.csv"
    si.write_text("slide_speed [mm/min],total_power [W],tare_power [W],force_x [N]\n"
                  + "".join(f"{float(v) * 6e4!r},{float(t)!r},{float(r)!r},{float(f)!r}\n" for v, t, r, f in
                            zip(read_feed_cuts(TABLE3).slide_speed, read_feed_cuts(TABLE3).total_power,
                                read_feed_cuts(TABLE3).tare_power, read_feed_cuts(TABLE3).force_x)))
    a = read_feed_cuts(si)
    b = read_feed_cuts(TABLE3)
    np.testing.assert_allclose(a.slide_speed, b.slide_speed, rtol=1e-12)
    np.testing.assert_allclose(a.force_x, b.force_x, rtol=1e-12)


@pytest.mark.parametrize("text, error, match", [
    ("slide_speed [in/min],total_power [W],tare_power [W],force_x [N]\n-30,1,0.5,-10\n", ConfigError,
     "slide_speed.*>= 0"),
    ("slide_speed [in/min],total_power [W],tare_power [W],force_x [N]\n0,1,0.5,-10\n", ConfigError, "stands still"),
    ("slide_speed [N],total_power [W],tare_power [W]\n30,1,0.5\n", UnitError, "slide_speed"),
    ("total_power [W],tare_power [W]\n1,0.5\n", ConfigError, "slide_speed"),
    ("slide_speed [in/min],total_power [W],tare_power [W],force_x [N]\n", Exception, "no data rows"),
])
def test_bad_cut_files(tmp_path, text, error, match):
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(error, match=match):
        read_feed_cuts(path)


def test_fit_needs_force_and_two_speeds(paper):
    with pytest.raises(MissingChannelError, match="force_x"):
        fit_feed_power(FeedCuts(paper.slide_speed, paper.total_power, paper.tare_power))
    with pytest.raises(IdentificationError, match="2 or more slide speeds"):
        fit_feed_power(paper.subset(paper.slide_speed < 35 * IN_MIN))


def test_model_file_roundtrip(tmp_path, paper):
    model = fit_feed_power(paper)
    loaded = FeedPowerModel.load(model.save(tmp_path / "m.json"))
    assert loaded == model
    (tmp_path / "bad.json").write_text('{"a0": 1}')
    with pytest.raises(ConfigError, match="feed-power model"):
        FeedPowerModel.load(tmp_path / "bad.json")


def test_cli_fit_and_predict(tmp_path):
    model = tmp_path / "model.json"
    res = runner.invoke(app, ["feedpower", "fit", str(TABLE3), "--model", str(model), "--json",
                              str(tmp_path / "fit.json"), "--plot", str(tmp_path / "fig14.png")])
    assert res.exit_code == 0, res.output
    info = json.loads((tmp_path / "fit.json").read_text())
    assert info["cross_validation"]["loco_mean_error"] <= 0.06 and (tmp_path / "fig14.png").exists()
    new = tmp_path / "new.csv"
    new.write_text("cut,slide_speed [in/min],total_power [hp],tare_power [hp]\nA,45,0.0005,0.00025\n")
    res = runner.invoke(app, ["feedpower", "predict", str(new), "--model", str(model), "--out",
                              str(tmp_path / "pred.csv"), "--force-unit", "lbf"])
    assert res.exit_code == 0, res.output
    lines = (tmp_path / "pred.csv").read_text().splitlines()
    assert lines[0] == "cut,slide_speed [mm/min],cutting_power [W],force_x_predicted [lbf],flag"
    assert -150 < float(lines[1].split(",")[3]) < -50
    far = tmp_path / "far.csv"
    far.write_text("slide_speed [in/min],total_power [hp],tare_power [hp]\n80,0.0005,0.00025\n")
    res = runner.invoke(app, ["feedpower", "predict", str(far), "--model", str(model), "--out",
                              str(tmp_path / "p.csv")])
    assert res.exit_code == 2 and "outside the calibrated range" in res.output
    res = runner.invoke(app, ["feedpower", "predict", str(new), "--model", str(model), "--out",
                              str(tmp_path / "p.csv"), "--force-unit", "kg"])
    assert res.exit_code == 2 and "force-unit" in res.output


def test_cli_predict_flags_out_of_range_rows_and_predicts_the_others(tmp_path):
    """One cut outside the calibrated speeds does not refuse the file: it is flagged, the others predicted."""
    import pandas as pd

    model = tmp_path / "model.json"
    assert runner.invoke(app, ["feedpower", "fit", str(TABLE3), "--model", str(model)]).exit_code == 0
    cuts = tmp_path / "mixed.csv"
    cuts.write_text("cut,slide_speed [in/min],total_power [hp],tare_power [hp]\n"
                    "A,45,0.0005,0.00025\nB,80,0.0005,0.00025\nC,50,0.0006,0.00025\n")
    out = tmp_path / "pred.csv"
    res = runner.invoke(app, ["feedpower", "predict", str(cuts), "--model", str(model), "--out", str(out),
                              "--json", str(tmp_path / "p.json")])
    assert res.exit_code == 0, res.output
    assert "warning:" in res.output and "cut B" in res.output and "outside the calibrated range" in res.output
    table = pd.read_csv(out)
    assert list(table["flag"]) == ["ok", "out_of_range", "ok"]
    force = table["force_x_predicted [N]"]
    assert np.isfinite(force[0]) and np.isnan(force[1]) and np.isfinite(force[2])
    info = json.loads((tmp_path / "p.json").read_text())
    assert info["predicted_n"][1] is None and info["out_of_range"][0]["cut"] == "B"
    assert model_predicts_nan_only_where_flagged(FeedPowerModel.load(model), read_feed_cuts(cuts))


def model_predicts_nan_only_where_flagged(model, cuts) -> bool:
    flags = model.coverage_flags(cuts)
    force = model.predict(cuts, skip_out_of_range=True)
    return [bool(f) for f in flags] == list(np.isnan(force))


def test_a_known_column_without_a_unit_is_refused(tmp_path):
    """slide_speed without [unit] would be read as m/s where a user meant mm/min: refuse, naming the column."""
    path = tmp_path / "cuts.csv"
    path.write_text("slide_speed,total_power [W],tare_power [W],force_x [N]\n500,900,300,120\n", encoding="utf-8")
    with pytest.raises(UnitError, match="column 'slide_speed' has no unit.*'slide_speed \\[m/s\\]'"):
        read_feed_cuts(path)
