"""The learned-method dataset cache is keyed on each run's spec and on the simulator's source."""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest

from drivesense.learn import dataset
from drivesense.learn.dataset import RunSpec, build_dataset, run_key, simulator_fingerprint
from drivesense.recording import Recording

RUNS = [RunSpec("groove_+x", 2e-3, 10e-3, 0.01, 4500.0, 1, "train"),
        RunSpec("side_+y", 1e-3, 4e-3, 0.005, 3500.0, 2, "test")]


class _Counter:
    """A stand-in simulator: a tiny recording per run, counting its calls."""

    def __init__(self):
        self.calls = []

    def __call__(self, spec: RunSpec) -> Recording:
        self.calls.append(spec.name)
        return Recording.from_arrays({"x_current": np.full(8, float(spec.seed))}, fs=250.0)


def test_key_changes_with_the_source_hash_and_the_spec(monkeypatch):
    spec = RUNS[0]
    key = run_key(spec)
    assert key == run_key(spec) == run_key(spec, simulator_fingerprint())
    assert run_key(replace(spec, seed=99)) != key
    monkeypatch.setattr(dataset, "simulator_fingerprint", lambda: "0123456789abcdef")
    assert run_key(spec) != key


def test_fingerprint_hashes_every_source_file_of_the_packages(tmp_path, monkeypatch):
    assert dataset.SIMULATOR_PACKAGES == ("drivesense.machine", "drivesense.sim")
    pkg = tmp_path / "fake_physics_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(dataset, "SIMULATOR_PACKAGES", ("fake_physics_pkg",))
    first = simulator_fingerprint()
    assert simulator_fingerprint() == first
    (pkg / "a.py").write_text("X = 2\n")
    second = simulator_fingerprint()
    (pkg / "b.py").write_text("")
    third = simulator_fingerprint()
    (pkg / "notes.txt").write_text("not source")
    assert len({first, second, third}) == 3 and simulator_fingerprint() == third
    sys.modules.pop("fake_physics_pkg", None)


def test_build_reuses_runs_until_the_source_changes(tmp_path, monkeypatch):
    sim = _Counter()
    index = build_dataset(tmp_path, RUNS, simulate=sim)
    assert sorted(sim.calls) == sorted(r.name for r in RUNS)
    assert all(e["key"] == run_key(RunSpec(**e["spec"])) for e in index["runs"])
    sim.calls.clear()
    build_dataset(tmp_path, RUNS, simulate=sim)
    assert sim.calls == []                                   # same spec, same source: cached
    changed = [RUNS[0], replace(RUNS[1], split="val")]
    build_dataset(tmp_path, changed, simulate=sim)
    assert sim.calls == [RUNS[1].name]                       # only the changed spec
    sim.calls.clear()
    monkeypatch.setattr(dataset, "simulator_fingerprint", lambda: "fedcba9876543210")
    index = build_dataset(tmp_path, changed, simulate=sim)
    assert sorted(sim.calls) == sorted(r.name for r in RUNS)  # a physics change rebuilds everything
    assert index["simulator"] == "fedcba9876543210"


@pytest.mark.parametrize("edit", ["drop_index_keys", "garbage_key"])
def test_old_or_foreign_index_entries_are_rebuilt(tmp_path, edit):
    import json

    sim = _Counter()
    build_dataset(tmp_path, RUNS, simulate=sim)
    path = tmp_path / "index.json"
    data = json.loads(path.read_text())
    for e in data["runs"]:
        if edit == "drop_index_keys":
            e.pop("key")
        else:
            e["key"] = "x"
    path.write_text(json.dumps(data))
    sim.calls.clear()
    build_dataset(tmp_path, RUNS, simulate=sim)
    assert sorted(sim.calls) == sorted(r.name for r in RUNS)
