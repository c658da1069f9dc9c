"""Monitoring: process events (breakage, chipping, chatter, collision/overload, teach-in limits) from force
streams, the tool's tooth count from the force's spectrum (when nobody gives it), tool wear from cutting
coefficients, when to calibrate next, runout from once-per-revolution vibration."""

from drivesense.monitor.breakage import BreakageDetector
from drivesense.monitor.chatter import ChatterDetector
from drivesense.monitor.detector import Detection, Detector, DetectorStream, Event
from drivesense.monitor.overload import OverloadDetector
from drivesense.monitor.pipeline import DetectionReport, default_detectors, detector_inputs, run_detectors
from drivesense.monitor.teach import TeachInDetector, TeachLimits, teach
from drivesense.monitor.teeth import TeethChoice, infer_teeth, resolve_teeth
from drivesense.monitor.cadence import AdaptiveCadence, CadenceProposal, CadenceSettings, propose_interval
from drivesense.monitor.runout import RunoutEstimate, estimate_runout
from drivesense.monitor.wear import (WearReport, WearState, WearTracker, WearTrackerSettings, percent_power_increase,
                                     track_wear)

__all__ = ["WearTracker", "WearTrackerSettings", "WearState", "WearReport", "track_wear", "percent_power_increase",
           "AdaptiveCadence", "CadenceSettings", "CadenceProposal", "propose_interval",
           "RunoutEstimate", "estimate_runout",
           "Event", "Detection", "Detector", "DetectorStream", "BreakageDetector", "ChatterDetector",
           "OverloadDetector",
           "TeachInDetector", "TeachLimits", "teach", "detector_inputs", "default_detectors", "run_detectors",
           "DetectionReport", "TeethChoice", "infer_teeth", "resolve_teeth"]
