"""The console's web application (Starlette): JSON API, the status WebSocket, static pages.

A thin composition: the routes table below (each route with its :class:`~welding.console.
access.Rule`: role, control, audit name, and its request body's :class:`Body`), the access
control middleware (:mod:`welding.console.access`) in front of all of it, and the console's
connections (:class:`~welding.console.backend.Console`) behind it.

Every blocking call of the console runs in the thread pool, so a request waiting for the
robot never holds up the event loop, the status stream or an EmergencyStop. Errors come back
as ``{"error": message}`` with a 4xx/5xx status, never a traceback.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import logging
import math
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, RedirectResponse, Response
from starlette.routing import BaseRoute, Match, Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.types import Scope
from starlette.websockets import WebSocket, WebSocketDisconnect

from spec.errors import ProtocolError, RemoteError, error_text
from welding.console.access import (
    Access,
    AccessControl,
    Rule,
    cookie_header,
    expired_cookie,
    session_of,
    set_cookie,
)
from welding.console.auth import Session, SignInRefused
from welding.console.backend import (
    JOG_DEFAULT_PCT,
    JOG_STEP_MAX,
    STATUS_HZ,
    Console,
    ConsoleError,
)
from welding.tools import ToolDBError

__all__ = ["Body", "create_app"]

log = logging.getLogger("welding.console")
STATIC = Path(__file__).with_name("static")
Handler = Callable[[Request], Awaitable[Response]]
Kind = Literal["bool", "str", "number", "list", "object"]


@dataclass(frozen=True)
class Body:
    """The JSON object a route takes: each field's kind and whether it is required. Anything
    else is refused: a body that is not an object (400), an unknown or missing field or one
    of the wrong kind (422), each with a message naming the field."""

    fields: Mapping[str, tuple[Kind, bool]] = field(default_factory=dict)

    def check(self, value: Any) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise ConsoleError("expected a JSON object {...} as the request body", 400)
        unknown = sorted(set(value) - set(self.fields))
        if unknown:
            known = ", ".join(self.fields) or "none"
            raise ConsoleError(f"unknown field {', '.join(unknown)} (fields: {known})", 422)
        for key, (kind, required) in self.fields.items():
            if key not in value:
                if required:
                    raise ConsoleError(f"{key}: required", 422)
                continue
            v = value[key]
            ok = {
                "bool": isinstance(v, bool),
                "str": isinstance(v, str),
                "number": isinstance(v, int | float)
                and not isinstance(v, bool)
                and math.isfinite(v),
                "list": isinstance(v, list),
                "object": isinstance(v, dict),
            }[kind]
            if not ok:
                what = {"bool": "true or false", "number": "a number", "str": "a string"}
                raise ConsoleError(f"{key}: expected {what.get(kind, f'a JSON {kind}')}", 422)
        return value


NONE = Body()


def _b(**fields: tuple[Kind, bool]) -> Body:
    return Body(fields)


REQ, OPT = True, False
BODIES = {
    "signin": _b(name=("str", REQ), password=("str", REQ)),
    "control": _b(take=("bool", REQ)),
    "power": _b(on=("bool", REQ)),
    "move": _b(job=("str", REQ), name=("str", REQ), linear=("bool", OPT)),
    "tool_new": _b(name=("str", REQ), kind=("str", REQ), location=("list", REQ), note=("str", OPT)),
    "tool_edit": _b(location=("list", REQ), note=("str", OPT)),
    "job": _b(job=("object", OPT), xml=("str", OPT)),
    "run": _b(dry_run=("bool", REQ)),
    "teach": _b(
        step=("number", OPT),
        length=("number", OPT),
        max_points=("number", OPT),
        speed=("number", OPT),
        sensor_tool=("str", OPT),
    ),
    "delta_t": _b(frequency=("number", OPT), amplitude=("number", OPT), duration=("number", OPT)),
    "calibrate": _b(
        which=("str", OPT), tool=("str", OPT), poses=("number", OPT), repeats=("number", OPT)
    ),
    "track": _b(seam=("str", OPT), speed=("number", OPT), tracked=("bool", OPT)),
    "ilc": _b(
        seam=("str", OPT),
        speed=("number", OPT),
        length=("number", OPT),
        trials=("number", OPT),
        model_payload_kg=("number", OPT),
    ),
    "sensor_settings": _b(
        exposure_ms=("number", OPT), first_column=("number", OPT), columns=("number", OPT)
    ),
}


def _error(message: str, status: int) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


async def _body(request: Request, schema: Body) -> dict[str, Any]:
    """The request's JSON object, checked against ``schema`` (an empty body is ``{}``)."""
    raw = await request.body()
    if not raw.strip():
        return schema.check({})
    try:
        value = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        raise ConsoleError("the request body is not JSON") from None
    return schema.check(value)


class ApiRoute(Route):
    """A route with the access rule the middleware applies to it."""

    def __init__(self, path: str, endpoint: Callable[..., Any], *, rule: Rule, **kw: Any) -> None:
        super().__init__(path, endpoint, **kw)
        self.rule = rule


def _rule_for(routes: list[BaseRoute]) -> Callable[[Scope], Rule]:
    def rule(scope: Scope) -> Rule:
        for route in routes:
            match, _ = route.matches(scope)
            if match is Match.FULL:
                return route.rule if isinstance(route, ApiRoute) else Rule("viewer")
        return Rule("operator")  # a method no route has: the router answers 405

    return rule


def _api(fn: Callable[[Request, dict[str, Any]], Any], body: Body = NONE) -> Handler:
    """A JSON endpoint: ``fn(request, body)`` runs in the thread pool; its result is the
    reply (None: ``{"ok": true}``); refusals become one-line errors."""

    async def endpoint(request: Request) -> Response:
        try:
            b = await _body(request, body) if request.method in ("POST", "PUT") else {}
            result = await run_in_threadpool(fn, request, b)
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


def _user(r: Request) -> str:
    return session_of(r.scope).user


def create_app(
    console: Console,
    access: Access,
    *,
    announce: Callable[[str], None] = log.info,
    base_url: str = "",
) -> Starlette:
    """The application over ``console`` (opened when the application starts unless it is
    already, closed when it stops: its lifespan), behind the
    access control of ``access``. ``announce`` is told each new sign-in URL (``base_url``
    + ``/signin?token=…``) after the last one was used."""
    access.holder = console.holder

    def p(request: Request, key: str) -> str:
        return str(request.path_params[key])

    sign = SignIn(console, access, announce, base_url)

    async def index(request: Request) -> Response:
        return FileResponse(STATIC / "index.html")

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

    def control(r: Request, b: dict[str, Any]) -> None:
        if b["take"]:
            console.take_control(_user(r))
        else:
            console.release_control()

    def move(r: Request, b: dict[str, Any]) -> None:
        console.move_to(b["job"], b["name"], bool(b.get("linear", False)))

    def edit_tool(r: Request, b: dict[str, Any]) -> None:
        console.save_tool(b | {"name": p(r, "name")}, new=False)

    def run(r: Request, b: dict[str, Any]) -> None:
        console.run_job(p(r, "name"), b["dry_run"])

    def audit(r: Request, b: dict[str, Any]) -> dict[str, Any]:
        return {"entries": access.audit.tail(500), "file": str(access.audit.path)}

    viewer = Rule("viewer")
    operator = Rule("operator")

    def act(name: str, control: bool = False) -> Rule:
        return Rule("operator", control=control, action=name)

    post, put, delete = ["POST"], ["PUT"], ["DELETE"]
    B = BODIES
    routes: list[BaseRoute] = [
        Route("/signin", sign.page),
        Route("/api/signin", sign.password, methods=post),
        ApiRoute("/api/signout", sign.out, methods=post, rule=Rule("viewer", action="sign-out")),
        ApiRoute("/api/session", sign.session, rule=viewer),
        ApiRoute("/api/audit", _api(audit), rule=operator),
        ApiRoute("/", index, rule=viewer),
        ApiRoute("/index.html", index, rule=viewer),
        ApiRoute("/api/status", _api(lambda r, b: console.snapshot()), rule=viewer),
        ApiRoute("/api/control", _api(control, B["control"]), methods=post,
                 rule=act("control", control=True)),
        ApiRoute("/api/power", _api(lambda r, b: console.power(b["on"]), B["power"]),
                 methods=post, rule=act("power", control=True)),
        # EmergencyStop: every signed-in user, viewer included, whoever holds control
        ApiRoute("/api/estop", _api(lambda r, b: console.emergency_stop()), methods=post,
                 rule=Rule("viewer", action="estop")),
        ApiRoute("/api/estop/reset", _api(lambda r, b: console.reset_emergency_stop()),
                 methods=post, rule=act("estop reset", control=True)),
        ApiRoute("/api/move", _api(move, B["move"]), methods=post, rule=act("move", True)),
        ApiRoute("/api/tools", _api(lambda r, b: console.tools_json()), rule=viewer),
        ApiRoute("/api/tools", _api(lambda r, b: console.save_tool(b, new=True), B["tool_new"]),
                 methods=post, rule=act("tool add")),
        ApiRoute("/api/tools/{name}", _api(edit_tool, B["tool_edit"]), methods=put,
                 rule=act("tool edit")),
        ApiRoute("/api/tools/{name}", _api(lambda r, b: console.remove_tool(p(r, "name"))),
                 methods=delete, rule=act("tool remove")),
        ApiRoute("/api/jobs", _api(lambda r, b: {"jobs": console.list_jobs()}), rule=viewer),
        ApiRoute("/api/jobs/{name}", _api(lambda r, b: console.open_job(p(r, "name"))),
                 rule=viewer),
        ApiRoute("/api/jobs/{name}", _api(lambda r, b: console.save_job(p(r, "name"), b),
                 B["job"]), methods=put, rule=act("job save")),
        ApiRoute("/api/jobs/{name}/check", _api(lambda r, b: console.check_job(p(r, "name"), b),
                 B["job"]), methods=post, rule=operator),
        ApiRoute("/api/jobs/{name}/run", _api(run, B["run"]), methods=post,
                 rule=act("job run", True)),
        ApiRoute("/api/abort", _api(lambda r, b: console.abort()), methods=post,
                 rule=act("abort", True)),
        ApiRoute("/api/teach", _api(lambda r, b: console.teach(b), B["teach"]), methods=post,
                 rule=act("teach", True)),
        ApiRoute("/api/delta-t", _api(lambda r, b: console.delta_t(b), B["delta_t"]),
                 methods=post, rule=act("delta-t", True)),
        ApiRoute("/api/calibrate", _api(lambda r, b: console.calibrate(b), B["calibrate"]),
                 methods=post, rule=act("calibrate", True)),
        ApiRoute("/api/track", _api(lambda r, b: console.track(b), B["track"]), methods=post,
                 rule=act("track")),
        ApiRoute("/api/ilc", _api(lambda r, b: console.ilc(b), B["ilc"]), methods=post,
                 rule=act("ilc")),
        ApiRoute("/api/result/{kind}",
                 _api(lambda r, b: {"result": console.result(p(r, "kind"))}), rule=viewer),
        ApiRoute("/api/sensor/frame", frame, rule=viewer),
        ApiRoute("/api/sensor/settings", _api(lambda r, b: console.sensor_settings()),
                 rule=viewer),
        ApiRoute("/api/sensor/settings",
                 _api(lambda r, b: console.set_sensor_settings(b), B["sensor_settings"]),
                 methods=post, rule=act("sensor settings", True)),
        WebSocketRoute("/ws", StatusSocket(console, access).handle),
        Mount("/", StaticFiles(directory=STATIC, html=False), name="static"),
    ]  # fmt: skip
    middleware = [Middleware(AccessControl, access=access, rule=_rule_for(routes))]

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        # the console's connections and threads live as long as the application serves
        await run_in_threadpool(console.open)
        try:
            yield
        finally:
            await run_in_threadpool(console.close)

    return Starlette(routes=routes, middleware=middleware, lifespan=lifespan)


def _address(request: Request) -> str:
    return request.client.host if request.client else "?"


class SignIn:
    """Sign-in by the one-time URL's token or by name and password, sign-out, the session
    the page reads; every sign-in and refusal in the audit log."""

    def __init__(
        self, console: Console, access: Access, announce: Callable[[str], None], base_url: str
    ) -> None:
        self.console, self.access = console, access
        self.sessions = access.sessions
        self.announce, self.base_url = announce, base_url

    def _json(self, s: Session) -> dict[str, Any]:
        return {"user": s.user, "role": s.role, "csrf": s.csrf,
                "controller": self.console.controller,
                # the page's jog: its starting speed and largest step, from the backend's rules
                "jog": {"speed": JOG_DEFAULT_PCT, "step_max": JOG_STEP_MAX}}  # fmt: skip

    def _signed_in(self, request: Request, s: Session, reply: Response) -> Response:
        self.access.audit.record(s.user, s.address, "sign-in", "ok")
        cookie = cookie_header(
            request.scope, s, tls=self.access.tls, max_age=self.sessions.lifetime
        )
        return set_cookie(reply, cookie)

    def _refused(self, request: Request, user: str, exc: SignInRefused) -> None:
        address = _address(request)
        log.warning("sign-in refused for %r from %s: %s", user, address, exc)
        self.access.audit.record(
            user, address, "sign-in", f"refused ({exc.status})", error=str(exc)
        )

    async def page(self, request: Request) -> Response:
        token = request.query_params.get("token")
        if token is None:
            return FileResponse(STATIC / "signin.html")
        address = _address(request)
        try:
            s = self.sessions.sign_in_token(token, address, self.access.clock())
        except SignInRefused as exc:
            await run_in_threadpool(self._refused, request, "token", exc)
            return RedirectResponse("/signin?failed=1", 303)
        self.announce(f"console: the sign-in URL was used from {address}; the next one: "
                      f"{self.base_url}/signin?token={self.sessions.token}")  # fmt: skip
        return await run_in_threadpool(self._signed_in, request, s, RedirectResponse("/", 303))

    async def password(self, request: Request) -> Response:
        try:
            b = await _body(request, BODIES["signin"])
        except ConsoleError as exc:
            return _error(str(exc), exc.status)
        try:
            s = await run_in_threadpool(
                self.sessions.sign_in_password,
                b["name"],
                b["password"],
                _address(request),
                self.access.clock(),
            )
        except SignInRefused as exc:
            await run_in_threadpool(self._refused, request, b["name"], exc)
            headers = {"Retry-After": str(math.ceil(exc.retry_after))} if exc.retry_after else {}
            return JSONResponse({"error": str(exc)}, exc.status, headers=headers)
        return await run_in_threadpool(self._signed_in, request, s, JSONResponse(self._json(s)))

    async def out(self, request: Request) -> Response:
        s = session_of(request.scope)
        self.sessions.end(s.sid)
        return set_cookie(JSONResponse({"ok": True}), expired_cookie(request.scope))

    async def session(self, request: Request) -> Response:
        return JSONResponse(self._json(session_of(request.scope)))


class StatusSocket:
    """The ``/ws`` WebSocket: the status stream out, the jog's messages in (jog, hold,
    release, select). A lost browser stops its jog (dead-man)."""

    def __init__(self, console: Console, access: Access) -> None:
        self.console, self.access = console, access
        self._ids = itertools.count(1)

    async def handle(self, ws: WebSocket) -> None:
        s = session_of(ws.scope)
        address = ws.client.host if ws.client else "?"
        await ws.accept()
        client_id = next(self._ids)
        self.console.select(client_id, "flange", "world")
        tasks = [
            asyncio.create_task(self._send(ws)),
            asyncio.create_task(self._receive(ws, s, address, client_id)),
        ]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in tasks:
                t.cancel()
            await run_in_threadpool(self.console.forget, client_id)
        if not self._ended_by_client(tasks):
            # the stream ended on our side: close it, so no client waits on it forever
            with contextlib.suppress(Exception):
                await ws.close(code=1011)

    @staticmethod
    def _ended_by_client(tasks: list[asyncio.Task[None]]) -> bool:
        ended = False
        for t in tasks:
            if t.done() and not t.cancelled():
                exc = t.exception()
                ended |= isinstance(exc, WebSocketDisconnect)
                if exc is not None and not isinstance(exc, WebSocketDisconnect | RuntimeError):
                    log.warning("status websocket ended: %r", exc, exc_info=exc)
        return ended

    async def _send(self, ws: WebSocket) -> None:
        seq = -1
        while True:
            snap = self.console.snapshot()
            if snap.get("seq") != seq:
                seq = snap.get("seq", -1)
                await ws.send_json({"type": "status", **snap})
            await asyncio.sleep(0.5 / STATUS_HZ)

    def _jog(self, s: Session, address: str, client_id: int, msg: dict[str, Any]) -> None:
        try:
            # the middleware's rules for a route, applied to the jog messages
            if s.role != "operator":
                raise ConsoleError(f"operators only: {s.user} is a {s.role}", 403)
            holder = self.access.holder()
            if holder is not None and holder != s.user:
                raise ConsoleError(f"{holder} holds control", 409)
            _jog(self.console, client_id, msg)
        except (ConsoleError, RemoteError, ProtocolError, OSError) as exc:
            self.access.audit.record(s.user, address, "jog start", "refused", error=str(exc))
            raise
        self.access.audit.record(s.user, address, "jog start", "ok", request=msg)

    def _release(self, s: Session, address: str, client_id: int) -> None:
        if self.console.stop_jog(client_id, "released"):
            self.access.audit.record(s.user, address, "jog stop", "ok")

    async def _receive(self, ws: WebSocket, s: Session, address: str, client_id: int) -> None:
        while True:
            msg = await ws.receive_json()
            kind = msg.get("type") if isinstance(msg, dict) else None
            try:
                if kind == "hold":
                    self.console.hold_jog(client_id)
                elif kind == "jog":
                    await run_in_threadpool(self._jog, s, address, client_id, msg)
                elif kind == "release":
                    await run_in_threadpool(self._release, s, address, client_id)
                elif kind == "select":
                    tool, frame = str(msg.get("tool")), str(msg.get("frame"))
                    await run_in_threadpool(self.console.select, client_id, tool, frame)
                else:
                    raise ConsoleError(f"unknown message type {kind!r}")
            except (ConsoleError, RemoteError, ProtocolError, OSError) as exc:
                await ws.send_json({"type": "error", "message": str(exc)})


def _jog(console: Console, client_id: int, msg: dict[str, Any]) -> None:
    console.start_jog(
        client_id,
        mode=str(msg.get("mode")),
        axis=msg.get("axis"),
        direction=msg.get("direction"),
        speed=msg.get("speed", JOG_DEFAULT_PCT),
        tool=str(msg.get("tool", "flange")),
        frame=str(msg.get("frame", "world")),
        step=msg.get("step"),
    )
