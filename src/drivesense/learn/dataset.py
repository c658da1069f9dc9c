"""Training and test data for the learned reconstruction: the third paper's process grid, simulated.

The grid is Table 1 of the third paper (``a_p`` 1-4 mm, ``a_e`` 1-10 mm,
``v_f`` 300-800 mm/min, ``n`` 2600-6000 min^-1) over the simulator's process
types.  Combinations that would overload the tool are dropped by an explicit
rule (:func:`allowed`): the chip cross-section ``a_p * a_e`` may not exceed
24 mm^2 (10 mm end mill in C45), and full-width grooves are limited to
``a_p <= 2 mm`` (chatter-prone full immersion).  The split is by process
parameters: test runs use combinations that appear in no training run, and
one process type is held out entirely.  Beyond the paper, the training split
also holds air cuts (the same toolpaths with the tool clear of the part, so
the force is zero): free labelled examples of friction, cogging and inertia,
reversals included, which a real machine gives at no cost.  Everything is
seeded and cached on disk (one netCDF file per run plus ``index.json``).

A cached run is reused only under the same key (:func:`run_key`): a hash of
the run's spec and of the simulator's source, i.e. every ``.py`` file of
:mod:`drivesense.machine` and :mod:`drivesense.sim`
(:func:`simulator_fingerprint`), so any change to the physics or the
simulators rebuilds the cache.
"""

from __future__ import annotations

import hashlib
import importlib
import itertools
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.io.netcdf import load_netcdf, save_netcdf
from drivesense.recording import Recording

__all__ = ["RunSpec", "allowed", "plan_runs", "build_dataset", "load_dataset", "load_folder", "HELD_OUT_PROCESS",
           "TEST_ONLY_PROCESSES", "EXTRA_TEST_POCKETS",
           "simulator_fingerprint", "run_key", "SIMULATOR_PACKAGES"]

#: Packages whose source (every ``.py`` file next to their ``__init__``) keys the dataset cache.
SIMULATOR_PACKAGES = ("drivesense.machine", "drivesense.sim")

#: Process type never shown to the networks during training.
HELD_OUT_PROCESS = "side_-x+y"
#: Process types drawn only for held-out pockets, never for training (the clockwise, up-milling pocket).
TEST_ONLY_PROCESSES = ("pocket_cw",)
#: Held-out pockets beyond the grid's counter-clockwise one: (process, radius [m]).
EXTRA_TEST_POCKETS = (("pocket_cw", 0.015), ("pocket_ccw", 0.010), ("pocket_cw", 0.022))


@dataclass(frozen=True)
class RunSpec:
    """One simulated run.

    Attributes
    ----------
    process : str
        Process type (see :func:`drivesense.sim.machining.process_names`).
    a_p, a_e : float
        Axial and radial depth of cut [m].
    v_f : float
        Feed speed [m/s].
    n : float
        Spindle speed [min^-1].
    seed : int
        Simulation seed.
    split : str
        ``"train"``, ``"val"`` (early stopping), ``"test"`` (held-out parameters)
        or ``"test_process"`` (held-out process type).
    air : bool
        An air cut of the process (zero force; see
        :func:`drivesense.sim.machining.simulate_process`).
    pocket_radius : float, optional
        A pocket's tool-centre radius [m] (default that of
        :class:`~drivesense.sim.machining.ProcessSettings`).
    """

    process: str
    a_p: float
    a_e: float
    v_f: float
    n: float
    seed: int
    split: str
    air: bool = False
    pocket_radius: float | None = None

    @property
    def name(self) -> str:
        """File-friendly identifier."""
        from drivesense.sim.machining import process_run_name

        return process_run_name(self.process, self.a_p, self.a_e, self.v_f, self.n, air=self.air,
                                pocket_radius=self.pocket_radius) + f"_s{self.seed}"


def allowed(process: str, a_p: float, a_e: float) -> bool:
    """Whether a combination is kept: chip cross-section <= 24 mm^2, grooves a_p <= 2 mm (see module doc).

    Parameters
    ----------
    process : str
        Process type (see :func:`drivesense.sim.machining.process_names`).
    a_p : float
        Axial depth of cut [m].
    a_e : float
        Radial depth of cut [m].

    Returns
    -------
    bool
    """
    if process.startswith("groove"):
        return a_p <= 2e-3 + 1e-12
    return a_p * a_e <= 24e-6 + 1e-15


def plan_runs(n_train: int = 150, n_val: int = 15, n_test: int = 21, n_held_out_process: int = 8,
              n_air: int = 34, seed: int = 2021, extra_pockets=EXTRA_TEST_POCKETS) -> list[RunSpec]:
    """Draw the runs: parameter combinations from the grid, process types in turn.

    Parameters
    ----------
    n_train, n_val, n_test : int
        Runs per split; test combinations are disjoint from training ones.
    n_held_out_process : int
        Runs of :data:`HELD_OUT_PROCESS`.
    n_air : int
        Air cuts added to the training split (process types in turn, training
        parameter combinations; never the held-out process type).
    seed : int
        Seed of the draw (and base of the simulation seeds).
    extra_pockets : sequence of (str, float)
        Further held-out pockets (process, radius [m]) in the test split, at
        parameter combinations that no training or validation run uses; drawn
        after every other run, so they change none of them.

    Returns
    -------
    list of RunSpec
    """
    from drivesense.sim.machining import process_names, table1_process_grid

    grid = table1_process_grid()
    processes = [p for p in process_names() if p != HELD_OUT_PROCESS and p not in TEST_ONLY_PROCESSES]
    combos = list(itertools.product(grid["a_p"], grid["a_e"], grid["v_f"], grid["n"]))
    rng = np.random.default_rng(seed)
    rng.shuffle(combos)
    runs: list[RunSpec] = []
    used_test: set = set()
    counts = {"train": n_train, "val": n_val, "test": n_test}
    it = iter(combos)
    k = 0
    for split in ("test", "val", "train"):
        made = 0
        while made < counts[split]:
            try:
                a_p, a_e, v_f, n = next(it)
            except StopIteration:
                raise ConfigError("the process grid holds too few allowed combinations for the requested runs") \
                    from None
            process = processes[k % len(processes)]
            if not allowed(process, a_p, a_e):
                continue
            if split == "test":
                used_test.add((a_p, a_e, v_f, n))
            elif (a_p, a_e, v_f, n) in used_test:
                continue
            runs.append(RunSpec(process, a_p, a_e, v_f, n, seed + len(runs), split))
            made += 1
            k += 1
    for j in range(n_held_out_process):
        a_p, a_e, v_f, n = combos[(7 * j + 3) % len(combos)]
        while not allowed(HELD_OUT_PROCESS, a_p, a_e):
            a_p = a_p - 1e-3
        runs.append(RunSpec(HELD_OUT_PROCESS, a_p, a_e, v_f, n, seed + len(runs), "test_process"))
    train = [r for r in runs if r.split == "train"]
    k = 0
    for j in range(n_air):
        process = processes[j % len(processes)]
        for _ in range(len(train)):      # the next training combination, in turn, that the process type allows
            r = train[k % len(train)]
            k += 1
            if allowed(process, r.a_p, r.a_e):
                break
        else:
            raise ConfigError(f"no training combination suits an air cut of {process!r}; add training runs")
        runs.append(RunSpec(process, r.a_p, r.a_e, r.v_f, r.n, seed + len(runs), "train", air=True))
    fitted = {(r.a_p, r.a_e, r.v_f, r.n) for r in runs if r.split in ("train", "val")}
    spare = (c for c in reversed(combos) if c not in fitted and c not in used_test)
    for process, radius in extra_pockets:
        a_p, a_e, v_f, n = next(c for c in spare if allowed(process, c[0], c[1]))
        runs.append(RunSpec(process, a_p, a_e, v_f, n, seed + len(runs), "test", pocket_radius=radius))
    return runs


def simulator_fingerprint() -> str:
    """Hash of the simulator's source: every ``.py`` file of :data:`SIMULATOR_PACKAGES`.

    The files are read next to each package's ``__init__``
    (``Path(module.__file__).parent.glob("*.py")``), in sorted order, and
    hashed with their package and file names (SHA-256).

    Returns
    -------
    str
        16 hex digits.
    """
    h = hashlib.sha256()
    for name in SIMULATOR_PACKAGES:
        folder = Path(importlib.import_module(name).__file__).parent
        for path in sorted(folder.glob("*.py")):
            h.update(f"{name}/{path.name}\0".encode())
            h.update(path.read_bytes())
            h.update(b"\0")
    return h.hexdigest()[:16]


def run_key(spec: RunSpec, fingerprint: str | None = None) -> str:
    """Cache key of one run: a hash of its spec and of the simulator's source.

    Parameters
    ----------
    spec : RunSpec
        The run.
    fingerprint : str, optional
        :func:`simulator_fingerprint` (computed if not given).

    Returns
    -------
    str
        16 hex digits; changes with any field of ``spec`` or any simulator source file.
    """
    fingerprint = simulator_fingerprint() if fingerprint is None else fingerprint
    payload = json.dumps({"spec": asdict(spec), "simulator": fingerprint}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def _write_index(path: Path, payload: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(payload, indent=1), encoding="utf-8")
    os.replace(tmp, path)


def build_dataset(out_dir, runs: Sequence[RunSpec] | None = None, *,
                  progress: Callable[[str], None] | None = None, simulate=None) -> dict:
    """Simulate and cache the runs in ``out_dir`` (runs already cached with the same spec are kept).

    Parameters
    ----------
    out_dir : str or Path
        Cache folder (created).
    runs : sequence of RunSpec, optional
        Default :func:`plan_runs`.
    progress : callable, optional
        Called with each run's name.
    simulate : callable, optional
        ``simulate(spec) -> Recording`` (default: :func:`drivesense.sim.machining.simulate_process`).

    Returns
    -------
    dict
        The index: runs with their split, file and cache key (:func:`run_key`),
        the simulator fingerprint, ``bytes_on_disk``.
    """
    from drivesense.sim.machining import ProcessSettings, simulate_process

    out = Path(out_dir)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    runs = list(runs) if runs is not None else plan_runs()
    simulate = simulate or (lambda s: simulate_process(
        s.process, s.a_p, s.a_e, s.v_f, s.n, seed=s.seed, air=s.air,
        settings=None if s.pocket_radius is None else ProcessSettings(pocket_radius=s.pocket_radius)))
    index_path = out / "index.json"
    fingerprint = simulator_fingerprint()
    old = {}
    if index_path.exists():
        previous = json.loads(index_path.read_text())
        old = {r["file"]: r.get("key") for r in previous.get("runs", [])}
    entries = []
    for spec in runs:
        file = f"runs/{spec.name}.nc"
        key = run_key(spec, fingerprint)
        if not (old.get(file) == key and (out / file).exists()):
            rec = simulate(spec)
            save_netcdf(rec.with_meta(split=spec.split), out / file)
        entries.append({"file": file, "spec": asdict(spec), "key": key})
        if progress:
            progress(spec.name)
    size = sum((out / e["file"]).stat().st_size for e in entries)
    index = {"format": "drivesense-dataset-1", "simulator": fingerprint, "runs": entries, "bytes_on_disk": size,
             "exclusion_rule": "a_p*a_e <= 24 mm^2; grooves a_p <= 2 mm", "held_out_process": HELD_OUT_PROCESS}
    _write_index(index_path, index)
    return index


def load_dataset(folder, *, read=None) -> list[tuple[RunSpec | None, Recording]]:
    """Load a dataset folder: a built one (``index.json``) or any folder of recordings.

    Parameters
    ----------
    folder : str or Path
        Built dataset, or a user's folder of ``.nc`` / ``.csv`` traces with
        canonical channel names and reference ``force_{ax}`` channels (their
        split is then decided by :func:`load_folder`).
    read : callable, optional
        Reads one trace of a user's folder, ``read(path) -> Recording``
        (default :func:`drivesense.io.read_recording`), e.g. with the CLI's
        ``--fs``/``--resample``/``--assume-si``.

    Returns
    -------
    list of (RunSpec or None, Recording)
    """
    folder = Path(folder)
    index = folder / "index.json"
    if not index.exists():
        return load_folder(folder, read=read)
    data = json.loads(index.read_text())
    out = []
    for entry in data["runs"]:
        rec = load_netcdf(folder / entry["file"])
        out.append((RunSpec(**entry["spec"]), rec))
    return out


def load_folder(folder, *, val_fraction: float = 0.1, seed: int = 0,
                read=None) -> list[tuple[RunSpec | None, Recording]]:
    """A user's own traces: every ``.nc`` and ``.csv`` in ``folder``; a seeded share goes to validation.

    Traces keep their sample rate here; :mod:`drivesense.learn.train` resamples
    explicitly to the model's rate.

    Parameters
    ----------
    folder : str or Path
        Folder holding the traces.
    val_fraction : float, optional
        Share of the traces for validation [-] (at least one when there are
        more than two traces).
    seed : int, optional
        Seed of the draw.
    read : callable, optional
        Reads one trace, ``read(path) -> Recording`` (default
        :func:`drivesense.io.read_recording`).

    Returns
    -------
    list of (None, Recording)
        Each trace with ``meta["split"]`` set to ``"train"`` or ``"val"``.
    """
    from drivesense.io import read_recording

    folder = Path(folder)
    if folder.is_file():
        raise InvalidSignalError(f"dataset folder '{folder}' is a file: give the folder of the traces")
    if not folder.is_dir():
        raise FileNotFoundError(f"dataset folder '{folder}' does not exist")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".nc", ".csv"))
    if not files:
        raise InvalidSignalError(f"'{folder}' holds no .nc or .csv traces")
    rng = np.random.default_rng(seed)
    n_val = max(1, int(round(val_fraction * len(files)))) if len(files) > 2 else 0
    val = set(rng.choice(len(files), n_val, replace=False).tolist()) if n_val else set()
    out = []
    for i, path in enumerate(files):
        rec = (read or read_recording)(path)
        out.append((None, rec.with_meta(split="val" if i in val else "train")))
    return out
