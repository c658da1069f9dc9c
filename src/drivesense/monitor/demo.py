"""The demo machine: the simulator as a live source, with a fitted estimator and the default detectors.

``drivesense monitor --demo`` runs it; the tests and ``drivesense bench monitor`` build machines from it.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

from drivesense.monitor.machine import AxisPipeline, MachineMonitor
from drivesense.monitor.service import MachineSpec
from drivesense.monitor.sources import SimulatedSource, demo_condition

__all__ = ["demo_estimator", "demo_monitor", "demo_machine", "DEMO_TEETH", "DEMO_FORCE_LIMIT_N"]

#: Flutes of the demo tool.
DEMO_TEETH = 2
#: Collision/overload limit of the demo axis [N] (the clean cut peaks near 30 N).
DEMO_FORCE_LIMIT_N = 400.0


@lru_cache(maxsize=1)
def _fitted():
    from drivesense.estimate import make
    from drivesense.machine.presets import table1_axis, table1_signal
    from drivesense.sim.scenarios import ScenarioSettings, simulate_idle

    est = make("vibration", axis=table1_axis(), signal=table1_signal())
    est.fit(simulate_idle(demo_condition(), replace(ScenarioSettings(), duration=6.0), seed=5000))
    return est


def demo_estimator():
    """The ``vibration`` estimator of the ball-screw stage with a friction map from 3 simulated idle runs."""
    return _fitted()


def demo_monitor(machine: str = "demo") -> MachineMonitor:
    """A :class:`MachineMonitor` of the demo axis X: breakage, chatter and overload detectors.

    Parameters
    ----------
    machine : str
        Machine id.
    """
    from drivesense.events.pipeline import default_detectors, estimate_limits

    est = demo_estimator()
    return MachineMonitor(machine, [AxisPipeline("x", est, default_detectors(
        "x", teeth=DEMO_TEETH, force_limit_n=DEMO_FORCE_LIMIT_N, **estimate_limits(est)))])


def demo_machine(machine: str = "demo", *, seed: int = 1, speed: float = 1.0, cut_s: float = 4.0,
                 event_share: float = 0.3) -> MachineSpec:
    """The simulated machine of ``drivesense monitor --demo``.

    Parameters
    ----------
    machine : str
        Machine id.
    seed : int
        Seed of its cuts and events.
    speed : float
        Replay rate [-] (1: real time).
    cut_s : float
        Length of each cut [s].
    event_share : float
        Share of cuts (after the second, which always breaks a flute) with an event [-].
    """
    return MachineSpec(machine, SimulatedSource(machine, seed=seed, speed=speed, cut_s=cut_s,
                                                event_share=event_share), demo_monitor(machine))
