"""The console's access control as one ASGI middleware (issue 28 items 1-3, 5).

Every HTTP request and WebSocket handshake passes these checks, in this order, before any
route sees it (Jupyter Server's ``check_host``, ``check_origin`` and XSRF are the model):

1. **Host** must be one the console serves: an IP literal, ``localhost``, or a name given
   with ``--allow-host`` (a DNS-rebinding page sends its own name) -> 400.
2. **A session** (the HttpOnly, SameSite=Strict cookie) for everything but the sign-in page,
   the sign-in request and static assets: API 401, the page redirects to ``/signin``.
3. **State-changing requests** (anything but GET/HEAD): ``Content-Type: application/json``
   (415; a cross-site page can send text/plain or a form without a preflight, never JSON),
   an ``Origin``, when the browser sends one, equal to the console's own (403), and the
   session's CSRF token in ``X-CSRF-Token`` (403).
4. **The role** the route needs (403 for a viewer), and for actions that need control, the
   caller must be the operator who holds it (409 naming who does).
5. The WebSocket handshake: Host, an Origin (when sent) equal to the console's own, and a
   session; refused before it is accepted (HTTP 403).

Every refusal is logged with the address; every state-changing request of a signed-in user
that names an audit ``action`` is one line in the audit log with its outcome.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.requests import cookie_parser
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from welding.console.audit import AuditLog
from welding.console.auth import Role, Session, Sessions

__all__ = ["Access", "AccessControl", "Rule", "cookie_name", "host_allowed", "session_of"]

log = logging.getLogger("welding.console")
LOCAL_NAMES = frozenset({"localhost", "localhost.localdomain"})
SAFE_METHODS = frozenset({"GET", "HEAD"})
#: Paths served without a session: the sign-in page and its request.
PUBLIC_PATHS = frozenset({"/signin", "/api/signin", "/signin.html", "/signin.js"})
#: Static assets (no data in them) a sign-in page may need; the console page itself is not.
PUBLIC_SUFFIXES = (".css", ".js", ".png", ".svg", ".ico", ".woff2")
SCOPE_KEY = "welding.console.session"


@dataclass(frozen=True)
class Rule:
    """What a route needs: ``role``; ``control``: the caller must hold control (or nobody
    does, and the console then says "take control first"); ``action``: its audit name."""

    role: Role = "operator"
    control: bool = False
    action: str | None = None


@dataclass
class Access:
    """The middleware's configuration: the sessions, the extra Host names, the audit log,
    TLS (cookies are then Secure and the console's origin is https), and who holds
    control (a user name or None)."""

    sessions: Sessions
    audit: AuditLog
    allow_hosts: frozenset[str] = frozenset()
    tls: bool = False
    holder: Callable[[], str | None] = field(default=lambda: None)

    def clock(self) -> float:
        return time.monotonic()


def host_allowed(host: str, extra: Iterable[str] = ()) -> bool:
    """Whether a ``Host`` header names this console: an IP literal (a rebinding attack needs
    a name), a local name, or one of ``extra``."""
    name = host.strip().lower()
    if name.startswith("["):  # [::1]:8024
        name = name[1 : name.find("]")] if "]" in name else ""
    elif name.count(":") == 1:
        name = name.rsplit(":", 1)[0]
    name = name.rstrip(".")
    if not name:
        return False
    if name in LOCAL_NAMES or name in {e.lower().rstrip(".") for e in extra}:
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def cookie_name(scope: Scope) -> str:
    """Per port: browsers share cookies between ports of one host, consoles must not."""
    server = scope.get("server")
    port = server[1] if server and server[1] is not None else 0
    return f"welding_console_{port}"


def session_of(scope: Scope) -> Session:
    """The session the middleware found for this request."""
    s: Session = scope[SCOPE_KEY]
    return s


def _address(scope: Scope) -> str:
    client = scope.get("client")
    return str(client[0]) if client else "?"


class AccessControl:
    """The ASGI middleware; ``rule(scope)`` is the matched route's :class:`Rule`."""

    def __init__(self, app: ASGIApp, access: Access, rule: Callable[[Scope], Rule]) -> None:
        self.app = app
        self.access = access
        self.rule = rule

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        host = headers.get("host", "")
        refusal = self._check(scope, headers, host)
        if refusal is not None:
            status, message = refusal
            log.warning(
                "refused %s %s from %s (Host %r, Origin %r): %s",
                scope.get("method", "WebSocket"), scope["path"], _address(scope), host,
                headers.get("origin"), message,
            )  # fmt: skip
            if scope["type"] == "websocket":
                await receive()  # websocket.connect
                await send({"type": "websocket.close", "code": 1008, "reason": message[:120]})
                return
            if status == 303:
                await RedirectResponse("/signin", 303)(scope, receive, send)
                return
            await JSONResponse({"error": message}, status)(scope, receive, send)
            return
        rule = self.rule(scope) if scope["type"] == "http" else Rule("viewer")
        session = scope.get(SCOPE_KEY)
        if scope["type"] == "http" and session is not None and rule.action is not None:
            await self._audited(scope, receive, send, session, rule.action)
            return
        await self.app(scope, receive, send)

    def _own_origin(self, host: str) -> str:
        return f"{'https' if self.access.tls else 'http'}://{host.lower()}"

    def _check(self, scope: Scope, headers: Headers, host: str) -> tuple[int, str] | None:
        """(status, message) of the first check the request fails; None when it passes (the
        session, if any, is then in the scope)."""
        if not host_allowed(host, self.access.allow_hosts):
            name = host or "(none)"
            return 400, f"Host {name} is not served here (--allow-host {name} to add it)"
        path = scope["path"]
        origin = headers.get("origin")
        cross = origin is not None and origin.lower() != self._own_origin(host)
        ws = scope["type"] == "websocket"
        changing = not ws and scope["method"] not in SAFE_METHODS
        if cross and (ws or changing):
            return 403, f"cross-origin request from {origin} refused"
        if changing:
            ctype = headers.get("content-type", "").split(";")[0].strip().lower()
            if ctype != "application/json":
                return 415, "Content-Type must be application/json"
        public = path in PUBLIC_PATHS or (
            not ws and not path.startswith("/api/") and path.endswith(PUBLIC_SUFFIXES)
        )
        cookies = cookie_parser(headers.get("cookie", ""))
        session = self.access.sessions.get(cookies.get(cookie_name(scope)), self.access.clock())
        if session is not None:
            scope[SCOPE_KEY] = session
        if public:
            return None
        if session is None:
            if ws or path.startswith("/api/"):
                return 401, "sign in first"
            return 303, "sign in first"
        if changing and not hmac.compare_digest(
            headers.get("x-csrf-token", "").encode(), session.csrf.encode()
        ):
            return 403, "missing or wrong CSRF token (X-CSRF-Token): reload the page"
        if ws:
            return None
        rule = self.rule(scope)
        if rule.role == "operator" and session.role != "operator":
            return 403, f"operators only: {session.user} is a {session.role}"
        if rule.control:
            holder = self.access.holder()
            if holder is not None and holder != session.user:
                return 409, f"{holder} holds control"
        return None

    async def _audited(
        self, scope: Scope, receive: Receive, send: Send, session: Session, action: str
    ) -> None:
        """Run the request, then write its audit line: the request body (when small) and the
        outcome ("ok" or the refusal)."""
        body = bytearray()
        reply = bytearray()
        status = 0

        async def receive_recorded() -> Message:
            message = await receive()
            if message["type"] == "http.request" and len(body) <= 4096:
                body.extend(message.get("body", b""))
            return message

        async def send_recorded(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body" and status >= 400 and len(reply) < 4096:
                reply.extend(message.get("body", b""))
            await send(message)

        try:
            await self.app(scope, receive_recorded, send_recorded)
        finally:
            outcome = "ok" if 0 < status < 400 else f"refused ({status or 'no reply'})"
            detail: dict[str, Any] = {"path": scope["path"]}
            if status >= 400:
                detail["error"] = _error_text(bytes(reply))
            request = _small_json(bytes(body))
            if request is not None:
                detail["request"] = request
            await run_in_threadpool(
                self.access.audit.record,
                session.user, _address(scope), action, outcome, **detail,
            )  # fmt: skip


def _error_text(raw: bytes) -> str:
    try:
        return str(json.loads(raw).get("error", ""))
    except (ValueError, AttributeError):
        return raw[:200].decode("utf-8", "replace")


def _small_json(raw: bytes) -> Any:
    """The request body for the audit line: the JSON when short, else its size."""
    if not raw:
        return None
    if len(raw) > 1024:
        return {"bytes": len(raw)}
    try:
        return json.loads(raw)
    except ValueError:
        return {"bytes": len(raw)}


def cookie_header(scope: Scope, session: Session, *, tls: bool, max_age: float) -> str:
    """The Set-Cookie value of ``session``: HttpOnly, SameSite=Strict, Secure with TLS."""
    secure = "; Secure" if tls else ""
    return (
        f"{cookie_name(scope)}={session.sid}; Path=/; Max-Age={int(max_age)}; HttpOnly; "
        f"SameSite=Strict{secure}"
    )


def expired_cookie(scope: Scope) -> str:
    return f"{cookie_name(scope)}=; Path=/; Max-Age=0; HttpOnly; SameSite=Strict"


def set_cookie(response: Response, value: str) -> Response:
    response.headers.append("set-cookie", value)
    return response
