"""The live monitor: a service that watches running machines (``drivesense monitor``).

Sources (:mod:`~drivesense.monitor.sources`: replay, simulated, MQTT;
:mod:`~drivesense.monitor.controllers`: MTConnect, OPC UA) deliver chunks of
drive signals (:mod:`~drivesense.monitor.wire`); each machine's
:class:`~drivesense.monitor.machine.MachineMonitor` runs the streaming
estimators and detectors; :class:`~drivesense.monitor.service.MonitorService`
ties them to the outputs (:mod:`~drivesense.monitor.outputs`) and the dashboard
(:mod:`drivesense.monitor.web`, needing the ``monitor`` extra).
"""

from drivesense.monitor.machine import AxisPipeline, MachineMonitor
from drivesense.monitor.service import MachineSpec, MonitorService
from drivesense.monitor.mqtt import MQTTSource
from drivesense.monitor.sources import ReplaySource, SimulatedSource, Source
from drivesense.monitor.wire import Chunk, WireError, decode_chunk, encode_chunk

__all__ = ["AxisPipeline", "MachineMonitor", "MachineSpec", "MonitorService", "MQTTSource", "ReplaySource",
           "SimulatedSource", "Source", "Chunk", "WireError", "decode_chunk", "encode_chunk"]
