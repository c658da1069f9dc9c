"""The live monitor: a service that watches running machines (``drivesense monitor``).

Sources (:mod:`~drivesense.serve.sources`: replay, simulated, MQTT;
:mod:`~drivesense.serve.controllers`: MTConnect, OPC UA) deliver chunks of
drive signals (:mod:`~drivesense.serve.wire`); each machine's
:class:`~drivesense.serve.machine.MachineMonitor` runs the streaming
estimators and detectors; :class:`~drivesense.serve.service.MonitorService`
ties them to the outputs (:mod:`~drivesense.serve.outputs`) and the dashboard
(:mod:`drivesense.serve.web`, needing the ``monitor`` extra).
"""

from drivesense.serve.machine import AxisPipeline, MachineMonitor
from drivesense.serve.service import MachineSpec, MonitorService
from drivesense.serve.mqtt import MQTTSource
from drivesense.serve.sources import ReplaySource, SimulatedSource, Source
from drivesense.serve.wire import Chunk, WireError, decode_chunk, encode_chunk

__all__ = ["AxisPipeline", "MachineMonitor", "MachineSpec", "MonitorService", "MQTTSource", "ReplaySource",
           "SimulatedSource", "Source", "Chunk", "WireError", "decode_chunk", "encode_chunk"]
