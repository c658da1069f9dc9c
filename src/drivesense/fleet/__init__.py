"""Fleet scale: a method over many recordings on a Dask cluster (:mod:`.batch`).

::

    from drivesense.fleet import EstimateJob, file_inputs, files_from_patterns, run_batch

    job = EstimateJob(method="vibration", axis_file="AXIS.toml", idle=["idle.nc"])
    report = run_batch(job, file_inputs(files_from_patterns(["runs/*.nc"])), "out", workers=2)
"""

from drivesense.fleet.batch import BatchReport, run_batch, run_task, task_key
from drivesense.fleet.inputs import BatchInput, archive_inputs, file_inputs, files_from_patterns
from drivesense.fleet.jobs import JOBS, BatchJob, DetectJob, EstimateJob, IdentifyJob, WearJob

__all__ = ["BatchJob", "EstimateJob", "DetectJob", "WearJob", "IdentifyJob", "JOBS", "BatchInput", "BatchReport",
           "run_batch", "run_task", "task_key", "file_inputs", "files_from_patterns", "archive_inputs"]
