"""What the live benches share: waiting, child processes, MQTT clients, monitor configs of the demo axis.

Used by ``drivesense bench monitor`` (:mod:`drivesense.bench.monitor`) and the failover part of ``drivesense
bench fleet`` (:mod:`drivesense.bench.failover`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from drivesense.io import write_recording
from drivesense.monitor.mqtt import parse_mqtt_url
from drivesense.monitor.sources import demo_condition
from drivesense.sim.scenarios import ScenarioSettings, simulate_idle

__all__ = ["CLI", "read_log_lines", "wait_until", "run_child", "end_process", "mqtt_client", "close_quietly",
           "subscribe_alarms", "setup_demo_axis", "write_config"]

#: ``python -c CLI ARGS...`` runs ``drivesense ARGS...`` with this interpreter.
CLI = "from drivesense.cli import main; main()"


def wait_until(cond, timeout: float, step: float = 0.1) -> bool:
    """Whether ``cond()`` came true within ``timeout``, asked every ``step``.

    Parameters
    ----------
    cond : callable
        Returns true once the wait is over.
    timeout : float
        Longest wait [s].
    step : float
        Time between two tries [s].
    """
    deadline = time.time() + timeout
    while time.time() < deadline and not cond():
        time.sleep(step)
    return bool(cond())


def run_child(name: str, args: dict, work: Path, core: int | None = None, timeout: float | None = None):
    """:mod:`drivesense.bench.monitor`'s ``_NAME_child`` in a subprocess: the Popen, or with a ``timeout`` [s]
    its JSON when it ends.

    Parameters
    ----------
    name : str
        The child function's name between ``_`` and ``_child``.
    args : dict
        Its keyword arguments (JSON); ``out`` is added.
    work : Path
        Folder of its JSON output and log.
    core : int, optional
        Pin it to this core.
    timeout : float, optional
        Wait this long [s] for its JSON (None: return the Popen).
    """
    code = f"import json, sys; from drivesense.bench import monitor as m; m._{name}_child(**json.loads(sys.argv[1]))"
    args = {**args, "out": str(work / f"{name}.json"), **({"core": core} if core is not None else {})}
    with open(work / f"{name}.log", "wb") as log:
        proc = subprocess.Popen([sys.executable, "-c", code, json.dumps(args)], stdout=log, stderr=log)
    if timeout is None:
        return proc
    end_process(proc, timeout)
    if proc.returncode != 0 or not (work / f"{name}.json").exists():
        raise RuntimeError(f"{name} subprocess failed (exit {proc.returncode}): "
                           f"{(work / f'{name}.log').read_text(errors='replace')[-800:]}")
    return json.loads((work / f"{name}.json").read_text())


def end_process(proc, timeout: float = 0.0) -> None:
    """Wait ``timeout`` [s] for a subprocess, then kill it.

    Parameters
    ----------
    proc : subprocess.Popen
        The subprocess.
    timeout : float
        Longest wait [s].
    """
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def mqtt_client(url: str, name: str, callbacks: dict | None = None, clean_session: bool = True):
    """A connected paho client, its network thread started.

    Parameters
    ----------
    url : str
        ``mqtt://HOST[:PORT]``.
    name : str
        Part of its client id (with this process's id).
    callbacks : dict, optional
        ``on_connect``, ``on_message``... set on the client.
    clean_session : bool
        False: a persistent session.
    """
    import paho.mqtt.client as mqtt

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-{name}-{os.getpid()}",
                         clean_session=clean_session)
    client.reconnect_delay_set(0.1, 1.0)
    client.max_inflight_messages_set(1000)
    for key, fn in (callbacks or {}).items():
        setattr(client, key, fn)
    client.connect_async(*parse_mqtt_url(url), keepalive=10)          # retried until the broker answers
    client.loop_start()
    wait_until(client.is_connected, 10.0, 0.02)
    return client


def close_quietly(x) -> None:
    """Stop a service, end a subprocess, disconnect an MQTT client (None: nothing).

    Parameters
    ----------
    x : object
        A service, subprocess, paho client or None.
    """
    if hasattr(x, "proc") and hasattr(x, "stop"):         # bench.monitor's service in a subprocess
        x.stop()
    elif isinstance(x, subprocess.Popen):
        end_process(x)
    elif x is not None:
        x.disconnect()
        x.loop_stop()


def subscribe_alarms(url: str) -> tuple:
    """A subscriber on ``+/alarm`` (persistent session), its list of (receive time [s since the epoch], record).

    Parameters
    ----------
    url : str
        ``mqtt://HOST[:PORT]``.
    """
    got: list = []
    client = mqtt_client(url, "alarms", {"on_connect": lambda c, u, f, r, p=None: c.subscribe("+/alarm", qos=1),
                                   "on_message": lambda c, u, m: got.append((time.time(), json.loads(m.payload)))},
                   False)
    time.sleep(0.5)
    return client, got, time.time()


def setup_demo_axis(work: Path) -> None:
    """AXIS.toml (``drivesense axis --out``) and the demo's simulated idle runs ``idle*.nc`` in ``work``.

    Parameters
    ----------
    work : Path
        The folder (it exists).
    """
    subprocess.run([sys.executable, "-c", CLI, "axis", "--out", str(work / "AXIS.toml")], check=True,
                   stdout=subprocess.DEVNULL)
    for i, rec in enumerate(simulate_idle(demo_condition(), replace(ScenarioSettings(), duration=6.0), seed=5000)):
        write_recording(rec, work / f"idle{i}.nc")


def write_config(path: Path, machines: dict, service: dict) -> Path:
    """A monitor config: ``machines`` id -> source table, each the demo axis X (idle runs next to it).

    Parameters
    ----------
    path : Path
        The TOML file to write (the idle runs lie next to it).
    machines : dict
        Machine id -> source table.
    service : dict
        The ``[service]`` table.
    """
    value, idle = json.dumps, json.dumps(sorted(p.name for p in path.parent.glob("idle*.nc")))   # JSON is TOML here
    lines = ["[service]", *(f"{k} = {value(v)}" for k, v in service.items()), ""]
    for mid, src in machines.items():
        lines += ["[[machine]]", f"id = {value(mid)}", "teeth = 2",
                  "source = { " + ", ".join(f"{k} = {value(v)}" for k, v in src.items()) + " }", "[[machine.axis]]",
                  'name = "x"', 'method = "vibration"', 'axis_file = "AXIS.toml"', f"idle = {idle}",
                  "force_limit = 400.0", ""]
    path.write_text("\n".join(lines))
    return path


def read_log_lines(path: Path) -> list[dict]:
    """Every line of a JSONL event log as a record (events, acknowledgements, notes), a last line torn by a kill
    left out; no file: none.

    Parameters
    ----------
    path : Path
        The log.
    """
    text = path.read_bytes() if path.exists() else b""
    return [json.loads(x) for x in text[:text.rfind(b"\n") + 1].splitlines()]
