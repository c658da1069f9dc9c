"""``drivesense monitor`` (the live service) and ``drivesense publish`` (an edge device's publisher)."""

from __future__ import annotations

import asyncio
import gc
import signal
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import (AssumeSiOpt, BadSamplesOpt, FsOpt, ResampleOpt, console, friendly,
                                   show_warnings, trace_reader, write_json)
from drivesense.cli.detect import (AxesOpt, AxisNameOpt, AxisOpt, ForceLimitOpt, IdleOpt, LimitsOpt, MethodOpt,
                                   ModelOpt, SpindleRpmOpt, TareOpt, TeethOpt,
                                   check_detector_options)

__all__ = ["register"]

_EXTRA = "the live monitor needs its extra: pip install 'drivesense[monitor]'"


def _need(module: str) -> None:
    import importlib.util

    from drivesense.errors import ConfigError

    if importlib.util.find_spec(module) is None:
        raise ConfigError(f"{_EXTRA} ({module} is missing)")


def _replay_config(trace: Path, read, *, axis_file, method, idle, tare, spindle_rpm, teeth, limits, force_limit,
                   baseline_revs, axis_name, axes_file, model_dir, speed):
    """The one-machine configuration of ``--replay TRACE`` (the options of ``drivesense detect``)."""
    from drivesense.errors import ConfigError
    from drivesense.events.teeth import known_teeth
    from drivesense.monitor.config import MonitorConfig, build_axis
    from drivesense.monitor.machine import MachineMonitor
    from drivesense.monitor.service import MachineSpec, machine_id_from
    from drivesense.monitor.sources import ReplaySource

    rec = read(trace, axis_name)
    if "spindle_speed" not in rec.channels and spindle_rpm is None:
        raise ConfigError("the trace has no spindle_speed column: give the spindle speed with --spindle-rpm RPM")
    known = known_teeth(rec, teeth)      # else build_axis infers it from the estimated forces, as detect does
    teeth = None if known is None else known.teeth
    spec = {"method": method, "axis_file": axis_file and str(axis_file), "axes_file": axes_file and str(axes_file),
            "model": model_dir and str(model_dir), "idle": [str(p) for p in idle or []] or None, "tare": tare,
            "limits": limits and str(limits), "force_limit": force_limit, "baseline_revs": baseline_revs}
    machine = machine_id_from(trace.stem)
    axis = build_axis(axis_name, {k: v for k, v in spec.items() if v is not None}, base=Path.cwd(), read=read,
                      where="--replay", teeth=teeth, spindle_rpm=spindle_rpm, tare_trace=rec, labels={})
    source = ReplaySource(machine, rec, speed=speed)
    return MonitorConfig([MachineSpec(machine, source, MachineMonitor(machine, [axis]))])


def _listen(http: tuple[str, int]):
    """The dashboard's socket, bound now (the monitor extra checked first): see ``serve.web.listen_socket``."""
    for module in ("fastapi", "uvicorn", "websockets"):     # websockets: uvicorn serves the live stream (/ws)
        _need(module)
    from drivesense.monitor.web import listen_socket

    return listen_socket(*http)


def _config_names_events(path: Path) -> bool:
    """Whether a config file's ``[service]`` table names an event log (False when it cannot be read here)."""
    import tomllib

    try:
        return "events" in tomllib.loads(path.read_text()).get("service", {})
    except (OSError, ValueError, AttributeError):
        return False


async def _run(service, http, stop: asyncio.Event, *, until_finished: bool, duration: Optional[float],
               sock=None) -> None:
    """Run the service (and the dashboard on `sock`) until it finishes, ``stop`` is set or `duration` ends.

    The first error of any part (the service, the HTTP server) is raised once everything has stopped, so
    that the command reports it (exit 2) instead of ending with a summary of nothing.
    """
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError):  # pragma: no cover - not the main thread / Windows
            pass
    tasks = [asyncio.create_task(service.run(stop, until_finished=until_finished))]
    if http is not None:
        from drivesense.monitor.web import serve_http

        tasks.append(asyncio.create_task(serve_http(service, http[0], http[1], stop, sock=sock)))
    if duration is not None:
        async def timer() -> None:
            try:
                await asyncio.wait_for(stop.wait(), duration)
            except asyncio.TimeoutError:
                stop.set()
        tasks.append(asyncio.create_task(timer()))
    await asyncio.wait(tasks[:1])
    stop.set()
    results = await asyncio.gather(*tasks, return_exceptions=True)
    for result in results:
        if isinstance(result, BaseException) and not isinstance(result, asyncio.CancelledError):
            raise result


def _print_event(record: dict) -> None:
    console.print(f"[bold red]{record['kind']}[/] machine {escape(record['machine'])} axis {escape(record['axis'])} "
                  f"at {record['time_s']:.4f} s (confidence {record['confidence']:.2f})", highlight=False,
                  soft_wrap=True)


def register(app: typer.Typer) -> None:
    """Add ``monitor`` and ``publish`` to the root app."""

    @app.command()
    @friendly
    def monitor(
        config: Annotated[Optional[Path], typer.Argument(help="CONFIG.toml naming the machines (see "
                                                          "docs/MONITORING.md).")] = None,
        replay: Annotated[Optional[Path], typer.Option("--replay", help="Watch one trace (CSV, .nc or .xml) played "
                                                       "as a live stream; takes the options of 'detect'.")] = None,
        demo: Annotated[bool, typer.Option("--demo", help="Watch the built-in simulated machine (a flute breaks "
                                           "in its second cut) with a dashboard on --http.")] = False,
        speed: Annotated[float, typer.Option(help="Replay rate of --replay/--demo [-]: 1 real time, 50 fifty "
                                             "times faster, 0 as fast as it goes.")] = 1.0,
        http: Annotated[Optional[str], typer.Option(help="Serve the dashboard and API on HOST:PORT "
                                                    "(--demo: 127.0.0.1:8765).")] = None,
        events: Annotated[Optional[Path], typer.Option("--events", help="Append events to this JSONL log "
                                                       "(every event fsync-ed); with --worker, the folder the "
                                                       "workers share (a log per machine).")] = None,
        worker: Annotated[Optional[str], typer.Option("--worker", help="Share the config's machines (mqtt "
                                                      "sources) with other monitor processes as worker NAME; "
                                                      "needs --events FOLDER.")] = None,
        fleet: Annotated[str, typer.Option("--fleet", help="Name of the fleet of workers to join with "
                                           "--worker.")] = "main",
        hold: Annotated[float, typer.Option("--hold", help="With --worker: signal kept for the next worker to "
                                            "re-prime its estimators on [s] (raise it for estimators with a "
                                            "long memory).")] = 1.0,
        archive: Annotated[Optional[str], typer.Option(help="Archive events and their signal segments here "
                                                       "(SQLite file or PostgreSQL DSN).")] = None,
        mqtt: Annotated[Optional[str], typer.Option("--mqtt", help="Publish alarms to this broker "
                                                    "(mqtt://HOST[:PORT]).")] = None,
        webhook: Annotated[Optional[str], typer.Option(help="POST each event as JSON to this URL.")] = None,
        duration: Annotated[Optional[float], typer.Option(help="Stop after this many seconds [s].")] = None,
        json_path: Annotated[Optional[Path], typer.Option("--json", help="Write a summary JSON here at the "
                                                          "end.")] = None,
        axis_file: AxisOpt = None,
        method: MethodOpt = "vibration",
        idle: IdleOpt = None,
        tare: TareOpt = None,
        spindle_rpm: SpindleRpmOpt = None,
        teeth: TeethOpt = None,
        limits: LimitsOpt = None,
        force_limit: ForceLimitOpt = None,
        baseline_revs: Annotated[Optional[int], typer.Option("--baseline-revs", help="Revolutions of each cut "
                                                             "the breakage detector learns over.")] = None,
        axis_name: AxisNameOpt = "x",
        axes_file: AxesOpt = None,
        model_dir: ModelOpt = None,
        assume_si: AssumeSiOpt = False,
        fs: FsOpt = None,
        resample: ResampleOpt = None,
        bad_samples: BadSamplesOpt = None,
    ) -> None:
        """Watch machines live: estimate forces, detect events, raise alarms, serve a dashboard."""
        from drivesense.errors import ConfigError
        from drivesense.monitor.config import MonitorConfig, load_config, parse_http
        from drivesense.monitor.sources import check_speed

        given = [name for name, v in (("CONFIG", config), ("--replay", replay), ("--demo", demo)) if v]
        if len(given) != 1:
            raise ConfigError("give one of CONFIG.toml, --replay TRACE or --demo"
                              + (f" (got {', '.join(given)})" if given else ""))
        if duration is not None and not duration > 0:
            raise ConfigError(f"--duration must be > 0 [s], got {duration!r}")
        check_speed(speed, "--speed")
        check_detector_options(spindle_rpm=spindle_rpm, teeth=teeth, baseline_revs=baseline_revs,
                               force_limit=force_limit)
        if worker is None and fleet != "main":
            raise ConfigError(f"--fleet {fleet} names the fleet a worker joins: give --worker NAME too")
        if worker is not None and events is None and not (config is not None and _config_names_events(config)):
            raise ConfigError("--worker needs --events FOLDER (or [service] events): the folder the workers share, "
                              "with each machine's event log and claim")
        sock, address = None, None
        if http is not None or demo:                 # bound before any work: a port in use is an error at once
            address = parse_http(http or "127.0.0.1:8765")
            sock = _listen(address)
        if config is not None:
            cfg = load_config(config, read=trace_reader(fs, resample, assume_si, bad_samples))
        elif replay is not None:
            with show_warnings():                    # e.g. "breakage detection is off": one warning line each
                cfg = _replay_config(replay, trace_reader(fs, resample, assume_si, bad_samples),
                                     axis_file=axis_file, method=method, idle=idle, tare=tare,
                                     spindle_rpm=spindle_rpm, teeth=teeth, limits=limits, force_limit=force_limit,
                                     baseline_revs=baseline_revs, axis_name=axis_name, axes_file=axes_file,
                                     model_dir=model_dir, speed=speed)
        else:
            from drivesense.monitor.demo import demo_machine

            console.print("simulating the demo machine (ball-screw stage, 2-flute end mill, 6000 min^-1) ...")
            cfg = MonitorConfig([demo_machine(speed=speed)])
        if sock is None and cfg.http is not None:    # the config file's [service] http
            address = cfg.http
            sock = _listen(address)
        if sock is not None:
            cfg.http = (address[0], sock.getsockname()[1])     # (port 0: the one the system chose)
        for attr, value in (("events", events), ("archive", archive), ("mqtt", mqtt), ("webhook", webhook)):
            if value is not None:
                setattr(cfg, attr, value)
        if worker is not None:
            from drivesense.monitor.fleet import FleetWorker

            cfg.fleet = FleetWorker(worker, cfg.events, group=fleet, hold_s=hold)
        if cfg.mqtt is not None or any(m.source.kind == "mqtt" for m in cfg.machines):
            _need("paho")
        service = cfg.service()
        service.listeners.append(_print_event)
        names = ", ".join(f"{m.id} ({m.source.kind})" for m in cfg.machines)
        console.print(f"monitoring {names}", highlight=False, markup=False, soft_wrap=True)
        if cfg.fleet is not None:
            console.print(f"worker '{worker}' of fleet '{fleet}': machines shared through {cfg.fleet.url}, event "
                          f"logs in {cfg.events}", markup=False, soft_wrap=True)
        if service.log.recovered:
            console.print(f"event log {cfg.events}: {service.log.recovered} event(s) from before, kept",
                          markup=False, soft_wrap=True)
        if cfg.http is not None:
            console.print(f"dashboard: http://{cfg.http[0]}:{cfg.http[1]}/  (Ctrl-C stops)", markup=False,
                          soft_wrap=True)
        finite = all(m.source.kind == "replay" for m in cfg.machines) and cfg.http is None
        # the loop thread computes while paho's network threads wait for the GIL to hand over messages:
        # a 1 ms switch interval (Python's default is 5 ms) keeps that hand-over off the alarm latency
        sys.setswitchinterval(1e-3)
        # everything imported and built so far lives as long as the service: frozen out of the collector's
        # full passes, which would otherwise walk it (tens of ms on the loop thread) every few seconds
        gc.collect()
        gc.freeze()
        began = time.time()
        asyncio.run(_run(service, cfg.http, asyncio.Event(), until_finished=finite, duration=duration, sock=sock))
        wall = time.time() - began
        table = Table(title="monitor summary")
        for col in ("machine", "samples", "chunks", "rejected", "gaps", "busy [s]", "events"):
            table.add_column(escape(col))
        per_machine = {}
        for mid in service.machines:
            st = service.machine_status(mid)
            n_ev = sum(1 for r in service.log.recent if r["machine"] == mid)     # (a fleet worker: its own)
            per_machine[mid] = {k: st[k] for k in ("samples", "chunks", "rejected", "gaps", "publisher_restarts",
                                                   "busy_s", "last_error")}
            per_machine[mid]["events"] = n_ev
            table.add_row(escape(mid), str(st["samples"]), str(st["chunks"]), str(st["rejected"]), str(st["gaps"]),
                          f"{st['busy_s']:.2f}", str(n_ev))
        console.print(table)
        write_json(json_path, {"wall_s": wall, "machines": per_machine, "events": service.events(0),
                               "event_log": str(cfg.events) if cfg.events else None})

    @app.command()
    @friendly
    def publish(
        trace: Annotated[Path, typer.Argument(help="CSV (name [unit] header), .nc or .xml trace to publish.")],
        mqtt: Annotated[str, typer.Option("--mqtt", help="Broker URL, mqtt://HOST[:PORT].")],
        topic: Annotated[Optional[str], typer.Option(help="Topic (default MACHINE/drive).")] = None,
        machine: Annotated[Optional[str], typer.Option(help="Machine id in the messages (default: the file "
                                                       "name).")] = None,
        speed: Annotated[float, typer.Option(help="Publishing rate [-]: 1 real time, 0 as fast as the broker "
                                             "takes it.")] = 1.0,
        chunk_ms: Annotated[float, typer.Option("--chunk-ms", help="Samples per message [ms].")] = 50.0,
        repeat: Annotated[int, typer.Option(help="Times the trace is sent (time and sequence continue).")] = 1,
        axis_name: AxisNameOpt = "x",
        assume_si: AssumeSiOpt = False,
        fs: FsOpt = None,
        resample: ResampleOpt = None,
        bad_samples: BadSamplesOpt = None,
    ) -> None:
        """Publish a trace to an MQTT broker in drivesense's chunk format (an edge device, or a test feed)."""
        from drivesense.errors import ConfigError
        from drivesense.monitor.publisher import publish_recording
        from drivesense.monitor.service import check_machine_id, machine_id_from
        from drivesense.monitor.sources import check_speed

        _need("paho")
        if not chunk_ms > 0:
            raise ConfigError(f"--chunk-ms must be > 0, got {chunk_ms!r}")
        check_speed(speed, "--speed")
        mid = check_machine_id(machine, "--machine") if machine is not None else machine_id_from(trace.stem)
        rec = trace_reader(fs, resample, assume_si, bad_samples)(trace, axis_name)
        report = publish_recording(rec, mqtt, machine=mid, topic=topic, speed=speed, chunk_s=chunk_ms * 1e-3,
                                   repeat=repeat)
        console.print(f"published {report['chunks']} chunk(s), {report['samples']} samples of machine {mid} to "
                      f"{mqtt} topic {report['topic']} (session {report['session']}) in {report['wall_s']:.2f} s",
                      markup=False, soft_wrap=True)
