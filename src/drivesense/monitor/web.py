"""The live monitor's dashboard and HTTP API (FastAPI + uvicorn, the ``monitor`` extra).

::

    app = create_app(service)                              # an ASGI app over a MonitorService
    await asyncio.gather(service.run(stop), serve_http(service, "127.0.0.1", 8080, stop))

========================================  =====================================================
``GET /``                                 the dashboard (packaged HTML/JS/CSS, no external URL)
``GET /api/machines``                     status of every machine
``GET /api/machines/{id}/force``          ``?seconds=S``: the last S seconds of estimated force
``GET /api/machines/{id}/spectrum``       ``?axis=x``: amplitude spectrum of the last 0.5 s
``GET /api/events``                       ``?since=SEQ&limit=N``: logged events after a seq
``POST /api/events/{event_id}/ack``       acknowledge an alarm (needs the token)
``PUT /api/machines/{id}/limits``         ``{"axis": "x", "force_limit_n": 500}`` (needs the token)
``GET /metrics``                          Prometheus text exposition
``WS /ws``                                ``hello``, then ``frame`` (5 per s) and ``event`` messages
========================================  =====================================================

Writes need ``Authorization: Bearer TOKEN`` with the config's ``[service] token``
(compared in constant time); without a configured token the service is
read-only.  Every body is strict JSON (no NaN).  The WebSocket never drops an
event: a client too slow to take them gets ``{"type": "resync"}`` and re-reads
``/api/events?since=``.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import math
import socket
from importlib import resources
from typing import Any

import uvicorn
from fastapi import FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response

from drivesense.errors import ConfigError

__all__ = ["create_app", "serve_http", "listen_socket", "STATIC_FILES"]

#: Packaged dashboard files and their media types.
STATIC_FILES = {"index.html": "text/html; charset=utf-8", "dashboard.js": "text/javascript; charset=utf-8",
                "dashboard.css": "text/css; charset=utf-8"}
#: Content type of ``/metrics`` (Prometheus text format).
METRICS_TYPE = "text/plain; version=0.0.4; charset=utf-8"
TOKEN_HELP = ("writes need the token from the config's [service] token, sent as the header "
              "'Authorization: Bearer TOKEN'")


def _finite(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (a last guard for strict JSON)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def _dumps(obj: Any) -> str:
    try:
        return json.dumps(obj, allow_nan=False, separators=(",", ":"))
    except ValueError:
        return json.dumps(_finite(obj), allow_nan=False, separators=(",", ":"))


class StrictJSONResponse(JSONResponse):
    """A JSON response that never writes NaN or Infinity (non-finite numbers become null)."""

    def render(self, content: Any) -> bytes:
        """The body.

        Parameters
        ----------
        content : Any
            JSON-able content.
        """
        return _dumps(content).encode()


def _error(status: int, message: str, parameter: str | None = None) -> StrictJSONResponse:
    body = {"error": message, "status": status}
    if parameter:
        body["parameter"] = parameter
    return StrictJSONResponse(body, status_code=status)


def _static(name: str) -> bytes:
    return (resources.files("drivesense.monitor") / "static" / name).read_bytes()


def _bearer(request: Request) -> str | None:
    scheme, _, token = (request.headers.get("authorization") or "").strip().partition(" ")
    return token.strip() if scheme.lower() == "bearer" and token.strip() else None


def _auth_error(service, request: Request) -> StrictJSONResponse | None:
    """None when the request carries the right token, else the 403 response."""
    if service.check_token(_bearer(request)):
        return None
    if service.token is None:
        return _error(403, f"this service is read-only: no token is configured; {TOKEN_HELP}", "Authorization")
    return _error(403, f"missing or wrong token: {TOKEN_HELP}", "Authorization")


async def _json_body(request: Request) -> dict | StrictJSONResponse:
    raw = await request.body()
    if not raw.strip():
        return {}
    try:
        body = json.loads(raw, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    except ValueError as exc:
        return _error(400, f"request body: not strict JSON ({exc})", "body")
    if not isinstance(body, dict):
        return _error(400, "request body: expected a JSON object", "body")
    return body


def create_app(service, *, title: str = "drivesense monitor") -> FastAPI:
    """The dashboard and HTTP API of a :class:`~drivesense.monitor.service.MonitorService`.

    Parameters
    ----------
    service : MonitorService
        The service (running or not: its machines keep their buffers).
    title : str
        Name shown in the dashboard's header and page title.

    Returns
    -------
    FastAPI
        The ASGI app (routes in the module docstring).
    """
    app = FastAPI(title=title, docs_url=None, redoc_url=None, openapi_url=None,
                  default_response_class=StrictJSONResponse)
    name = str(getattr(service, "name", None) or title)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> StrictJSONResponse:
        problems = [f"{' '.join(str(p) for p in e.get('loc', ()))}: {e.get('msg', 'invalid')}" for e in exc.errors()]
        first = exc.errors()[0].get("loc", ("", "?"))[-1] if exc.errors() else None
        return _error(422, "; ".join(problems), str(first) if first is not None else None)

    def known(machine_id: str) -> StrictJSONResponse | None:
        if machine_id in service.machines:
            return None
        return _error(404, f"no machine {machine_id!r} (machines: {', '.join(service.machines)})", "id")

    @app.get("/", include_in_schema=False)
    async def index() -> Response:
        page = _static("index.html").decode().replace("{{title}}", html.escape(name))
        return Response(page, media_type=STATIC_FILES["index.html"], headers={"Cache-Control": "no-cache"})

    @app.get("/static/{file}", include_in_schema=False)
    async def static(file: str) -> Response:
        if file not in STATIC_FILES:
            return _error(404, f"no static file {file!r}", "file")
        return Response(_static(file), media_type=STATIC_FILES[file], headers={"Cache-Control": "no-cache"})

    @app.get("/api/service")
    async def about() -> dict:
        return {"name": name, "started": service.started, "running": service.running,
                "writable": service.token is not None, "machines": list(service.machines)}

    @app.get("/api/machines")
    async def machines() -> list:
        return [service.machine_status(mid) for mid in service.machines]

    @app.get("/api/events")
    async def events(since: int = 0, limit: int = 1000) -> Any:
        if since < 0:
            return _error(400, f"since must be >= 0 (the last seq the client has), got {since}", "since")
        if not 1 <= limit <= 10000:
            return _error(400, f"limit must be between 1 and 10000, got {limit}", "limit")
        return service.events(since, limit)

    @app.get("/api/machines/{machine_id}/force")
    async def force(machine_id: str, seconds: float = 2.0) -> Any:
        if (err := known(machine_id)) is not None:
            return err
        mon = service.machine(machine_id).monitor
        if not (math.isfinite(seconds) and 0 < seconds <= mon.history_s):
            return _error(400, f"seconds must be > 0 and <= {mon.history_s:g} (the history kept) [s], "
                               f"got {seconds!r}", "seconds")
        return mon.force_history(seconds)

    @app.get("/api/machines/{machine_id}/spectrum")
    async def spectrum(machine_id: str, axis: str = "x") -> Any:
        if (err := known(machine_id)) is not None:
            return err
        mon = service.machine(machine_id).monitor
        axes = [a.axis for a in mon.axes]
        if axis not in axes:
            return _error(400, f"machine {machine_id!r} has no axis {axis!r} (axes: {', '.join(axes)})", "axis")
        return {"axis": axis, "fs": mon.fs, **mon.spectrum(axis)}

    @app.put("/api/machines/{machine_id}/limits")
    async def limits(machine_id: str, request: Request) -> Any:
        if (err := _auth_error(service, request)) is not None:
            return err
        if (err := known(machine_id)) is not None:
            return err
        body = await _json_body(request)
        if isinstance(body, Response):
            return body
        axis, limit = body.get("axis"), body.get("force_limit_n")
        if not isinstance(axis, str):
            return _error(400, f"axis must be an axis letter (a string), got {axis!r}", "axis")
        try:
            new = service.set_force_limit(machine_id, axis, limit)
        except ConfigError as exc:
            return _error(400, str(exc), "force_limit_n" if "force_limit_n" in str(exc) else "axis")
        return {"machine": machine_id, "limits": new}

    @app.post("/api/events/{event_id:path}/ack")
    async def ack(event_id: str, request: Request) -> Any:
        if (err := _auth_error(service, request)) is not None:
            return err
        body = await _json_body(request)
        if isinstance(body, Response):
            return body
        try:
            done = service.acknowledge(event_id, str(body.get("by", "dashboard")))
        except KeyError:
            return _error(404, f"no event with id {event_id!r}", "event_id")
        record = next((r for r in reversed(service.events(0, 10 ** 9)) if r["id"] == event_id), None)
        if record is not None:
            for sub in list(service.subscribers):
                sub.offer_event(record)                   # the other dashboards see it acknowledged
        return {"acknowledged": event_id, **{k: v for k, v in done.items() if k != "ack"}}

    @app.get("/metrics", include_in_schema=False)
    async def metrics() -> Response:
        return Response(service.metrics(), media_type=METRICS_TYPE)

    @app.websocket("/ws")
    async def ws(websocket: WebSocket) -> None:
        await websocket.accept()
        sub = service.subscribe()
        pending: dict[str, asyncio.Task] = {}
        try:
            hello = {"type": "hello", "service": {"name": name, "writable": service.token is not None},
                     "machines": [service.machine_status(mid) for mid in service.machines],
                     "events": service.events(0)}
            await websocket.send_text(_dumps(hello))
            pending = {"frame": asyncio.ensure_future(sub.frames.get()),
                       "event": asyncio.ensure_future(sub.events.get()),
                       "recv": asyncio.ensure_future(websocket.receive())}
            while True:
                await asyncio.wait(pending.values(), return_when=asyncio.FIRST_COMPLETED)
                if pending["recv"].done():
                    if pending["recv"].result().get("type") == "websocket.disconnect":
                        return
                    pending["recv"] = asyncio.ensure_future(websocket.receive())   # clients say nothing
                if pending["event"].done():                # events first, all that are queued
                    batch = [pending["event"].result()]
                    while not sub.events.empty():
                        batch.append(sub.events.get_nowait())
                    for record in batch:
                        await websocket.send_text(_dumps({"type": "event", "event": record}))
                    pending["event"] = asyncio.ensure_future(sub.events.get())
                if sub.overflow:                           # events were lost to this client: it re-reads them
                    sub.overflow = False
                    while not sub.events.empty():
                        sub.events.get_nowait()
                    await websocket.send_text(_dumps({"type": "resync"}))
                if pending["frame"].done():
                    await websocket.send_text(_dumps(pending["frame"].result()))
                    pending["frame"] = asyncio.ensure_future(sub.frames.get())
        except Exception:  # noqa: BLE001 - a client that went away mid-send: nothing to report
            return
        finally:
            for task in pending.values():
                task.cancel()
            service.unsubscribe(sub)

    return app


class _Server(uvicorn.Server):
    """uvicorn's server without its signal handlers: the caller owns the loop and sets ``stop``."""

    @contextlib.contextmanager
    def capture_signals(self):
        """No signal handling here (see :func:`serve_http`)."""
        yield


def listen_socket(host: str, port: int) -> socket.socket:
    """Bind the dashboard's listening socket now, so that a port in use is an error before anything runs.

    Parameters
    ----------
    host : str
        Address to listen on.
    port : int
        TCP port (0: any free one: read it from ``sock.getsockname()``).

    Returns
    -------
    socket.socket
        The bound socket, for :func:`serve_http`'s ``sock``.

    Raises
    ------
    ConfigError
        The host does not resolve, or the address cannot be bound (in use, not this machine's), naming ``--http``.
    """
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise ConfigError(f"--http {host}:{port}: cannot resolve host {host!r} ({exc.strerror})") from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise ConfigError(f"--http {host}:{port}: cannot listen there ({exc.strerror})") from None
    sock.set_inheritable(True)
    return sock


async def serve_http(service, host: str, port: int, stop: asyncio.Event, *,
                     sock: socket.socket | None = None) -> None:
    """Serve :func:`create_app` with uvicorn in the running loop until ``stop`` is set.

    Meant to run beside the service:
    ``await asyncio.gather(service.run(stop), serve_http(service, host, port, stop))``.  uvicorn's own
    signal handlers are not installed: the caller turns Ctrl-C into ``stop.set()``.  A server that fails
    sets ``stop`` as well, so the service shuts down cleanly instead of running without its dashboard.

    Parameters
    ----------
    service : MonitorService
        The service.
    host : str
        Address to listen on (``127.0.0.1``; ``0.0.0.0`` for every interface).
    port : int
        TCP port (0: any free one).
    stop : asyncio.Event
        Set to shut the server down.
    sock : socket.socket, optional
        A socket bound by :func:`listen_socket` beforehand (the CLI binds it before it prints the URL).

    Raises
    ------
    ConfigError
        The address cannot be listened on (port in use, unknown host), naming ``--http``.
    """
    if sock is None:
        try:
            sock = listen_socket(host, port)
        except ConfigError:
            stop.set()
            raise
    config = uvicorn.Config(create_app(service), host=host, port=port, log_level="warning", lifespan="off",
                            timeout_graceful_shutdown=2)
    server = _Server(config)

    async def watch() -> None:
        await stop.wait()
        server.should_exit = True

    watcher = asyncio.create_task(watch())
    ok = False
    try:
        await server.serve(sockets=[sock])
        ok = server.started
    finally:
        watcher.cancel()
        sock.close()
        if not ok:
            stop.set()
    if not ok:
        raise ConfigError(f"--http {host}:{port}: the dashboard server did not start")
