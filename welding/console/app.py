"""The console's web application (Starlette): JSON API, the status WebSocket, static pages.

Every blocking call of :class:`~welding.console.backend.Console` runs in the thread pool, so
a request waiting for the robot never holds up the event loop, the status stream or an
EmergencyStop. Errors come back as ``{"error": message}`` with a 4xx/5xx status, never a
traceback.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import logging
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from spec.errors import ProtocolError, RemoteError, error_text
from welding.console.backend import STATUS_HZ, Console, ConsoleError
from welding.tools import ToolDBError

__all__ = ["create_app"]

log = logging.getLogger("welding.console")
STATIC = Path(__file__).with_name("static")
Handler = Callable[[Request], Awaitable[Response]]


def _error(message: str, status: int) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


async def _body(request: Request) -> Any:
    raw = await request.body()
    if not raw:
        return {}
    try:
        return json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        raise ConsoleError("the request body is not JSON") from None


def _api(fn: Callable[[Request, Any], Any]) -> Handler:
    """A JSON endpoint: ``fn(request, body)`` runs in the thread pool; its result is the
    reply (None: ``{"ok": true}``); refusals become one-line errors."""

    async def endpoint(request: Request) -> Response:
        try:
            body = await _body(request) if request.method in ("POST", "PUT") else None
            result = await run_in_threadpool(fn, request, body)
        except ConsoleError as exc:
            return _error(str(exc), exc.status)
        except ToolDBError as exc:  # e.g. a database file broken by hand
            return _error(str(exc), 400)
        except RemoteError as exc:
            return _error(f"the robot refused: {exc}", 409)
        except (ProtocolError, OSError) as exc:
            return _error(f"connection problem: {error_text(exc)}", 503)
        return JSONResponse({"ok": True} if result is None else result)

    return endpoint


def create_app(console: Console) -> Starlette:
    """The application over ``console`` (which the caller starts and closes)."""
    ids = itertools.count(1)

    def p(request: Request, key: str) -> str:
        return str(request.path_params[key])

    def flag(body: Any, key: str) -> bool:
        v = body.get(key) if isinstance(body, dict) else None
        if not isinstance(v, bool):
            raise ConsoleError(f"{key}: expected true or false")
        return v

    def text(body: Any, key: str) -> str:
        v = body.get(key) if isinstance(body, dict) else None
        if not isinstance(v, str):
            raise ConsoleError(f"{key}: expected a string")
        return v

    async def frame(request: Request) -> Response:
        try:
            data = await run_in_threadpool(console.sensor_frame)
        except ConsoleError as exc:
            return _error(str(exc), exc.status)
        except (ProtocolError, OSError) as exc:
            return _error(f"connection problem: {error_text(exc)}", 503)
        png = data.pop("png")
        data["image"] = None if png is None else base64.b64encode(png).decode("ascii")
        return JSONResponse(data)

    async def status_ws(ws: WebSocket) -> None:
        await ws.accept()
        client_id = next(ids)
        console.select(client_id, "flange", "world")

        async def send() -> None:
            seq = -1
            while True:
                snap = console.snapshot()
                if snap.get("seq") != seq:
                    seq = snap.get("seq", -1)
                    await ws.send_json({"type": "status", **snap})
                await asyncio.sleep(0.5 / STATUS_HZ)

        async def receive() -> None:
            while True:
                msg = await ws.receive_json()
                kind = msg.get("type") if isinstance(msg, dict) else None
                try:
                    if kind == "hold":
                        console.hold_jog(client_id)
                    elif kind == "jog":
                        await run_in_threadpool(_jog, console, client_id, msg)
                    elif kind == "release":
                        await run_in_threadpool(console.stop_jog, client_id, "released")
                    elif kind == "select":
                        tool, frame = str(msg.get("tool")), str(msg.get("frame"))
                        await run_in_threadpool(console.select, client_id, tool, frame)
                    else:
                        raise ConsoleError(f"unknown message type {kind!r}")
                except (ConsoleError, RemoteError, ProtocolError, OSError) as exc:
                    await ws.send_json({"type": "error", "message": str(exc)})

        tasks = [asyncio.create_task(send()), asyncio.create_task(receive())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in tasks:
                t.cancel()
            # dead-man: a lost browser stops its jog
            await run_in_threadpool(console.forget, client_id)
        ended_by_client = False
        for t in tasks:
            if t.done() and not t.cancelled():
                exc = t.exception()
                ended_by_client |= isinstance(exc, WebSocketDisconnect)
                if exc is not None and not isinstance(exc, WebSocketDisconnect | RuntimeError):
                    log.warning("status websocket ended: %r", exc, exc_info=exc)
        if not ended_by_client:
            # the stream ended on our side: close it, so no client waits on it forever
            with contextlib.suppress(Exception):
                await ws.close(code=1011)

    def move(r: Request, b: Any) -> None:
        console.move_to(text(b, "job"), text(b, "name"), bool(b.get("linear", False)))

    def edit_tool(r: Request, b: Any) -> None:
        console.save_tool(b | {"name": p(r, "name")} if isinstance(b, dict) else b, new=False)

    def run(r: Request, b: Any) -> None:
        console.run_job(p(r, "name"), flag(b, "dry_run"))

    post, put, delete = ["POST"], ["PUT"], ["DELETE"]
    routes = [
        Route("/api/status", _api(lambda r, b: console.snapshot())),
        Route("/api/control", _api(lambda r, b: _control(console, flag(b, "take"))), methods=post),
        Route("/api/power", _api(lambda r, b: console.power(flag(b, "on"))), methods=post),
        Route("/api/estop", _api(lambda r, b: console.emergency_stop()), methods=post),
        Route("/api/estop/reset", _api(lambda r, b: console.reset_emergency_stop()), methods=post),
        Route("/api/move", _api(move), methods=post),
        Route("/api/tools", _api(lambda r, b: console.tools_json())),
        Route("/api/tools", _api(lambda r, b: console.save_tool(b, new=True)), methods=post),
        Route("/api/tools/{name}", _api(edit_tool), methods=put),
        Route(
            "/api/tools/{name}",
            _api(lambda r, b: console.remove_tool(p(r, "name"))),
            methods=delete,
        ),
        Route("/api/jobs", _api(lambda r, b: {"jobs": console.list_jobs()})),
        Route("/api/jobs/{name}", _api(lambda r, b: console.open_job(p(r, "name")))),
        Route(
            "/api/jobs/{name}", _api(lambda r, b: console.save_job(p(r, "name"), b)), methods=put
        ),
        Route(
            "/api/jobs/{name}/check",
            _api(lambda r, b: console.check_job(p(r, "name"), b)),
            methods=post,
        ),
        Route("/api/jobs/{name}/run", _api(run), methods=post),
        Route("/api/abort", _api(lambda r, b: console.abort()), methods=post),
        Route("/api/teach", _api(lambda r, b: console.teach(b)), methods=post),
        Route("/api/delta-t", _api(lambda r, b: console.delta_t(b)), methods=post),
        Route("/api/calibrate", _api(lambda r, b: console.calibrate(b)), methods=post),
        Route("/api/track", _api(lambda r, b: console.track(b)), methods=post),
        Route(
            "/api/result/{kind}", _api(lambda r, b: {"result": console.results.get(p(r, "kind"))})
        ),
        Route("/api/sensor/frame", frame),
        Route("/api/sensor/settings", _api(lambda r, b: console.sensor_settings())),
        Route(
            "/api/sensor/settings", _api(lambda r, b: console.set_sensor_settings(b)), methods=post
        ),
        WebSocketRoute("/ws", status_ws),
        Mount("/", StaticFiles(directory=STATIC, html=True), name="static"),
    ]
    return Starlette(routes=routes)


def _jog(console: Console, client_id: int, msg: dict[str, Any]) -> None:
    console.start_jog(
        client_id,
        mode=str(msg.get("mode")),
        axis=msg.get("axis"),
        direction=msg.get("direction"),
        speed=msg.get("speed", 10),
        tool=str(msg.get("tool", "flange")),
        frame=str(msg.get("frame", "world")),
    )


def _control(console: Console, take: bool) -> None:
    if take:
        console.take_control()
    else:
        console.release_control()
