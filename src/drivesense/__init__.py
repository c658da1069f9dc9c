"""drivesense: process force and tool condition from a CNC machine tool's own drive signals.

>>> import drivesense as ds
>>> axis = ds.table1_axis()
>>> cut = ds.sim.simulate_cut(ds.sim.paper_conditions()[0])
>>> est = ds.estimate.VibrationMode(axis).fit(ds.sim.simulate_idle(ds.sim.paper_conditions()[0]))
>>> force = est.estimate(cut)                        # Recording with force_x [N]
"""

from drivesense import errors, estimate, learn, sim
from drivesense.errors import DriveSenseError
from drivesense.estimate import (CurrentOnly, FrictionMap, MEDOB, RigidBody, SignalParams, VibrationMode,
                                 build_friction_map)
from drivesense.learn import LSTM, Hybrid
from drivesense.io import read_csv, read_recording, write_csv, write_recording
from drivesense.io.axis_file import read_axis_file, write_axis_file
from drivesense.machine.ballscrew import BallScrewAxis
from drivesense.machine.presets import table1_axis, table1_stage
from drivesense.recording import Recording
from drivesense.score import Score, score_estimate
from drivesense import condition, events
from drivesense.machine.cutting_power import (CutConditions, average_tangential_force, chip_thickness_from_angles,
                                              cutting_power, engagement_angle, force_per_depth)
from drivesense.identify.coefficients import (CutTable, SeeSawWarning, TangentialFit, average_power,
                                              calibrate_from_power, fit_tangential_coefficients, read_cut_table)
from drivesense.identify.feed_power import FeedCuts, FeedPowerModel, fit_feed_power, per_speed_fits, read_feed_cuts
from drivesense.identify.sensor import (SensorCalibration, calibrate_sensor, check_linearity, deconvolution_residual,
                                        ratio_spectrum)
from drivesense.condition import (RunoutEstimate, WearReport, WearTracker, WearTrackerSettings, estimate_runout,
                                  percent_power_increase, track_wear)
from drivesense.sim.tool_life import WearExperiment, simulate_tool_life, table1_experiments
from drivesense.sim.electret import ElectretSensor, simulate_shaker_pair
from drivesense.estimate.model_based import ModelBased
from drivesense.identify.linear_axis import IdentificationReport, identify_axes, run_identification
from drivesense.identify.controller import ControllerIdentification, identify_controller
from drivesense.machine.controller_model import ControllerAxis, ControllerModel
from drivesense.io.axes_file import read_axes_file, write_axes_file
from drivesense.machine.linear_motor import LinearMotorAxis, ThreeAxisModel, linear_machine_model
from drivesense.sim.machining import process_names, simulate_air_moves, simulate_process

__version__ = "0.1.0"

__all__ = [
    "errors", "estimate", "sim", "DriveSenseError",
    "Recording", "read_csv", "read_recording", "write_csv", "write_recording", "read_axis_file", "write_axis_file",
    "BallScrewAxis", "table1_axis", "table1_stage",
    "CurrentOnly", "RigidBody", "MEDOB", "VibrationMode", "SignalParams", "learn", "LSTM", "Hybrid",
    "FrictionMap", "build_friction_map", "Score", "score_estimate", "__version__",
]
__all__ += [
    "events", "condition", "CutConditions", "engagement_angle", "chip_thickness_from_angles", "cutting_power",
    "average_tangential_force", "force_per_depth", "TangentialFit", "CutTable", "SeeSawWarning",
    "fit_tangential_coefficients", "calibrate_from_power", "average_power", "read_cut_table",
    "FeedCuts", "FeedPowerModel", "read_feed_cuts", "fit_feed_power", "per_speed_fits",
    "SensorCalibration", "ratio_spectrum", "check_linearity", "calibrate_sensor", "deconvolution_residual",
    "WearTracker", "WearTrackerSettings", "WearReport", "track_wear", "percent_power_increase",
    "RunoutEstimate", "estimate_runout", "WearExperiment", "table1_experiments", "simulate_tool_life",
    "ElectretSensor", "simulate_shaker_pair",
]
__all__ += ["ModelBased", "LinearMotorAxis", "ThreeAxisModel", "linear_machine_model", "identify_axes",
            "run_identification", "IdentificationReport", "read_axes_file", "write_axes_file",
            "simulate_process", "simulate_air_moves", "process_names",
            "identify_controller", "ControllerIdentification", "ControllerModel", "ControllerAxis"]

# experiment data: the XML format, the archive, MTConnect ingest
from drivesense import archive  # noqa: E402
from drivesense.archive import open_archive  # noqa: E402
from drivesense.io.mtconnect import parse_devices, parse_shdr, parse_streams  # noqa: E402
from drivesense.io.mtconnect_client import MTConnectClient  # noqa: E402
from drivesense.io.mtconnect_resample import read_mtconnect  # noqa: E402
from drivesense.io.xml_format import (Experiment, read_experiment, read_xml, transform_xml,  # noqa: E402
                                      validate_xml, write_xml)

__all__ += ["archive", "open_archive", "Experiment", "write_xml", "read_xml", "read_experiment", "validate_xml",
            "transform_xml", "parse_devices", "parse_streams", "parse_shdr", "read_mtconnect", "MTConnectClient"]
