"""The experiment archive, one suite for both backends (SQLite, PostgreSQL).

PostgreSQL runs when ``DRIVESENSE_TEST_PG_DSN`` names a server (``scripts/test`` starts one);
under ``CI=true`` a missing DSN fails instead of skipping.  Atomicity is tested by killing a
writer process in the middle of an import, and concurrency with 8 writer processes.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import select
import signal
import sqlite3
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import drivesense.archive.sqlite as sqlite_backend
from drivesense.archive import SqliteStore, default_archive_path, open_archive, parse_query, tokenize
from drivesense.archive.postgres import is_postgres_dsn
from drivesense.cli import app
from drivesense.errors import ConfigError, DriveSenseError, InvalidSignalError, MissingChannelError
from drivesense.io.xml_format import Experiment, read_experiment, read_xml, write_xml
from drivesense.recording import Recording
from drivesense.io import read_recording, write_recording

runner = CliRunner()
_FORK = multiprocessing.get_context("fork")


def _rec(seed: int = 0, n: int = 3000, **meta) -> Recording:
    rng = np.random.default_rng(seed)
    return Recording.from_arrays({"x_current_ref": rng.standard_normal(n), "x_table_position": rng.uniform(0, .2, n),
                                  "force_x": rng.standard_normal(n) * 30}, fs=10_000.0, t0=0.25,
                                 meta={"name": f"cut {seed}", **meta})


@pytest.fixture(params=["sqlite", "postgres"])
def where(request, tmp_path):
    """(location, keyword arguments) of an empty archive of each backend."""
    if request.param == "sqlite":
        yield str(tmp_path / "lab.sqlite"), {}
        return
    dsn = os.environ.get("DRIVESENSE_TEST_PG_DSN")
    if not dsn:
        if os.environ.get("CI") == "true":
            pytest.fail("CI=true but DRIVESENSE_TEST_PG_DSN is not set: the PostgreSQL tests must run in CI "
                        "(scripts/test installs and starts the server)")
        pytest.skip("no PostgreSQL server: set DRIVESENSE_TEST_PG_DSN (scripts/test does) to run these")
    schema = f"t_{uuid.uuid4().hex[:12]}"
    yield dsn, {"schema": schema}
    import psycopg

    with psycopg.connect(dsn, autocommit=True) as conn:
        conn.execute(f"DROP SCHEMA IF EXISTS {schema} CASCADE")


@pytest.fixture
def store(where):
    location, kw = where
    with open_archive(location, **kw) as st:
        yield st


def _rows(store) -> dict[str, int]:
    tables = ("experiments", "measurements", "channels", "samples", "states")
    return {t: store._conn.execute(f"SELECT count(*) FROM {t}").fetchone()[0] for t in tables}


# ------------------------------------------------------------------ basics
def test_add_show_load_export_remove_roundtrip(store, tmp_path):
    rec = _rec(machine="Haas VF-2", start_state={"feed_rate": 0.1})
    eid = store.add(rec)
    assert store.count() == 1 and store.resolve(eid[:6]) == eid
    exp = store.load(eid)
    assert isinstance(exp, Experiment) and exp.recordings[0].equals(rec)
    info = store.show(eid)
    assert info["machine"] == "Haas VF-2" and info["measurements"][0]["samples"] == 3000
    assert [c["name"] for c in info["measurements"][0]["channels"]] == rec.channels
    assert info["measurements"][0]["meta"] == rec.meta
    out = store.export(eid, tmp_path / "back.xml")
    back = read_experiment(out)
    assert back.id == eid and back.recordings[0].equals(rec)
    store.export(eid, tmp_path / "back.nc")
    assert read_recording(tmp_path / "back.nc").equals(rec)
    store.remove(eid)
    assert store.count() == 0 and set(_rows(store).values()) == {0}


def test_xml_file_keeps_its_id_and_several_measurements(store, tmp_path):
    a, b = _rec(1, machine="Fadal"), _rec(2, machine="Fadal", run=2)
    path = tmp_path / "two.xml"
    write_xml([a, b], path, experiment_id="unh-2006-017", created="2006-07-14T10:30:00-04:00")
    assert store.add(path) == "unh-2006-017"
    exp = store.load("unh-2006-017")
    assert [r.equals(x) for r, x in zip(exp.recordings, (a, b))] == [True, True]
    assert exp.created == "2006-07-14T14:30:00.000000Z"  # stored in UTC
    with pytest.raises(ConfigError, match="already in the archive"):
        store.add(path)
    with pytest.raises(ConfigError, match="2 measurements: choose one"):
        store.export("unh", tmp_path / "x.nc")


def test_unknown_and_ambiguous_ids(store):
    store.add(Experiment.from_recordings(_rec(1), id="abc-1"))
    store.add(Experiment.from_recordings(_rec(2), id="abc-2"))
    with pytest.raises(ConfigError, match="ambiguous"):
        store.show("abc")
    with pytest.raises(MissingChannelError, match="no experiment 'zzz' in the archive") as err:
        store.load("zzz")
    assert isinstance(err.value, KeyError)
    assert store.show("abc-2")["id"] == "abc-2"


# ------------------------------------------------------------------ search
@pytest.fixture
def lab(store):
    """Four experiments with the kind of configuration a lab writes."""
    rows = [
        dict(machine={"manufacturer": "Haas", "model": "VF-2"}, tool={"type": "end mill", "flutes": 2, "coating": "TiAlN"},
             material="Aluminium 6061", purpose="tooth passing study, dry", personnel=[{"name": "Ana Lima"}],
             start_state={"feed_rate": 0.05, "spindle": {"rpm": 1000}}, end_state={"feed_rate": 0.05}),
        dict(machine={"manufacturer": "Haas", "model": "VF-2"}, tool={"type": "end mill", "flutes": 4},
             material="AISI 1045 steel", purpose="chatter onset with a Fräser from Ølstykke",
             personnel=[{"name": "Ben Ode"}], start_state={"feed_rate": 0.12, "spindle": {"rpm": 4000}}),
        dict(machine="Fadal VMC 15XT", tool="face mill 50 mm", workpiece={"material": "cast iron"},
             operator="Carla", notes="passing tooth frequency; coolant flood",
             start_state={"feed_rate": 0.2}),
        dict(machine="Kern Evo", material="titanium Ti-6Al-4V", purpose="x_current_ref noise floor at 0.005 A"),
    ]
    ids = []
    for k, (meta, created) in enumerate(zip(rows, ("2024-01-10T08:00:00Z", "2024-02-20T12:00:00Z",
                                                 "2024-03-05T09:00:00+01:00", "2024-03-06T00:00:00Z"))):
        ids.append(store.add(Experiment.from_recordings(_rec(k, n=500, **meta), id=f"e{k}", created=created)))
    return store


@pytest.mark.parametrize("query, expected", [
    ("tooth", {"e0", "e2"}),
    ('"tooth passing"', {"e0"}),
    ('"passing tooth"', {"e2"}),
    ("alumin*", {"e0"}),
    ("FRASER olstykke", {"e1"}),
    ("tialn", {"e0"}),
    ("x_current_ref", {"e0", "e1", "e2", "e3"}),   # a channel name: in every document
    ("0.005 noise", {"e3"}),
    ("rpm", {"e0", "e1"}),                          # a key
    ("coolant haas", set()),
    ("", {"e0", "e1", "e2", "e3"}),
])
def test_full_text_finds_any_word_of_the_document(lab, query, expected):
    assert {h.id for h in lab.search(query or None)} == expected


@pytest.mark.parametrize("filters, expected", [
    (dict(machine="haas"), {"e0", "e1"}),
    (dict(machine="vf-2", material="steel"), {"e1"}),
    (dict(tool="flutes=4"), {"e1"}),
    (dict(material="iron"), {"e2"}),                 # found under workpiece.material
    (dict(operator="ana"), {"e0"}),
    (dict(operator="carla"), {"e2"}),
    (dict(since="2024-02-01", until="2024-03-05"), {"e1", "e2"}),   # e2 is 08:00 UTC on the 5th
    (dict(until="2024-01-10"), {"e0"}),
    (dict(start={"feed_rate": (0.1, None)}), {"e1", "e2"}),
    (dict(start={"feed_rate": (0.04, 0.15)}, end={"feed_rate": (None, 0.06)}), {"e0"}),
    (dict(start={"spindle.rpm": (2000, 5000)}), {"e1"}),
    (dict(machine="100%_"), set()),
])
def test_structured_filters(lab, filters, expected):
    assert {h.id for h in lab.search(**filters)} == expected


def test_text_and_filters_combine_and_limit(lab):
    hits = lab.search("tooth", machine="fadal")
    assert [h.id for h in hits] == ["e2"] and hits[0].machine == "Fadal VMC 15XT"
    assert len(lab.search(limit=2)) == 2
    assert [h.id for h in lab.search()] == ["e3", "e2", "e1", "e0"]  # newest first
    with pytest.raises(ConfigError, match="feed_rate"):
        lab.search(start={"feed_rate": 5})
    with pytest.raises(ConfigError, match="ISO 8601"):
        lab.search(since="last tuesday")


def test_search_never_reads_samples(lab):
    lab._conn.execute("DELETE FROM samples")
    if isinstance(lab, SqliteStore):
        lab._conn.execute("VACUUM")
    assert {h.id for h in lab.search("tooth", machine="haas")} == {"e0"}
    assert lab.show("e1")["measurements"][0]["samples"] == 500
    with pytest.raises(DriveSenseError, match="has 0 of 500 samples"):
        lab.load("e1")


def test_foreign_extension_text_is_searchable(store, tmp_path):
    path = tmp_path / "ext.xml"
    write_xml(_rec(3), path)
    text = path.read_text().replace('<measurement name="cut 3">',
                                    '<measurement name="cut 3" xmlns:lab="https://lab.example/x">', 1)
    text = text.replace("</measurement>", "<lab:note>spindle bearing replaced beforehand</lab:note></measurement>")
    path.write_text(text)
    eid = store.add(path)
    assert [h.id for h in store.search("bearing replaced")] == [eid]


def test_tokenizer_and_query_parser():
    assert tokenize("x_current_ref Fräser Ø6, 0.005") == ["x", "current", "ref", "fraser", "o6", "0", "005"]
    assert parse_query('"tooth passing" alu* x_current -') == [(["tooth", "passing"], False), (["alu"], True),
                                                              (["x", "current"], False)]


# ------------------------------------------------------------------ nothing lost
def test_failed_import_leaves_the_archive_unchanged(store, tmp_path, monkeypatch):
    store.add(_rec(1))
    before = _rows(store)
    path = tmp_path / "bad.xml"
    write_xml([_rec(2), _rec(3)], path)
    text = path.read_text()
    cut = text.rindex('<dataGroup count="3000">') + len('<dataGroup count="3000">') + 50
    path.write_text(text[:cut] + "!" + text[cut + 1:])  # bad base64 in the last channel
    with pytest.raises(InvalidSignalError, match="bad base64"):
        store.add(path)
    assert _rows(store) == before
    monkeypatch.setattr(type(store), "_index", lambda *a: (_ for _ in ()).throw(RuntimeError("disk on fire")))
    with pytest.raises(RuntimeError, match="disk on fire"):  # fails inside the transaction, after rows went in
        store.add(_rec(4))
    assert _rows(store) == before


def _slow_import(location, kw, seed, wfd):
    """Child: import one experiment, signal after the first sample blob is written, then hang."""
    st = open_archive(location, **kw)
    orig = st._exec

    def exec_then_hang(cur, sql, params=()):
        out = orig(cur, sql, params)
        if sql.startswith("INSERT INTO samples"):
            os.write(wfd, b"s")
            time.sleep(120)
        return out

    st._exec = exec_then_hang
    st.add(_rec(seed, n=20_000))


def test_killed_import_leaves_no_trace(where, monkeypatch):
    location, kw = where
    monkeypatch.setattr(sqlite_backend, "CHUNK_SAMPLES", 4096)
    with open_archive(location, **kw) as st:
        kept = st.add(_rec(1))
        before = _rows(st)
    rfd, wfd = os.pipe()
    child = _FORK.Process(target=_slow_import, args=(location, kw, 2, wfd))
    child.start()
    ready, _, _ = select.select([rfd], [], [], 60)
    assert ready, "the importing child never reached the sample blobs"
    os.kill(child.pid, signal.SIGKILL)
    child.join(30)
    os.close(rfd)
    os.close(wfd)
    assert child.exitcode == -signal.SIGKILL
    with open_archive(location, **kw) as st:
        assert _rows(st) == before and st.count() == 1
        assert st.load(kept).recordings[0].equals(_rec(1))
        if isinstance(st, SqliteStore):
            assert st._conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        st.add(_rec(2, n=20_000))  # the archive takes the same experiment afterwards
        assert st.count() == 2


def _writer(location, kw, worker, per):
    st = open_archive(location, **kw)
    for k in range(per):
        st.add(Experiment.from_recordings(_rec(100 * worker + k, n=5000, worker=worker), id=f"w{worker}-{k}"))
    st.close()


def test_eight_concurrent_writer_processes(where, monkeypatch):
    location, kw = where
    monkeypatch.setattr(sqlite_backend, "CHUNK_SAMPLES", 1024)  # several blobs per channel
    workers, per = 8, 5  # the archive does not exist yet: the writers also race to create it
    procs = [_FORK.Process(target=_writer, args=(location, kw, w, per)) for w in range(workers)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(180)
    assert [p.exitcode for p in procs] == [0] * workers
    with open_archive(location, **kw) as st:
        assert st.count() == workers * per
        rows = _rows(st)
        assert rows["channels"] == 3 * workers * per and rows["samples"] == 3 * 5 * workers * per
        for w in range(workers):
            for k in range(per):
                got = st.load(f"w{w}-{k}").recordings[0]
                assert got.equals(_rec(100 * w + k, n=5000, worker=w)), f"w{w}-{k} differs"
        if isinstance(st, SqliteStore):
            assert st._conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            assert st._conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


# ------------------------------------------------------------------ locations and CLI
def test_default_location_and_dsn_detection(tmp_path, monkeypatch):
    monkeypatch.delenv("DRIVESENSE_ARCHIVE", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert default_archive_path() == tmp_path / "data" / "drivesense" / "archive.sqlite"
    monkeypatch.setenv("DRIVESENSE_ARCHIVE", str(tmp_path / "mine.sqlite"))
    with open_archive() as st:
        assert st.location == str(tmp_path / "mine.sqlite")
    assert is_postgres_dsn("postgresql://u@h/db") and is_postgres_dsn("dbname=x host=/tmp")
    assert not is_postgres_dsn("/home/me/archive.sqlite")
    (tmp_path / "junk.sqlite").write_bytes(b"not a database" * 100)
    with pytest.raises(ConfigError, match="not a usable drivesense archive"):
        SqliteStore(tmp_path / "junk.sqlite")


def test_cli_user_story_archive_search_export_import(tmp_path, monkeypatch):
    """Archive recordings, find one by a word of its configuration, export XML, read it back identical."""
    monkeypatch.setenv("DRIVESENSE_ARCHIVE", str(tmp_path / "a.sqlite"))
    files = []
    for k, mat in enumerate(("aluminium", "brass", "steel")):
        rec = _rec(k, material=mat, condition={"feed_speed": 0.001 * (k + 1), "mode": "down"})
        write_recording(rec, tmp_path / f"r{k}.nc")
        files.append(str(tmp_path / f"r{k}.nc"))
    res = runner.invoke(app, ["archive", "add", *files, "--json", "-"])
    assert res.exit_code == 0, res.output
    ids = [r["id"] for r in json.loads(res.output)["added"]]
    res = runner.invoke(app, ["archive", "search", "brass", "--json", "-"])
    hits = json.loads(res.output)["hits"]
    assert [h["id"] for h in hits] == [ids[1]]
    res = runner.invoke(app, ["archive", "search", "--material", "steel"])
    assert res.exit_code == 0 and "1 experiment(s)" in res.output and "steel" in res.output
    res = runner.invoke(app, ["archive", "search", "--start", "feed_rate"])
    assert res.exit_code == 2 and "KEY=LOW:HIGH" in res.output
    res = runner.invoke(app, ["archive", "show", ids[1][:8]])
    assert res.exit_code == 0 and "x_table_position" in res.output and "brass" in res.output
    out = tmp_path / "brass.xml"
    assert runner.invoke(app, ["archive", "export", ids[1][:8], "--out", str(out)]).exit_code == 0
    res = runner.invoke(app, ["xml", "import", str(out), "--out", str(tmp_path / "brass.nc")])
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "brass.nc").equals(read_recording(files[1]))
    assert read_xml(out).equals(read_recording(files[1]))
    assert runner.invoke(app, ["archive", "rm", ids[0]]).exit_code == 0
    res = runner.invoke(app, ["archive", "show", ids[0]])
    assert res.exit_code == 2 and "no experiment" in res.output
    res = runner.invoke(app, ["archive", "add", str(tmp_path / "missing.xml")])
    assert res.exit_code == 2 and "missing.xml" in res.output
    assert sqlite3.connect(tmp_path / "a.sqlite").execute("SELECT count(*) FROM experiments").fetchone()[0] == 2
    assert Path(tmp_path / "a.sqlite").exists()
