"""Process events (``drivesense detect``, ``drivesense teach``, and what ``drivesense monitor`` runs live):
breakage, chipping, chatter, collision/overload and teach-in limits from force streams, the guards that hold
them where the process changes on command (the NC's context), and the tool's tooth count from the force's
spectrum when nobody gives it."""

from drivesense.events.breakage import BreakageDetector
from drivesense.events.chatter import ChatterDetector
from drivesense.events.detector import Detection, Detector, DetectorStream, Event
from drivesense.events.overload import OverloadDetector
from drivesense.events.pipeline import DetectionReport, default_detectors, detector_inputs, run_detectors
from drivesense.events.teach import TeachInDetector, TeachLimits, teach
from drivesense.events.teeth import TeethChoice, infer_teeth, resolve_teeth

__all__ = ["Event", "Detection", "Detector", "DetectorStream", "BreakageDetector", "ChatterDetector",
           "OverloadDetector", "TeachInDetector", "TeachLimits", "teach", "detector_inputs", "default_detectors",
           "run_detectors", "DetectionReport", "TeethChoice", "infer_teeth", "resolve_teeth"]
