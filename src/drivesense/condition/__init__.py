"""The tool's condition (``drivesense wear``): wear from cutting coefficients identified on spindle power, when
to calibrate next, runout from once-per-revolution vibration."""

from drivesense.condition.cadence import AdaptiveCadence, CadenceProposal, CadenceSettings, propose_interval
from drivesense.condition.runout import RunoutEstimate, estimate_runout
from drivesense.condition.wear import (WearReport, WearState, WearTracker, WearTrackerSettings,
                                       percent_power_increase, track_wear)

__all__ = ["WearTracker", "WearTrackerSettings", "WearState", "WearReport", "track_wear", "percent_power_increase",
           "AdaptiveCadence", "CadenceSettings", "CadenceProposal", "propose_interval",
           "RunoutEstimate", "estimate_runout"]
