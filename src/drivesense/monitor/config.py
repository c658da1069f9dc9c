"""The monitor's configuration: ``drivesense monitor CONFIG.toml``.

::

    [service]
    http = "127.0.0.1:8765"            # dashboard and API (optional)
    events = "events.jsonl"            # append-only event log (every event fsync-ed)
    archive = "monitor.sqlite"         # events + signal segments (SQLite file or PostgreSQL DSN; optional)
    mqtt = "mqtt://127.0.0.1:1883"     # alarms on {machine}/alarm, stop requests on {machine}/stop (optional)
    webhook = "https://example.com/hook"   # each event POSTed as JSON (optional)
    token_env = "DRIVESENSE_TOKEN"     # or token = "...": acknowledging and changing limits need it

    [[machine]]
    id = "vmc1"
    teeth = 2                          # flutes (breakage, chipping)
    spindle_rpm = 6000                 # when the signals carry no spindle_speed
    source = { kind = "mqtt", url = "mqtt://127.0.0.1:1883", topic = "vmc1/drive" }

    [[machine.axis]]
    name = "x"
    method = "vibration"
    axis_file = "x_axis.toml"          # or axes_file (linear motors), model (lstm, hybrid)
    idle = ["idle_1.csv", "idle_2.csv"]    # friction map; or tare_trace = "cut.csv" + tare = "0:0.5"
    detectors = ["breakage", "chatter", "overload"]
    force_limit = 300.0                # [N]
    limits = "LIMITS.json"             # teach-in bands (drivesense teach)

Sources: ``replay`` (``path``, ``speed``, ``loop``, ``chunk_s``), ``simulated``
(``seed``, ``speed``, ``cut_s``, ``event_share``), ``mqtt`` (``url``,
``topic``), ``mtconnect`` and ``opcua`` (:mod:`drivesense.monitor.controllers`), ``shdr`` (an MTConnect
adapter read directly: :mod:`drivesense.monitor.shdr`).
Relative paths are read from the config file's folder.  Every error names
the machine, the axis and the key.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivesense.errors import ConfigError
from drivesense.monitor.machine import AxisPipeline, MachineMonitor
from drivesense.monitor.service import MachineSpec, MonitorService, check_machine_id
from drivesense.monitor.mqtt import MQTTSource
from drivesense.monitor.sources import ReplaySource, SimulatedSource, Source

__all__ = ["MonitorConfig", "load_config", "build_axis", "fit_or_tare", "parse_http", "SOURCE_KINDS"]

#: Source kinds a config may name.
SOURCE_KINDS = ("replay", "simulated", "mqtt", "mtconnect", "shdr", "opcua")
_DETECTORS = ("breakage", "chatter", "overload", "teach-in")
#: Keys each table may hold (a typo is refused, not ignored).
_KEYS = {"machine": {"id", "teeth", "spindle_rpm", "source", "axis", "history_s"},
         "axis": {"name", "method", "axis_file", "axes_file", "model", "idle", "tare", "tare_trace", "detectors",
                  "force_limit", "limits", "baseline_revs"},
         "replay": {"kind", "path", "speed", "loop", "chunk_s", "axis_name"},
         "simulated": {"kind", "seed", "speed", "cut_s", "event_share"},
         "mqtt": {"kind", "url", "topic"},
         "service": {"http", "events", "archive", "mqtt", "webhook", "token", "token_env", "alarm_prefix"}}


#: What messages call the method options in a config file.
_CONFIG_LABELS = {"--method": "method", "--axis": "axis_file", "--axes": "axes_file", "--model": "model"}


#: How :func:`fit_or_tare`'s messages name the method, the idle runs and the tare window.
_CLI_NAMES = {"method": "--method", "idle": "--idle runs", "tare": "--tare", "window": "--tare START:END"}
_CONFIG_NAMES = {"method": "method", "idle": "'idle' runs", "tare": "'tare'", "window": "'tare' (with 'tare_trace')"}


def fit_or_tare(est: Any, method: str, *, idle_runs: Callable | None, tare: tuple | None, trace: Any,
                names: dict = _CLI_NAMES) -> None:
    """Calibrate a ball-screw estimator's friction from idle runs or a tare window; refuse what cannot work.

    Parameters
    ----------
    est : ForceEstimator
        The estimator (``est.drive`` says whether it is a ball-screw method).
    method : str
        Its name (for messages).
    idle_runs : callable, optional
        Returns the idle (air-cut) runs, read only when they are used.
    tare : tuple of float, optional
        START, END [s] of a window where the axis stands.
    trace : Recording, optional
        The trace the tare window is cut from.
    names : dict
        How messages name ``method``, ``idle``, ``tare`` and ``window`` (the CLI's options by default).

    Raises
    ------
    ConfigError
        Both or neither for a ball-screw method; either for another method; a tare without a trace.
    """
    if est.drive != "ballscrew":
        if idle_runs is not None or tare is not None:
            raise ConfigError(f"{names['method']} {method} takes no {names['idle'].split()[0]}/{names['tare']} "
                              f"(it reads a 3-axis NC trace)")
        return
    if idle_runs is not None and tare is not None:
        raise ConfigError(f"give either {names['idle']} or {names['tare']}, not both")
    if idle_runs is not None:
        est.fit(idle_runs())
    elif tare is not None:
        if trace is None:
            raise ConfigError(f"{names['tare']} needs a trace of the standing axis ('tare_trace')")
        est.tare(trace, *tare)
    else:
        raise ConfigError(f"{names['method']} {method} needs {names['idle']} (friction map) or {names['window']}: "
                          f"without them the friction would be taken for process force")


def _known(table: dict, which: str, where: str) -> None:
    unknown = sorted(set(table) - _KEYS[which])
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(_KEYS[which]))})")


@dataclass
class MonitorConfig:
    """A loaded configuration: the service's settings and its machines.

    Attributes
    ----------
    machines : list of MachineSpec
        The machines, their sources and pipelines.
    http : tuple or None
        ``(host, port)`` of the dashboard, or None.
    events : Path or None
        Event log.
    archive : str or None
        Archive location.
    mqtt : str or None
        Alarm broker.
    webhook : str or None
        Webhook URL.
    token : str or None
        Write token.
    alarm_prefix : str
        Topic prefix of the alarms.
    fleet : FleetWorker or None
        Share the machines with other workers (``--worker``; see :mod:`drivesense.monitor.fleet`).
    """

    machines: list
    http: tuple | None = None
    events: Path | None = None
    archive: str | None = None
    mqtt: str | None = None
    webhook: str | None = None
    token: str | None = field(default=None, repr=False)
    alarm_prefix: str = ""
    fleet: Any = None

    def service(self) -> MonitorService:
        """The :class:`MonitorService` of this configuration."""
        return MonitorService(self.machines, events_path=self.events, archive=self.archive, alarm_url=self.mqtt,
                              alarm_prefix=self.alarm_prefix, webhook=self.webhook, token=self.token,
                              fleet=self.fleet)


def parse_http(text: str, what: str = "--http") -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port).

    Parameters
    ----------
    text : str
        The address.
    what : str
        Option or key named in errors.
    """
    host, sep, port = str(text).rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"{what} must be HOST:PORT (e.g. 127.0.0.1:8765), got {text!r}")
    return host.strip("[]"), int(port)


def _get(table: dict, key: str, kinds, where: str, default: Any = None, *, check: Callable | None = None,
         need: str = "") -> Any:
    value = table.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise ConfigError(f"{where}: '{key}' must be {need or kinds}, got {value!r}")
    if check is not None and not check(value):
        raise ConfigError(f"{where}: '{key}' must be {need}, got {value!r}")
    return value


def _number(table: dict, key: str, where: str, default: float | None = None, *, positive: bool = True):
    return _get(table, key, (int, float), where, default, need="a positive number" if positive else "a number",
                check=lambda v: math.isfinite(v) and (v > 0 or not positive))


def _path(base: Path, value: Any, where: str, key: str) -> Path:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: '{key}' must be a file path, got {value!r}")
    p = Path(value).expanduser()
    p = p if p.is_absolute() else base / p
    if not p.exists():
        raise ConfigError(f"{where}: '{key}' file {p} does not exist")
    return p


def build_axis(name: str, spec: dict, *, base: Path, read: Callable, where: str, teeth: int | None,
               spindle_rpm: float | None, tare_trace: Any = None, labels: dict | None = None) -> AxisPipeline:
    """One axis's fitted estimator and detectors from its config table (or the CLI's options).

    Parameters
    ----------
    name : str
        Axis letter.
    spec : dict
        ``method``, ``axis_file`` / ``axes_file`` / ``model``, ``idle`` or ``tare`` (+ ``tare_trace``),
        ``detectors``, ``force_limit``, ``limits``, ``baseline_revs``.
    base : Path
        Folder relative paths are read from.
    read : callable
        ``read(path, axis_name)`` -> Recording.
    where : str
        Prefix of error messages (``machine 'vmc1' axis 'x'``).
    teeth : int or None
        Flutes of the tool (``--replay`` without it: read from the trace's estimated forces, see
        :func:`drivesense.events.teeth.resolve_teeth`; a warning says when breakage stays off).
    spindle_rpm : float or None
        Fixed spindle speed [min^-1].
    tare_trace : Recording, optional
        Trace the tare window is cut from when ``tare_trace`` is not in `spec` (``--replay``).
    labels : dict, optional
        What messages call the method and its files (default: the config's keys; ``{}``: the CLI's options).
    """
    from drivesense.estimate.registry import make_from_files
    from drivesense.io import read_json_file
    from drivesense.events import TeachLimits
    from drivesense.events.pipeline import default_detectors, estimate_limits

    cli = labels is not None and not labels     # the CLI's options (--replay), checked by the command already
    method = _get(spec, "method", str, where, "vibration", need="a method name")
    files = {k: (_path(base, spec[k], where, k) if spec.get(k) is not None else None)
             for k in ("axis_file", "axes_file", "model")}
    try:
        est = make_from_files(method, axis_file=files["axis_file"], axes_file=files["axes_file"],
                              model_dir=files["model"], axis_name=name,
                              labels=_CONFIG_LABELS if labels is None else labels)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    idle = spec.get("idle")
    tare = _get(spec, "tare", str, where, need="START:END [s]")
    window = None
    if tare:
        start, _, end = tare.partition(":")
        try:
            window = (float(start), float(end))
        except ValueError:
            raise ConfigError(f"{where}: 'tare' must be START:END [s], got {tare!r}") from None
        if spec.get("tare_trace"):
            tare_trace = read(_path(base, spec["tare_trace"], where, "tare_trace"), name)
    idle = [idle] if isinstance(idle, str) else idle
    runs = (lambda: [read(_path(base, p, where, "idle"), name) for p in idle]) if idle else None
    try:
        fit_or_tare(est, method, idle_runs=runs, tare=window, trace=tare_trace,
                    names=_CONFIG_NAMES if labels is None else _CLI_NAMES)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    kinds = _get(spec, "detectors", list, where, list(_DETECTORS), need=f"a list of {', '.join(_DETECTORS)}")
    bad = [k for k in kinds if k not in _DETECTORS]
    if bad:
        raise ConfigError(f"{where}: unknown detector(s) {', '.join(map(str, bad))} in 'detectors' "
                          f"(known: {', '.join(_DETECTORS)})")
    limits = spec.get("limits")
    taught = None if limits is None else TeachLimits.from_json(read_json_file(_path(base, limits, where, "limits"),
                                                                              "limits file"))
    force_limit = _number(spec, "force_limit", where)
    baseline = _get(spec, "baseline_revs", int, where, need="an integer >= 3", check=lambda v: v >= 3)
    bounds = estimate_limits(est)
    if cli and teeth is None and tare_trace is not None and "breakage" in kinds:
        teeth = _replay_teeth(tare_trace, est, spindle_rpm, bounds["band_hz"])
    detectors = default_detectors(name, teeth=teeth, spindle_rpm=spindle_rpm, limits=taught,
                                  force_limit_n=force_limit, kinds=kinds, baseline_revs=baseline, **bounds)
    if not detectors:
        raise ConfigError(f"{where}: no detector to run: give 'teeth' for breakage, 'force_limit' or 'limits' for "
                          f"overload")
    return AxisPipeline(name, est, detectors)


def _replay_teeth(trace: Any, est: Any, spindle_rpm: float | None, band: float | None) -> int | None:
    """``--replay`` without ``--teeth`` or a tool in the trace: the count from the trace's estimated forces
    (:func:`~drivesense.events.teeth.resolve_teeth`); a ``UserWarning`` says breakage is off when it stays
    unknown."""
    import warnings

    from drivesense.events.pipeline import detector_inputs
    from drivesense.events.teeth import resolve_teeth

    choice = resolve_teeth(trace, None, forces=detector_inputs(trace, est.estimate(trace)), spindle_rpm=spindle_rpm,
                           band_hz=band)
    if choice.teeth is None:
        warnings.warn(choice.note, UserWarning, stacklevel=2)
    return choice.teeth


def _source(machine: str, spec: Any, base: Path, read: Callable, where: str) -> Source:
    if not isinstance(spec, dict) or not isinstance(spec.get("kind"), str):
        raise ConfigError(f"{where}: 'source' must be a table with a 'kind' ({', '.join(SOURCE_KINDS)})")
    kind = spec["kind"]
    where = f"{where} source"
    if kind in _KEYS:
        _known(spec, kind, where)
    if kind == "replay":
        rec = read(_path(base, spec.get("path"), where, "path"), spec.get("axis_name", "x"))
        return ReplaySource(machine, rec, speed=_number(spec, "speed", where, 1.0, positive=False),
                            chunk_s=_number(spec, "chunk_s", where, 0.05),
                            loop=_get(spec, "loop", int, where, 1, need="an integer >= 1", check=lambda v: v >= 1))
    if kind == "simulated":
        return SimulatedSource(machine, seed=_get(spec, "seed", int, where, 1, need="an integer"),
                               speed=_number(spec, "speed", where, 1.0, positive=False),
                               cut_s=_number(spec, "cut_s", where, 4.0),
                               event_share=_number(spec, "event_share", where, 0.3, positive=False))
    if kind == "mqtt":
        return MQTTSource(machine, _get(spec, "url", str, where, need="mqtt://HOST[:PORT]") or "",
                          _get(spec, "topic", str, where, need="a topic"))
    if kind in ("mtconnect", "shdr", "opcua"):
        from drivesense.monitor import controllers, shdr

        options = {k: v for k, v in spec.items() if k != "kind"}
        cls = {"mtconnect": controllers.MTConnectSource, "shdr": shdr.SHDRSource, "opcua": controllers.OPCUASource}[kind]
        try:
            return cls(machine, **options)
        except TypeError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    raise ConfigError(f"{where}: unknown kind {kind!r} (known: {', '.join(SOURCE_KINDS)})")


def _machine(spec: Any, base: Path, read: Callable) -> MachineSpec:
    if not isinstance(spec, dict) or not isinstance(spec.get("id"), str) or not spec["id"]:
        raise ConfigError("every [[machine]] needs an 'id' (a string)")
    mid = check_machine_id(spec["id"], "[[machine]] id")
    where = f"machine '{mid}'"
    _known(spec, "machine", where)
    teeth = _get(spec, "teeth", int, where, need="an integer >= 1", check=lambda v: v >= 1)
    rpm = _number(spec, "spindle_rpm", where)
    source = _source(mid, spec.get("source"), base, read, where)
    if isinstance(source, SimulatedSource) and not spec.get("axis"):
        from drivesense.monitor.demo import demo_monitor

        return MachineSpec(mid, source, demo_monitor(mid))
    axes = spec.get("axis")
    if not isinstance(axes, list) or not axes:
        raise ConfigError(f"{where}: name at least one [[machine.axis]] (name, method, axis_file, idle or tare)")
    pipelines = []
    for a in axes:
        name = a.get("name") if isinstance(a, dict) else None
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{where}: every [[machine.axis]] needs a 'name' (the axis letter)")
        _known(a, "axis", f"{where} axis '{name}'")
        pipelines.append(build_axis(name, a, base=base, read=read, where=f"{where} axis '{name}'", teeth=teeth,
                                    spindle_rpm=rpm))
    history = _number(spec, "history_s", where, 10.0)
    return MachineSpec(mid, source, MachineMonitor(mid, pipelines, history_s=history))


def load_config(path: str | Path, *, read: Callable | None = None,
                only: Sequence[str] | None = None) -> MonitorConfig:
    """Read a monitor configuration (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The TOML file.
    read : callable, optional
        ``read(path, axis_name)`` -> Recording for traces (default :func:`drivesense.io.read_recording`).
    only : sequence of str, optional
        Build only these machine ids.

    Raises
    ------
    ConfigError
        Naming the file, the machine, the axis and the key that is wrong.
    """
    from drivesense.io import read_recording

    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    read = read or (lambda p, axis: read_recording(p, axis=axis) if Path(p).suffix.lower() == ".csv"
                    else read_recording(p))
    base = path.parent
    svc = doc.get("service", {})
    if not isinstance(svc, dict):
        raise ConfigError(f"{path}: [service] must be a table")
    where = f"{path} [service]"
    _known(svc, "service", where)
    token = _get(svc, "token", str, where, need="a string")
    env = _get(svc, "token_env", str, where, need="an environment variable name")
    if env:
        token = os.environ.get(env) or token
        if not token:
            raise ConfigError(f"{where}: 'token_env' names {env}, which is not set")
    http = parse_http(svc["http"], f"{where} 'http'") if svc.get("http") else None
    events = svc.get("events")
    events = None if events is None else (Path(events) if Path(events).is_absolute() else base / events)
    archive = svc.get("archive")
    if isinstance(archive, str) and "://" not in archive and "=" not in archive and not Path(archive).is_absolute():
        archive = str(base / archive)
    machines = doc.get("machine")
    if not isinstance(machines, list) or not machines:
        raise ConfigError(f"{path}: no [[machine]] table: name at least one machine to monitor")
    try:
        specs = [_machine(m, base, read) for m in machines if only is None or m.get("id") in only]
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return MonitorConfig(specs, http=http, events=events, archive=archive,
                         mqtt=_get(svc, "mqtt", str, where, need="mqtt://HOST[:PORT]"),
                         webhook=_get(svc, "webhook", str, where, need="a URL"), token=token,
                         alarm_prefix=_get(svc, "alarm_prefix", str, where, "", need="a topic prefix"))
