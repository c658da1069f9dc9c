"""The XML experiment format: lossless Recording <-> XML, the schema, versioning, foreign files, XSLT, CLI."""

from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from lxml import etree
from typer.testing import CliRunner

from drivesense.cli import app
from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.io.xml_format import (SCHEMA_PATH, Experiment, read_experiment, read_xml, transform_xml,
                                      validate_xml, write_xml)
from drivesense.recording import Recording
from drivesense.io import read_recording, write_recording

runner = CliRunner()
NS = "urn:drivesense:experiment:1"


def _rec(n: int = 257, seed: int = 0, **meta) -> Recording:
    rng = np.random.default_rng(seed)
    special = np.array([0.0, -0.0, 5e-324, -1.7976931348623157e308, np.nextafter(1.0, 2.0), 1 / 3])
    cur = rng.standard_normal(n)
    cur[: special.size] = special
    return Recording.from_arrays(
        {"x_current_ref": cur, "x_motor_angle": np.cumsum(rng.standard_normal(n)),
         "force_x": rng.standard_normal(n) * 50, "x_table_position": rng.uniform(0, 0.3, n),
         "temperature_probe": rng.standard_normal(n)},
        fs=10_000.0 / 3, t0=-0.125, meta={"name": "cut 1", **meta})


NASTY = {
    "machine": {"manufacturer": "Haas", "model": "VF-2", "spindle": {"max_rpm": 8100, "power_w": 22400.0}},
    "tool": {"diameter_m": 0.006, "flutes": 2, "coating": "TiAlN"},
    "material": "Al 6061-T6 — Ølstykke",
    "ints_and_floats": [1, 1.0, True, None, 2**70, -0.0, 1e-300],
    "empty": {}, "empty_list": [], "key with spaces & <angles>": "a \"quoted\" 'value' & <tag>",
    "control\u0001key": "bell\u0007 and CR\r\nLF and tab\t",
    "surrogate": "lone \ud800 half",
    "provenance": ["simulated", "trimmed"],
}


def _roundtrip(tmp_path: Path, recs, **kw) -> Experiment:
    path = tmp_path / "e.xml"
    write_xml(recs, path, **kw)
    return read_experiment(path)


def test_roundtrip_is_bit_exact_with_all_metadata(tmp_path):
    rec = _rec(start_state={"feed_rate": 0.1, "gcode_line": 40}, end_state={},
               personnel=[{"name": "Ana Lima", "role": "operator", "email": "ana@example.org"}], **NASTY)
    exp = _roundtrip(tmp_path, rec)
    back = exp.recordings[0]
    assert back.equals(rec)
    assert back.meta == rec.meta and "end_state" in back.meta and back.meta["end_state"] == {}
    assert type(back.meta["ints_and_floats"][1]) is float and back.meta["ints_and_floats"][2] is True
    assert exp.personnel == ({"name": "Ana Lima", "role": "operator", "email": "ana@example.org"},)
    raw = (tmp_path / "e.xml").read_text(encoding="utf-8")
    assert '<personnel><experimenter name="Ana Lima"' in raw and "inRecording" not in raw


@pytest.mark.parametrize("encoding", ["base64", "text"])
def test_text_and_base64_are_both_exact(tmp_path, encoding):
    rec = _rec(n=70_001)  # several dataGroups in text mode
    exp = _roundtrip(tmp_path, rec, encoding=encoding)
    assert exp.recordings[0].equals(rec)
    groups = (tmp_path / "e.xml").read_text().count("<dataGroup")
    assert groups == (5 if encoding == "base64" else 10)  # 2**18 samples a group in base64, 2**16 in text


def test_float32_is_smaller_close_and_says_so(tmp_path):
    with pytest.raises(ConfigError, match="x_current_ref.*float32 range"):  # holds -1.8e308
        write_xml(_rec(n=10), tmp_path / "f.xml", dtype="float32")
    rec = _rec(n=1000).select("force_x", "x_motor_angle")
    back = _roundtrip(tmp_path, rec, dtype="float32").recordings[0]
    assert np.allclose(back["force_x"], rec["force_x"], rtol=1e-6)
    assert not back.equals(rec)
    assert "stored as float32" in back.meta["provenance"][-1]


def test_absent_personnel_is_filled_in_but_not_read_back(tmp_path):
    rec = _rec()
    path = tmp_path / "e.xml"
    write_xml(rec, path, experimenter="Lab Robot")
    root = etree.parse(str(path)).getroot()
    people = root.find(f"{{{NS}}}personnel")
    assert people.get("inRecording") == "false" and people[0].get("name") == "Lab Robot"
    back = read_xml(path)
    assert back.equals(rec) and "personnel" not in back.meta


def test_non_canonical_personnel_stays_in_the_configuration(tmp_path):
    rec = _rec(personnel=["Ana", "Ben"])
    assert _roundtrip(tmp_path, rec).recordings[0].equals(rec)


def test_several_measurements_share_the_configuration(tmp_path):
    a = _rec(seed=1, machine="Haas VF-2", run=1, personnel=[{"name": "Ana"}], start_state={"feed_rate": 0.1})
    b = _rec(seed=2, machine="Haas VF-2", run=2, personnel=[{"name": "Ben"}]).with_meta(name="cut 2")
    exp = _roundtrip(tmp_path, [a, b], experiment_id="exp-42", created="2024-05-01T12:00:00Z")
    assert [r.equals(x) for r, x in zip(exp.recordings, (a, b))] == [True, True]
    assert exp.id == "exp-42" and exp.created == "2024-05-01T12:00:00Z"
    root = etree.parse(str(tmp_path / "e.xml")).getroot()
    common = root.find(f"{{{NS}}}configuration")
    assert 'key="machine"' in etree.tostring(common, encoding="unicode")
    assert 'key="run"' not in etree.tostring(common, encoding="unicode")
    assert len(root.findall(f"{{{NS}}}measurement")) == 2


def test_channel_order_and_sensor_grouping_survive(tmp_path):
    rec = _rec().select("force_x", "x_current_ref", "temperature_probe", "x_motor_angle")
    rec = rec.with_meta(sensors={"temperature_probe": ["thermo DAQ", "PT100 spindle"]})
    path = tmp_path / "e.xml"
    write_xml(rec, path)
    back = read_xml(path)
    assert back.channels == rec.channels and back.equals(rec)
    root = etree.parse(str(path)).getroot()
    sensors = [s.get("name") for s in root.iter(f"{{{NS}}}sensor")]
    assert sensors == ["dynamometer", "x servo drive", "PT100 spindle", "x motor encoder"]


def test_written_files_follow_the_schema_in_two_validators(tmp_path):
    xmlschema = pytest.importorskip("xmlschema")
    path = tmp_path / "e.xml"
    write_xml([_rec(**NASTY), _rec(seed=3)], path, encoding="text")
    etree.XMLSchema(etree.parse(str(SCHEMA_PATH))).assertValid(etree.parse(str(path)))
    xmlschema.XMLSchema10(str(SCHEMA_PATH)).validate(str(path))


FOREIGN = """<?xml version="1.0" encoding="UTF-8"?>
<experimentResults xmlns="urn:drivesense:experiment:1" xmlns:lab="https://lab.example/ext"
                   formatVersion="1.7" id="unh-2006-017" created="2006-07-14T10:30:00-04:00" lab:site="Durham">
  <personnel>
    <experimenter name="B. Student">ran the dynamometer</experimenter>
    <lab:supervisor>Prof. Jerard</lab:supervisor>
  </personnel>
  <configuration>
    <machine manufacturer="Fadal" model="VMC 15XT"/>
    <workpiece><material>Aluminium 6061</material></workpiece>
    <purpose>slot milling, tare power</purpose>
  </configuration>
  <measurement name="slot 3" lab:operatorNote="coolant off">
    <startState><feedRate units="mm/s">12.5</feedRate><gcodeLine>N40</gcodeLine></startState>
    <endState/>
    <interface name="NI PCI-6036E" type="A/D board">
      <sensor name="feed drive power sensor" type="Load Controls PH-3A">
        <channel name="x_table_position" units="mm" sampleRate="1000" startTime="0.5" samples="5">
          <dataGroup count="2" encoding="text">
              1.0
              2.0
          </dataGroup>
          <dataGroup count="3" dtype="float32" byteOrder="big">{b64}</dataGroup>
          <lab:calibration date="2006-07-01">linear</lab:calibration>
        </channel>
        <channel name="power" units="kW" sampleRate="1000.0" startTime="0.5" samples="5">
          <dataGroup count="5">{b64_64}</dataGroup>
        </channel>
      </sensor>
      <lab:cable length="2 m"/>
    </interface>
    <lab:note>The newer reader's extension: an older reader ignores it.</lab:note>
  </measurement>
  <lab:summary>three slots</lab:summary>
</experimentResults>
"""


def _foreign(tmp_path: Path) -> Path:
    b32 = base64.b64encode(np.array([3.0, 4.0, 5.5], ">f4").tobytes()).decode()
    b64 = base64.b64encode(np.array([0.5, 0.25, 1.0, 2.0, 4.0], "<f8").tobytes()).decode()
    path = tmp_path / "foreign.xml"
    path.write_text(FOREIGN.replace("{b64}", b32).replace("{b64_64}", b64), encoding="utf-8")
    return path


def test_newer_minor_version_with_extensions_validates_and_reads(tmp_path):
    path = _foreign(tmp_path)
    etree.XMLSchema(etree.parse(str(SCHEMA_PATH))).assertValid(etree.parse(str(path)))
    exp = read_experiment(path)
    rec = exp.recordings[0]
    assert exp.format_version == "1.7" and exp.id == "unh-2006-017"
    assert rec.fs == 1000.0 and rec.t0 == 0.5
    assert np.array_equal(rec["x_table_position"], [1e-3, 2e-3, 3e-3, 4e-3, 5.5e-3])
    assert np.array_equal(rec["power"], [500.0, 250.0, 1000.0, 2000.0, 4000.0]) and rec.units("power") == "W"
    assert rec.meta["machine"] == {"@manufacturer": "Fadal", "@model": "VMC 15XT"}
    assert rec.meta["workpiece"] == {"material": "Aluminium 6061"}
    assert rec.meta["start_state"]["feedRate"] == {"@units": "mm/s", "#text": 12.5}
    assert rec.meta["personnel"] == [{"name": "B. Student"}] and rec.name == "slot 3"
    assert rec.meta["sensors"]["power"] == ["NI PCI-6036E", "feed drive power sensor"]
    prov = rec.meta["provenance"][-1]
    assert "x_table_position mm->m" in prov and "power kW->W" in prov and "float32" in prov
    assert "three slots" in exp.texts and "coolant off" in exp.texts and "lab:calibration" not in exp.texts


def test_reexport_of_a_foreign_file_is_stable(tmp_path):
    rec = read_xml(_foreign(tmp_path))
    again = _roundtrip(tmp_path, rec).recordings[0]
    assert again.equals(rec)


def test_other_major_version_and_other_documents_are_refused(tmp_path):
    path = tmp_path / "v2.xml"
    path.write_text('<experimentResults xmlns="urn:drivesense:experiment:2" formatVersion="2.0"/>')
    with pytest.raises(InvalidSignalError, match=r"format version 2\.x; this reader reads 1\.x"):
        read_experiment(path)
    path.write_text('<html><body/></html>')
    with pytest.raises(InvalidSignalError, match="not a drivesense experiment file"):
        read_experiment(path)


def _edit(tmp_path: Path, old: str, new: str, count: int = -1) -> Path:
    path = tmp_path / "e.xml"
    write_xml(_rec(n=50), path)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, count))
    return path


@pytest.mark.parametrize("old, new, pattern", [
    ("personnel", "staff", r"line 3: does not follow the schema: Element 'staff': This element is not expected"),
    ('sampleRate="3333.', 'sampleRate="-3333.', r"line \d+: does not follow the schema: .*sampleRate"),
    ("<startState/>", "", r"line \d+: does not follow the schema: Element 'endState'"),
])
def test_schema_errors_name_line_and_element(tmp_path, old, new, pattern):
    path = _edit(tmp_path, old, new)
    with pytest.raises(InvalidSignalError, match=pattern):
        validate_xml(path)
    res = runner.invoke(app, ["xml", "validate", str(path)])
    assert res.exit_code == 2 and "error:" in res.output and "line" in res.output
    assert "Traceback" not in res.output


def test_channels_on_different_time_bases_are_refused(tmp_path):
    path = _edit(tmp_path, 'name="x_motor_angle" units="rad" sampleRate="3333.',
                 'name="x_motor_angle" units="rad" sampleRate="1111.', 1)
    with pytest.raises(InvalidSignalError, match=r"channel 'x_motor_angle'.*one time base"):
        read_experiment(path)


def test_nonfinite_samples_and_bad_units_name_the_channel(tmp_path):
    path = _edit(tmp_path, 'units="N"', 'units="furlong"', 1)
    with pytest.raises(Exception, match=r"line \d+, channel 'force_x'.*unknown unit 'furlong'"):
        read_experiment(path)
    rec = _rec(n=10)
    write_xml(rec, tmp_path / "t.xml", encoding="text")
    text = (tmp_path / "t.xml").read_text()
    first = re.search(r'encoding="text">(\S+)', text).group(1)
    (tmp_path / "t.xml").write_text(text.replace(f'encoding="text">{first}', 'encoding="text">nan', 1))
    with pytest.raises(InvalidSignalError, match=r"measurement 'cut 1'.*x_current_ref.*NaN"):
        read_experiment(tmp_path / "t.xml")


def test_read_xml_picks_a_measurement(tmp_path):
    path = tmp_path / "two.xml"
    write_xml([_rec(seed=1), _rec(seed=2).with_meta(name="cut 2")], path)
    with pytest.raises(ConfigError, match="2 measurements"):
        read_xml(path)
    assert read_xml(path, measurement="cut 2").name == "cut 2"
    assert read_xml(path, measurement=0).name == "cut 1"
    with pytest.raises(ConfigError, match="no measurement 'cut 9'"):
        read_xml(path, measurement="cut 9")


def test_shipped_xslt_flattens_to_csv(tmp_path):
    path = tmp_path / "two.xml"
    write_xml([_rec(seed=1), _rec(seed=2).with_meta(name="cut 2")], path, experiment_id="e1",
              experimenter='Dr. "Q"')
    rows = transform_xml(path).splitlines()
    assert rows[0].startswith("experiment_id,format_version,experimenters,measurement,interface,sensor,channel")
    assert len(rows) == 1 + 2 * 5
    assert rows[1].split(",")[:4] == ['"e1"', "1.0", '"Dr. ""Q"""', '"cut 1"']
    assert '"force_x","N",3333.3333333333335,-0.125,257,' in rows[3]
    assert rows[-1].endswith("base64 float64")


def test_custom_xslt_runs_but_cannot_read_files(tmp_path):
    path = tmp_path / "e.xml"
    write_xml(_rec(n=20), path)
    sheet = tmp_path / "names.xsl"
    sheet.write_text("""<xsl:stylesheet version="1.0" xmlns:xsl="http://www.w3.org/1999/XSL/Transform"
        xmlns:e="urn:drivesense:experiment:1"><xsl:output method="text"/>
        <xsl:template match="/"><xsl:for-each select="//e:channel"><xsl:value-of select="@name"/>;</xsl:for-each>
        </xsl:template></xsl:stylesheet>""")
    assert transform_xml(path, sheet) == "x_current_ref;x_motor_angle;force_x;x_table_position;temperature_probe;"
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET")
    evil = tmp_path / "evil.xsl"
    evil.write_text(f"""<xsl:stylesheet version="1.0" xmlns:xsl="http://www.w3.org/1999/XSL/Transform">
        <xsl:output method="text"/><xsl:template match="/">
        <xsl:value-of select="document('{secret.as_uri()}')"/></xsl:template></xsl:stylesheet>""")
    with pytest.raises(ConfigError, match="XSLT failed") as err:
        transform_xml(path, evil)
    assert "TOP-SECRET" not in str(err.value)


def test_cli_export_validate_transform_import(tmp_path):
    a, b = _rec(seed=1, machine="Haas"), _rec(seed=2, machine="Haas").with_meta(name="cut 2")
    write_recording(a, tmp_path / "a.nc")
    write_recording(b, tmp_path / "b.nc")
    xml = tmp_path / "exp.xml"
    res = runner.invoke(app, ["xml", "export", str(tmp_path / "a.nc"), str(tmp_path / "b.nc"), "--out", str(xml)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["xml", "validate", str(xml), "--json", str(tmp_path / "v.json")])
    assert res.exit_code == 0 and "valid:" in res.output and "2 measurement(s)" in res.output
    assert json.loads((tmp_path / "v.json").read_text())["measurements"][1]["name"] == "cut 2"
    res = runner.invoke(app, ["xml", "transform", str(xml), "--out", str(tmp_path / "s.csv")])
    assert res.exit_code == 0 and (tmp_path / "s.csv").read_text().count("\n") == 11
    res = runner.invoke(app, ["xml", "import", str(xml), "--out", str(tmp_path / "b2.nc"), "--measurement", "1"])
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "b2.nc").equals(b)
    res = runner.invoke(app, ["xml", "import", str(xml), "--out", str(tmp_path / "x.nc")])
    assert res.exit_code == 2 and "choose one" in res.output
    res = runner.invoke(app, ["xml", "export", str(tmp_path / "a.nc"), "--out", str(xml), "--encoding", "hex"])
    assert res.exit_code == 2 and "encoding must be" in res.output


def test_import_streams_with_memory_under_twice_the_samples(tmp_path):
    """Peak memory of reading a 48 MB-of-samples file stays under 2x the samples (measured in a child)."""
    n, chans = 1_000_000, 6
    rec = Recording.from_arrays({f"c{i}": np.random.default_rng(i).standard_normal(n) for i in range(chans)}, fs=1e4)
    path = tmp_path / "big.xml"
    write_xml(rec, path)
    write_xml(_rec(n=10), tmp_path / "small.xml")
    code = textwrap.dedent(f"""
        import json, re, threading, psutil
        from pathlib import Path
        from drivesense.io.xml_format import read_experiment
        read_experiment({str(tmp_path / 'small.xml')!r})   # imports and compiled kernels
        status = lambda key: int(re.search(key + r":\\s+(\\d+) kB", Path("/proc/self/status").read_text())[1]) * 1024
        before = psutil.Process().memory_info().rss
        try:
            Path("/proc/self/clear_refs").write_text("5")  # reset the peak (VmHWM) to the current RSS
            exp = read_experiment({str(path)!r})
            peak = status("VmHWM")
        except OSError:                                    # no clear_refs here: poll the RSS instead
            samples, done = [before], threading.Event()
            def poll():
                while not done.is_set():
                    samples.append(psutil.Process().memory_info().rss)
                    done.wait(0.002)
            t = threading.Thread(target=poll)
            t.start()
            exp = read_experiment({str(path)!r})
            done.set()
            t.join()
            peak = max(samples)
        print(json.dumps({{"before": before, "peak": peak}}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    mem = json.loads(out.strip().splitlines()[-1])
    data = n * chans * 8
    assert mem["peak"] - mem["before"] < 2 * data, f"peak grew {(mem['peak'] - mem['before']) / data:.2f}x the samples"


def test_simulated_idle_runs_export_as_measurements_of_distinct_names(tmp_path):
    """Idle runs named alike (same name whatever the seed) became measurements of one name; now each is unique."""
    from dataclasses import replace

    from drivesense.sim.scenarios import ScenarioSettings, condition_by_name, simulate_idle

    cond = condition_by_name("feed_r6_S1000")[0]
    short = replace(ScenarioSettings(), duration=0.2, t_contact=0.1)
    runs = [*simulate_idle(cond, short, repeats=2, seed=5), simulate_idle(cond, short, repeats=1, seed=9)[0]]
    names = [r.name for r in runs]
    assert len(set(names)) == 3 and all("seed" in n for n in names), names
    for k, rec in enumerate(runs):
        write_recording(rec, tmp_path / f"idle{k}.nc")
    xml = tmp_path / "idle.xml"
    res = runner.invoke(app, ["xml", "export", *(str(tmp_path / f"idle{k}.nc") for k in range(3)), "--out", str(xml)])
    assert res.exit_code == 0, res.output
    assert [m["name"] for m in validate_xml(xml)["measurements"]] == names
    res = runner.invoke(app, ["xml", "import", str(xml), "--measurement", names[2], "--out", str(tmp_path / "b.nc")])
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "b.nc").equals(runs[2])


def test_writer_makes_repeated_measurement_names_unique(tmp_path):
    path = tmp_path / "dup.xml"
    write_xml([_rec(seed=1), _rec(seed=2), _rec(seed=3).with_meta(name="cut 1 (2)")], path)
    back = read_experiment(path).recordings
    assert [r.name for r in back] == ["cut 1", "cut 1 (3)", "cut 1 (2)"]
    assert "renamed 'cut 1' to 'cut 1 (3)'" in back[1].meta["provenance"][-1]
    assert read_xml(path, measurement="cut 1").equals(_rec(seed=1))


def test_ambiguous_measurement_name_is_an_error_listing_the_choices(tmp_path):
    """A file from another tool may repeat a name: --measurement NAME must not silently take the first."""
    path = tmp_path / "foreign.xml"
    write_xml([_rec(seed=1).with_meta(name="run"), _rec(seed=2).with_meta(name="other"),
               _rec(seed=3).with_meta(name="run B")], path)
    path.write_text(path.read_text().replace("run B", "run"))
    with pytest.raises(ConfigError, match="2 measurements are named 'run' .indices 0, 2.; choose one"):
        read_xml(path, measurement="run")
    res = runner.invoke(app, ["xml", "import", str(path), "--measurement", "run", "--out", str(tmp_path / "r.nc")])
    assert res.exit_code == 2 and "0 'run', 1 'other', 2 'run'" in res.output, res.output
    assert not (tmp_path / "r.nc").exists()
