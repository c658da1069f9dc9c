"""Closed-loop servo simulation producing drive-signal Recordings with the true force."""

from drivesense.machine.vmc import vmc_physics
from drivesense.sim.nc_programs import nc_programs
from drivesense.sim.scenarios import (CutCondition, ScenarioSettings, condition_by_name, paper_conditions,
                                      scenario_names, simulate_cut, simulate_idle)
from drivesense.sim.servo import ServoConfig, run_servo
from drivesense.sim.vmc import VMCSettings, simulate_nc_program

__all__ = ["CutCondition", "ScenarioSettings", "paper_conditions", "scenario_names", "condition_by_name",
           "simulate_cut", "simulate_idle", "ServoConfig", "run_servo", "vmc_physics", "nc_programs",
           "simulate_nc_program", "VMCSettings"]
