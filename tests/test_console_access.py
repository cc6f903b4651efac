"""Who may use the console (issue 28): sessions, roles, Host/Origin/CSRF/Content-Type checks,
the one-time sign-in URL, accounts with scrypt hashes, the audit log; and the issue's two
curl lines against ``python -m welding console --emulate`` refused, the robot untouched."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("starlette", reason="the console extra is not installed")
pytest.importorskip("httpx2", reason="the console extra is not installed")

from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from robotsocket.client import RobotClient
from welding.cli import merge_cell_tools
from welding.console.access import Access, host_allowed
from welding.console.app import ApiRoute, create_app
from welding.console.audit import AuditLog
from welding.console.auth import (
    Sessions,
    UsersError,
    add_user,
    hash_password,
    load_users,
    verify_password,
)
from welding.console.backend import Console
from welding.emulate import cell_tables, realtime_cell

BASE = "http://127.0.0.1:8024"
WS = "ws://127.0.0.1:8024/ws"
EVIL = "http://evil.example"


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Any, Console, Access]]:
    tmp = tmp_path_factory.mktemp("access")
    cell = realtime_cell("straight")
    tools = tmp / "tools.json"
    merge_cell_tools(str(tools), cell_tables(cell))
    users = tmp / "users.json"
    add_user(users, "alice", "operator", "alice-password")
    add_user(users, "bob", "operator", "bob-password")
    add_user(users, "vera", "viewer", "vera-password")
    console = Console(cell.robot_address, cell.sensor_address, tools=tools, jobs=tmp, cell=cell)
    console.open()  # the clients below are not all opened as context managers (no lifespan)
    access = Access(Sessions(load_users(users)), AuditLog(tmp / "audit.jsonl"))
    app = create_app(console, access)
    try:
        yield app, console, access
    finally:
        console.close()
        cell.close()


def client(app: Any, who: str | None = None) -> TestClient:
    """A browser: signed in as ``who`` (password sign-in), or not at all."""
    c = TestClient(app, base_url=BASE)
    if who is not None:
        r = c.post("/api/signin", json={"name": who, "password": f"{who}-password"})
        assert r.status_code == 200, r.text
        c.headers["X-CSRF-Token"] = r.json()["csrf"]
    return c


def routes(app: Any) -> list[tuple[str, str]]:
    """(method, path) of every API route, path parameters filled in."""
    out: list[tuple[str, str]] = []
    for r in app.routes:
        if isinstance(r, ApiRoute) and r.path.startswith("/api/") and r.path != "/api/signin":
            path = r.path.replace("{name}", "demo.xml").replace("{kind}", "delta_t")
            out.extend((m, path) for m in sorted(r.methods or ()) if m != "HEAD")
    return out


def test_every_route_and_the_websocket_need_a_session(env: Any) -> None:
    app, _, _ = env
    c = client(app)
    found = routes(app)
    assert len(found) >= 25 and ("POST", "/api/control") in found
    for method, path in found:
        r = c.request(method, path, json={} if method != "GET" else None)
        assert r.status_code == 401, (method, path, r.text)
        assert r.json() == {"error": "sign in first"}
    with pytest.raises(WebSocketDisconnect) as refused, c.websocket_connect(WS):
        pass
    assert refused.value.code == 1008
    page = c.get("/", follow_redirects=False)
    assert page.status_code == 303 and page.headers["location"] == "/signin"
    assert "Sign in" in c.get("/signin").text  # the sign-in page and assets are served
    assert c.get("/console.css").status_code == 200


def test_favicon_and_the_chart_library_are_served(env: Any) -> None:
    """Issue 35 item 7: /favicon.ico was a 404 in every browser's console; the vendored
    chart library and its licence ship with the page (no build step, no download)."""
    app, _, _ = env
    c = client(app)
    icon = c.get("/favicon.ico")
    assert icon.status_code == 200 and icon.content[:4] == b"\x00\x00\x01\x00"  # ICO
    lib = c.get("/vendor/chart.umd.min.js")
    assert lib.status_code == 200 and "Chart.js v4" in lib.text[:300]
    licence = Path(__file__).parent.parent / "welding/console/static/vendor/chart.js-LICENSE.md"
    assert "MIT License" in licence.read_text()


def test_viewer_sees_but_may_not_act_except_emergency_stop(env: Any) -> None:
    app, console, _ = env
    v = client(app, "vera")
    assert v.get("/api/status").status_code == 200
    assert v.get("/api/session").json()["role"] == "viewer"
    for method, path in routes(app):
        if method == "GET" and path != "/api/audit":
            continue
        if path in ("/api/estop", "/api/signout"):
            continue
        r = v.request(method, path, json={} if method != "GET" else None)
        assert r.status_code == 403, (method, path, r.text)
        assert r.json()["error"] == "operators only: vera is a viewer"
    with v.websocket_connect(WS) as ws:  # the status stream, but no jog
        assert ws.receive_json()["type"] == "status"
        ws.send_json({"type": "jog", "mode": "joint", "axis": 1, "direction": 1, "speed": 10})
        while (msg := ws.receive_json())["type"] != "error":
            pass
        assert msg["message"] == "operators only: vera is a viewer"
    # EmergencyStop: one request for everyone, no confirmation, whoever holds control
    a = client(app, "alice")
    assert a.post("/api/control", json={"take": True}).status_code == 200
    assert v.post("/api/estop", json={}).status_code == 200
    deadline = time.monotonic() + 10
    while not console.snapshot().get("estop"):
        assert time.monotonic() < deadline, console.snapshot()
        time.sleep(0.05)
    assert a.post("/api/estop/reset", json={}).status_code == 200
    assert a.post("/api/control", json={"take": False}).status_code == 200


def test_one_operator_holds_control_and_the_status_names_them(env: Any) -> None:
    app, console, _ = env
    a, b = client(app, "alice"), client(app, "bob")
    assert a.post("/api/control", json={"take": True}).status_code == 200
    try:
        for path, body in [("/api/control", {"take": True}), ("/api/power", {"on": True}),
                           ("/api/control", {"take": False})]:  # fmt: skip
            r = b.post(path, json=body)
            assert r.status_code == 409 and r.json()["error"] == "alice holds control"
        assert b.get("/api/session").json()["controller"] == "alice"
        deadline = time.monotonic() + 10
        while console.snapshot().get("controller") != "alice":
            assert time.monotonic() < deadline, console.snapshot()
            time.sleep(0.05)
    finally:
        assert a.post("/api/control", json={"take": False}).status_code == 200


def test_cross_site_requests_are_refused(env: Any) -> None:
    app, console, _ = env
    a = client(app, "alice")
    csrf = a.headers["X-CSRF-Token"]
    # a page of another origin: text/plain (a "simple" no-cors request) is 415
    r = a.post("/api/control", content=b'{"take":true}', headers={"Content-Type": "text/plain"})
    assert r.status_code == 415 and "application/json" in r.json()["error"]
    form = a.post("/api/control", data={"take": "true"})  # a form POST
    assert form.status_code == 415
    r = a.post("/api/control", json={"take": True}, headers={"Origin": EVIL})
    assert r.status_code == 403 and "cross-origin" in r.json()["error"]
    for token in ("", "wrong"):
        r = a.post("/api/control", json={"take": True}, headers={"X-CSRF-Token": token})
        assert r.status_code == 403 and "CSRF" in r.json()["error"]
    with (
        pytest.raises(WebSocketDisconnect),
        a.websocket_connect(WS, headers={"Origin": EVIL}),
    ):
        pass
    assert console.controller is None and not console.in_control
    # the console's own origin is served
    with a.websocket_connect(WS, headers={"Origin": BASE}) as ws:
        assert ws.receive_json()["type"] == "status"
    r = a.post("/api/control", json={"take": False}, headers={"Origin": BASE, "X-CSRF-Token": csrf})
    assert r.status_code == 200


def test_a_host_the_console_does_not_serve_is_refused(env: Any) -> None:
    app, _, _access = env
    a = client(app, "alice")
    for path in ("/api/status", "/", "/signin"):
        r = a.get(path, headers={"Host": "evil.example"})
        assert r.status_code == 400 and "evil.example" in r.json()["error"]
    with (
        pytest.raises(WebSocketDisconnect),
        a.websocket_connect("ws://evil.example:8024/ws"),
    ):
        pass
    assert host_allowed("127.0.0.1:8024") and host_allowed("[::1]:8024")
    assert host_allowed("localhost") and host_allowed("10.0.0.7:8024")
    assert not host_allowed("evil.example:8024") and not host_allowed("")
    assert host_allowed("cell-7.plant:8024", ["cell-7.plant"])


def test_sign_in_url_works_once_and_guessing_is_slowed(env: Any) -> None:
    app, _, access = env
    token = access.sessions.token
    c = client(app)
    r = c.get(f"/signin?token={token}", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/"
    cookie = r.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and "Max-Age=43200" in cookie
    assert c.get("/api/session").json()["user"] == "token"
    again = client(app).get(f"/signin?token={token}", follow_redirects=False)
    assert again.headers["location"] == "/signin?failed=1"  # one-time
    assert access.sessions.token != token  # the next one
    g = TestClient(app, base_url=BASE, client=("10.9.9.9", 5000))
    codes = [
        g.post("/api/signin", json={"name": "alice", "password": "guess"}).status_code
        for _ in range(5)
    ]
    assert codes[:3] == [401, 401, 401] and codes[-1] == 429, codes
    lines = [json.loads(x) for x in access.audit.path.read_text().splitlines()]
    fails = [e for e in lines if e["address"] == "10.9.9.9" and e["action"] == "sign-in"]
    assert fails and all(e["outcome"].startswith("refused") for e in fails)


def test_sessions_expire(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    app, _, access = env
    a = client(app, "alice")
    assert a.get("/api/status").status_code == 200
    now = time.monotonic()
    monkeypatch.setattr(access, "clock", lambda: now + access.sessions.lifetime + 1)
    assert a.get("/api/status").status_code == 401


def test_operator_actions_are_audited_and_shown_to_operators(env: Any) -> None:
    app, _, _access = env
    a = client(app, "alice")
    assert a.post("/api/control", json={"take": True}).status_code == 200
    assert a.post("/api/power", json={"on": "yes"}).status_code == 422
    assert a.post("/api/control", json={"take": False}).status_code == 200
    entries = a.get("/api/audit").json()["entries"]
    mine = [e for e in entries if e["user"] == "alice" and e["action"] in ("control", "power")]
    assert [(e["action"], e["outcome"], e.get("request")) for e in mine[-3:]] == [
        ("control", "ok", {"take": True}),
        ("power", "refused (422)", {"on": "yes"}),
        ("control", "ok", {"take": False}),
    ]
    assert mine[-2]["error"] == "on: expected true or false"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}\+00:00", mine[-1]["time"])
    assert client(app, "vera").get("/api/audit").status_code == 403


def test_users_file_and_hashes(tmp_path: Path) -> None:
    h = hash_password("correct horse")
    assert h.startswith("scrypt$16384$8$1$") and "correct" not in h
    assert verify_password("correct horse", h) and not verify_password("wrong", h)
    assert not verify_password("x", "scrypt$broken")
    f = tmp_path / "users.json"
    assert add_user(f, "ann", "viewer", "12345678") is True
    assert add_user(f, "ann", "operator", "87654321") is False
    assert load_users(f)["ann"].role == "operator"
    with pytest.raises(UsersError, match="too short"):
        add_user(f, "bo", "operator", "short")
    f.write_text('{"users": [{"name": "x", "role": "admin", "password": "scrypt$"}]}')
    with pytest.raises(UsersError, match="role must be one of viewer, operator"):
        load_users(f)


def test_adduser_command_and_non_loopback_needs_tls(tmp_path: Path) -> None:
    users = tmp_path / "users.json"
    run = subprocess.run(
        [sys.executable, "-m", "welding", "console", "adduser", str(users), "op1",
         "--password-stdin"],
        input="a-long-password\n", capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert run.stdout == f"added operator op1 in {users}\n"
    assert verify_password("a-long-password", load_users(users)["op1"].password_hash)
    run = subprocess.run(
        [sys.executable, "-m", "welding", "console", "--emulate", "--host", "0.0.0.0",
         "--tools", str(tmp_path / "t.json"), "--jobs", str(tmp_path)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 2
    assert "--certfile" in run.stderr and "--insecure" in run.stderr
    assert not (tmp_path / "t.json").exists()  # refused before a cell was started


@pytest.mark.slow  # about 10 s: a console subprocess and curl
def test_the_issues_curl_lines_are_refused_and_the_robot_has_no_owner(tmp_path: Path) -> None:
    """The closing note's scripted check: issue 28's two curl lines."""
    log = tmp_path / "console.log"
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "welding", "console", "--emulate", "--port", "0",
             "--tools", str(tmp_path / "tools.json"), "--jobs", str(tmp_path)],
            stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not (m := re.search(r"console: http://127\.0\.0\.1:(\d+)/signin", log.read_text())):
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        port = m[1]
        robot = re.search(r"emulated cell: robot ([\d.]+):(\d+)", log.read_text())
        assert robot
        url = f"http://127.0.0.1:{port}"
        lines = [
            ["curl", "-sS", "-i", "-X", "POST", "-H", "Content-Type: text/plain",
             "-H", "Origin: http://evil.example", "-H", "Host: evil.example",
             "--data", '{"take":true}', f"{url}/api/control"],
            ["curl", "-sS", "-i", "-X", "POST", "-H", "Content-Type: text/plain",
             "-H", "Origin: http://evil.example", "--data", '{"on":true}', f"{url}/api/power"],
        ]  # fmt: skip
        replies = [subprocess.run(c, capture_output=True, text=True, timeout=30) for c in lines]
        for reply in replies:
            print(reply.stdout)
        assert replies[0].stdout.startswith("HTTP/1.1 400")
        assert "Host evil.example is not served here" in replies[0].stdout
        assert replies[1].stdout.startswith("HTTP/1.1 403")
        assert "cross-origin request from http://evil.example refused" in replies[1].stdout
        with RobotClient(robot[1], int(robot[2]), timeout=10, client_name="observer") as r:
            st = r.status()
            assert not st.controlled and not st.powered
        assert log.read_text().count("refused POST") == 2
    finally:
        proc.terminate()
        proc.wait(20)


def _console_banner(command: list[str], log: Path) -> tuple[subprocess.Popen[bytes], str]:
    with log.open("w") as out:
        proc = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while not (m := re.search(r"console: (\S+/signin\?token=\S+)", log.read_text())):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.fail(log.read_text())
        time.sleep(0.1)
    return proc, m[1]


@pytest.mark.slow  # about 10 s: two consoles
def test_tls_serves_https_and_insecure_warns(tmp_path: Path) -> None:
    import ssl
    import urllib.request

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj",
         "/CN=127.0.0.1", "-keyout", str(key), "-out", str(cert)],
        check=True, capture_output=True, timeout=60,
    )  # fmt: skip
    common = ["--emulate", "--port", "0", "--tools", str(tmp_path / "t.json"), "--jobs",
              str(tmp_path)]  # fmt: skip
    proc, url = _console_banner(
        [sys.executable, "-m", "welding", "console", *common, "--certfile", str(cert),
         "--keyfile", str(key)],
        tmp_path / "tls.log",
    )  # fmt: skip
    try:
        assert url.startswith("https://127.0.0.1:")
        ctx = ssl.create_default_context(cafile=str(cert))
        ctx.check_hostname = False
        with urllib.request.urlopen(url, context=ctx, timeout=10) as r:
            assert r.status == 200 and b"24-Laser" in r.read()
    finally:
        proc.terminate()
        proc.wait(20)
    proc, url = _console_banner(
        [sys.executable, "-m", "welding", "console", *common, "--host", "0.0.0.0", "--insecure"],
        tmp_path / "insecure.log",
    )  # fmt: skip
    try:
        assert url.startswith("http://0.0.0.0:")
        assert (
            "--insecure: serving plain http on 0.0.0.0" in (tmp_path / "insecure.log").read_text()
        )
    finally:
        proc.terminate()
        proc.wait(20)
