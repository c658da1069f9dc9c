"""Run a job over many inputs on a Dask cluster: resumable, one summary row per input, failures recorded.

::

    job = EstimateJob(method="vibration", axis_file=Path("AXIS.toml"), idle=[Path("idle.nc")])
    report = run_batch(job, file_inputs(files_from_patterns(["runs/*.nc"])), Path("out"), workers=2)
    pandas.read_parquet("out/summary.parquet")

Each input gets a key: the digest of its content and of the job's
configuration (:meth:`~drivesense.fleet.jobs.BatchJob.config_hash`).  A task
writes its result files under ``OUT/results/`` and then its row as
``OUT/rows/KEY.json`` (both atomically): a row on disk means the result is
complete, so a rerun -- after a kill, or with new inputs -- runs only the
inputs without a row.  A failing input gets a row with status ``error`` and its
message; it never stops the batch (``retry_failed`` runs those again).
``OUT/summary.parquet`` holds the rows of this run's inputs in input order; it
is rewritten every few seconds while the batch runs.

Where the inputs came from an archive, the client writes the results back
(one writer): the force estimate as an experiment ``<id>-estimate-<key>``,
detected events into the events table (ids ``<experiment>/<detector>/<axis>/<us>``);
both are idempotent, and a rerun completes what a killed run left unwritten.

With ``workers=0`` the inputs run one after the other in this process (the
reference a parallel run is compared with); otherwise on a
:class:`distributed.LocalCluster` of that many single-threaded worker
processes, or on the cluster at ``scheduler``.  A remote cluster's workers
must see the inputs, the archive and ``OUT`` under the same paths.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import socket
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

from drivesense.errors import ConfigError
from drivesense.fleet.inputs import BatchInput, derived_id
from drivesense.fleet.jobs import BatchJob

__all__ = ["run_batch", "run_task", "task_key", "BatchReport", "read_rows", "local_cluster", "ROWS", "RESULTS",
           "SUMMARY"]

#: Folders and files of a batch's output folder.
ROWS, RESULTS, SUMMARY = "rows", "results", "summary.parquet"
#: Seconds between rewrites of the summary while a batch runs.
SUMMARY_EVERY_S = 5.0


def task_key(item: BatchInput, job_hash: str) -> str:
    """The key of one input under one job: BLAKE2b-128 of its content key and the job's hash (hex).

    Parameters
    ----------
    item : BatchInput
        The input (its ``content`` key).
    job_hash : str
        :meth:`~drivesense.fleet.jobs.BatchJob.config_hash` of the job.
    """
    return hashlib.blake2b(f"{item.content}|{job_hash}".encode(), digest_size=16).hexdigest()


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def run_task(job: BatchJob, item: BatchInput, out_dir: str, key: str) -> dict:
    """Run ``job`` on one input, write its result files and then its row; the row (runs on a worker).

    Parameters
    ----------
    job : BatchJob
        The prepared job.
    item : BatchInput
        The input.
    out_dir : str
        The batch's output folder.
    key : str
        The input's key (:func:`task_key`).

    Returns
    -------
    dict
        The row: ``input``, ``key``, ``status`` (``ok`` | ``error``), ``error``, ``outputs``, ``seconds``
        (compute time [s]), ``cpu_seconds`` (CPU time of the task's thread [s]: below ``seconds`` when the
        worker shared its core), ``finished``, ``worker``, and the job's values.
    """
    from drivesense.io import write_json_file

    out = Path(out_dir)
    stem = out / RESULTS / f"{item.stem}-{key[:12]}"
    began, began_cpu = time.perf_counter(), time.thread_time()
    row: dict[str, Any] = {"input": item.name, "key": key, "job": job.kind}
    try:
        with _local_io():
            values = job.run(item.load(job), stem)
        row.update(status="ok", error="", outputs=";".join(f"{RESULTS}/{stem.name}{s}" for s in job.outputs),
                   **values)
    except Exception as exc:  # noqa: BLE001 - one input failing never stops the batch: it is recorded
        row.update(status="error", error=f"{type(exc).__name__}: {exc}"[:2000], outputs="")
    row.update(seconds=time.perf_counter() - began, cpu_seconds=time.thread_time() - began_cpu, finished=_now(), worker=f"{socket.gethostname()}:{os.getpid()}")
    write_json_file(out / ROWS / f"{key}.json", row, indent=None)      # last: the results are in place
    return row


@contextmanager
def _local_io():
    """Inside a Dask worker, xarray would take the cluster's distributed lock for every netCDF write (a round
    trip to the scheduler each): the arrays here are in memory, so the synchronous scheduler is the right one."""
    try:
        import dask
    except ImportError:
        yield
        return
    with dask.config.set(scheduler="synchronous"):
        yield


def read_rows(out_dir: Path, keys) -> dict[str, dict]:
    """Rows already written for ``keys`` (a torn or unreadable row counts as not written).

    Parameters
    ----------
    out_dir : Path
        The batch's output folder.
    keys : iterable of str
        Input keys.
    """
    import json

    rows = {}
    for k in keys:
        p = Path(out_dir) / ROWS / f"{k}.json"
        if p.exists():
            try:
                rows[k] = json.loads(p.read_text())
            except ValueError:
                continue
    return rows


@dataclass
class BatchReport:
    """What a batch did.

    Attributes
    ----------
    job : str
        Job kind.
    inputs : int
        Inputs given.
    ran, skipped, failed : int
        Run now; skipped (a row from before); failed now or before (status ``error``).
    seconds : float
        Wall time [s] of the whole batch (cluster start included).
    workers : int
        Worker processes (0: in this process).
    summary : Path
        The Parquet summary.
    dashboard : str or None
        The Dask dashboard's address.
    archived : int
        Results written back into the archive now.
    rows : list of dict
        One per input, in input order.
    """

    job: str
    inputs: int
    ran: int
    skipped: int
    failed: int
    seconds: float
    workers: int
    summary: Path
    dashboard: str | None = None
    archived: int = 0
    rows: list = field(default_factory=list, repr=False)

    def to_dict(self) -> dict:
        """Plain JSON values (rows left out)."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in self.__dict__.items() if k != "rows"}


def _write_summary(path: Path, rows: list[dict]) -> None:
    import pandas as pd

    from drivesense.io import atomic_output

    frame = pd.DataFrame(rows)
    with atomic_output(path) as tmp:
        frame.to_parquet(tmp, index=False)


#: Environment of local worker processes: Dask's (one thread per BLAS library; glibc returning freed memory),
#: plus arrays of a few MB from the heap rather than fresh mmaps (page faults on every drive-signal array).
WORKER_ENVIRON = {"MALLOC_TRIM_THRESHOLD_": 65536, "MALLOC_MMAP_THRESHOLD_": 1 << 26, "OMP_NUM_THREADS": 1,
                  "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}

#: Less book-keeping for tasks of seconds: no statistical profiler sampling the tasks, slower ticks and
#: system monitoring (a scheduler in the client's process takes ~10 % of a core with Dask's defaults).
QUIET_CLUSTER = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "200ms",
                 "distributed.admin.system-monitor.interval": "2s"}


def local_cluster(workers: int, *, dashboard: bool = True):
    """A :class:`distributed.LocalCluster` of ``workers`` single-threaded processes for batches.

    Parameters
    ----------
    workers : int
        Worker processes.
    dashboard : bool
        Serve the Dask dashboard on a free port (when bokeh is installed).
    """
    try:
        import dask
        from distributed import LocalCluster
    except ImportError:
        raise ConfigError("a parallel batch needs Dask: pip install 'drivesense[fleet]' (or --workers 0 to run "
                          "in this process)") from None
    address = "127.0.0.1:0" if dashboard and importlib.util.find_spec("bokeh") else None
    with dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON, **QUIET_CLUSTER}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=address,
                            silence_logs=logging.ERROR)


def _start_cluster(workers: int, scheduler: str | None):
    """A Dask client on ``scheduler``, or on a new :func:`local_cluster`; (client, cluster or None)."""
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError("a parallel batch needs Dask: pip install 'drivesense[fleet]' (or --workers 0 to run "
                          "in this process)") from None
    if scheduler is not None:
        try:
            return Client(scheduler, timeout=20), None
        except OSError as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    cluster = local_cluster(workers)
    return Client(cluster), cluster


def run_batch(job: BatchJob, items: list[BatchInput], out_dir: str | Path, *, workers: int = 2,
              scheduler: str | None = None, client: Any = None, retry_failed: bool = False,
              progress: Callable[[int, int, dict], None] | None = None,
              on_start: Callable[[dict], None] | None = None) -> BatchReport:
    """Run ``job`` over ``items``; results and rows under ``out_dir``, the Parquet summary at the end.

    Parameters
    ----------
    job : BatchJob
        The job (prepared here when there is something to run, unless it was already).
    items : list of BatchInput
        The inputs.
    out_dir : str or Path
        Output folder (created).
    workers : int
        Local worker processes (0: run in this process, one input after the other).
    scheduler : str, optional
        ``tcp://HOST:8786`` of a running Dask scheduler (``workers`` is then ignored).
    client : distributed.Client, optional
        A client of your own (left open; ``workers`` and ``scheduler`` are then ignored).
    retry_failed : bool
        Run inputs whose row says ``error`` again.
    progress : callable, optional
        ``progress(done, to_run, row)`` after each input run now.
    on_start : callable, optional
        ``on_start(info)`` once the work is known: ``to_run``, ``skipped``, ``dashboard``, ``workers``.

    Returns
    -------
    BatchReport
    """
    from drivesense.io import write_json_file

    began = time.perf_counter()
    if not items:
        raise ConfigError("the batch has no input")
    if workers < 0:
        raise ConfigError(f"--workers must be >= 0, got {workers!r}")
    if not (importlib.util.find_spec("pyarrow") and importlib.util.find_spec("pandas")):
        raise ConfigError("the batch summary is a Parquet table: pip install 'drivesense[fleet]' (pyarrow, pandas)")
    out = Path(out_dir)
    (out / ROWS).mkdir(parents=True, exist_ok=True)
    (out / RESULTS).mkdir(parents=True, exist_ok=True)
    job_hash = job.config_hash()                       # the contents it depends on, not the prepared state
    write_json_file(out / f"job-{job.kind}-{job_hash[:12]}.json", {"hash": job_hash, "config": job.config()})
    keys = [task_key(i, job_hash) for i in items]
    rows = read_rows(out, set(keys))
    if retry_failed:
        rows = {k: r for k, r in rows.items() if r.get("status") == "ok"}
    skipped = sum(1 for k in keys if k in rows)
    todo: dict[str, BatchInput] = {}
    for item, key in zip(items, keys):
        if key not in rows:
            todo.setdefault(key, item)                 # the same content twice runs once
    if todo:
        job.ensure_prepared()                          # a rerun with nothing to do fits no friction map
    own = client is None
    cluster = None
    dashboard = None
    archived = 0
    writer = _ArchiveWriteBack(job, out) if any(i.archive for i in items) else None
    last_summary = [time.perf_counter()]

    def finished(key: str, row: dict, done: int) -> None:
        rows[key] = row
        if progress is not None:
            progress(done, len(todo), row)
        if time.perf_counter() - last_summary[0] > SUMMARY_EVERY_S:
            _write_summary(out / SUMMARY, _ordered(items, keys, rows))
            last_summary[0] = time.perf_counter()

    try:
        n_workers = 0
        if own and todo and (workers > 0 or scheduler is not None):
            client, cluster = _start_cluster(workers, scheduler)
        if client is not None:
            dashboard = client.dashboard_link if cluster is None or importlib.util.find_spec("bokeh") else None
            n_workers = len(client.nthreads()) or workers
        if on_start is not None:
            on_start({"to_run": len(todo), "skipped": skipped, "dashboard": dashboard, "workers": n_workers})
        if client is None:
            for done, (key, item) in enumerate(todo.items(), 1):
                finished(key, run_task(job, item, str(out), key), done)
        else:
            _run_on_cluster(client, job, todo, out, finished)
    finally:
        if own and client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        ordered = _ordered(items, keys, rows)
        if ordered:
            _write_summary(out / SUMMARY, ordered)
    if writer is not None:
        archived = writer.write_all([(i, rows[k]) for i, k in zip(items, keys) if i.archive and k in rows])
    failed = sum(1 for k in set(keys) if rows.get(k, {}).get("status") == "error")
    return BatchReport(job.kind, len(items), len(todo), skipped, failed, time.perf_counter() - began, n_workers,
                       out / SUMMARY, dashboard, archived, ordered)


def _ordered(items, keys, rows) -> list[dict]:
    """The rows in input order, each naming its own input (two inputs with one content share a row)."""
    return [{**rows[k], "input": i.name} for i, k in zip(items, keys) if k in rows]


def _run_on_cluster(client, job: BatchJob, todo: dict, out: Path, finished) -> None:
    """Submit every input, collect rows as they complete; a task lost with its worker gets an error row."""
    from distributed import as_completed

    from drivesense.io import write_json_file

    shared = client.scatter(job, broadcast=True, hash=False)
    futures = {client.submit(run_task, shared, item, str(out), key, key=f"drivesense-{job.kind}-{key}",
                             pure=False, retries=0): key for key, item in todo.items()}
    for done, fut in enumerate(as_completed(futures), 1):
        key = futures[fut]
        try:
            row = fut.result()
        except Exception as exc:  # noqa: BLE001 - a worker lost (killed, out of memory): recorded, the batch goes on
            item = todo[key]
            row = {"input": item.name, "key": key, "job": job.kind, "status": "error", "outputs": "",
                   "error": f"the task was lost: {type(exc).__name__}: {exc}"[:2000], "seconds": None,
                   "cpu_seconds": None, "finished": _now(), "worker": ""}
            write_json_file(out / ROWS / f"{key}.json", row, indent=None)
        finished(key, row, done)


class _ArchiveWriteBack:
    """Results of archived inputs back into their archive (idempotent; from the client only)."""

    def __init__(self, job: BatchJob, out: Path) -> None:
        self.job, self.out = job, out

    def write_all(self, pairs: list) -> int:
        from drivesense.archive import open_archive

        n, stores = 0, {}
        try:
            for item, row in pairs:
                if row.get("status") != "ok":
                    continue
                store = stores.get(item.archive)
                if store is None:
                    store = stores[item.archive] = open_archive(item.archive, create=False)
                n += self._one(store, item, row)
        finally:
            for store in stores.values():
                store.close()
        return n

    def _one(self, store, item: BatchInput, row: dict) -> int:
        kind, first = self.job.kind, self.out / row["outputs"].split(";")[0]
        if kind == "estimate":
            from drivesense.io import read_recording
            from drivesense.io.xml_format import Experiment

            exp_id = derived_id(item.experiment, "estimate", row["key"])
            try:
                store.show(exp_id)
                return 0
            except KeyError:
                pass
            force = read_recording(first)
            force = force.with_meta(name=f"{force.meta.get('name') or 'force'} of {item.experiment}",
                                    derived_from=item.experiment, batch_key=row["key"],
                                    **({"machine": item.machine} if item.machine else {}))
            store.add(Experiment.from_recordings(force, id=exp_id))
            return 1
        if kind == "detect":
            import json

            payload = json.loads(first.read_text())
            added = 0
            for e in payload.get("events", []):
                record = {**e, "id": f"{item.experiment}/{e['detector']}/{e['axis']}/{round(e['time_s'] * 1e6)}",
                          "machine": item.machine or item.experiment, "source_experiment": item.experiment,
                          "batch_key": row["key"]}
                added += bool(store.add_event(record))
            return added
        return 0
