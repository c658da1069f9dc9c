"""The tool's condition (``drivesense wear``): wear from cutting coefficients identified on spindle power, wear as
a live event between calibrations (each cut's power against the last calibration), when to calibrate next,
runout from once-per-revolution vibration."""

from drivesense.condition.cadence import AdaptiveCadence, CadenceProposal, CadenceSettings, propose_interval
from drivesense.condition.runout import RunoutEstimate, estimate_runout
from drivesense.condition.wear import (WearReport, WearState, WearTracker, WearTrackerSettings,
                                       percent_power_increase, track_wear)
from drivesense.condition.wear_live import (CutResidual, LiveWearMonitor, LiveWearReport, LiveWearSettings,
                                            cut_power, remaining_life, track_wear_live)

__all__ = ["WearTracker", "WearTrackerSettings", "WearState", "WearReport", "track_wear", "percent_power_increase",
           "AdaptiveCadence", "CadenceSettings", "CadenceProposal", "propose_interval",
           "RunoutEstimate", "estimate_runout", "LiveWearMonitor", "LiveWearSettings", "LiveWearReport",
           "CutResidual", "track_wear_live", "cut_power", "remaining_life"]
