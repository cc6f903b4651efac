"""The console as a controller that fails: ``python -m welding console`` in its own process
against an emulated cell in another, a jog held over its WebSocket, then the console frozen
(SIGSTOP), killed (SIGKILL) or interrupted (SIGINT). The arm always comes to a controlled stop;
thawed, the console says control was lost, runs no jog, and can take control again."""

from __future__ import annotations

import http.cookiejar
import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest

pytest.importorskip("starlette", reason="the console extra is not installed")
ws_client = pytest.importorskip("websockets.sync.client", reason="the console extra is missing")

from robotsocket.client import RobotClient  # noqa: E402

T = TypeVar("T")


def _until(what: str, get: Callable[[], T], ok: Callable[[T], bool], timeout: float) -> T:
    """Poll ``get`` until ``ok`` holds; fail naming ``what`` and the last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = get()
        if ok(value):
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"{what} not within {timeout} s; last: {value!r}")
        time.sleep(0.05)


class Console:
    """The emulated cell (``python -m cell serve``, real-time clock) and the console against it,
    each in its own process as on the shop floor: its URL, the robot's address, its HTTP API."""

    def __init__(self, tmp: Path) -> None:
        self.log = tmp / "console.log"
        self.cell = subprocess.Popen(
            [sys.executable, "-m", "cell", "serve", "--clock", "real", "--robot-port", "0",
             "--sensor-port", "0", "--udp-port", "0"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        assert self.cell.stdout is not None
        described: dict[str, str] = {}
        while "true_delta_t_ms" not in described:
            line = self.cell.stdout.readline()
            assert line, "the cell ended before describing itself"
            key, _, value = line.partition(":")
            described[key.strip()] = value.strip()
        host, port = described["robot"].rsplit(":", 1)
        self.robot = (host, int(port))
        with self.log.open("w") as out:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "welding", "console", "--robot", described["robot"],
                 "--sensor", described["sensor"], "--port", "0",
                 "--tools", str(tmp / "tools.json"), "--jobs", str(tmp)],
                stdout=out, stderr=subprocess.STDOUT,
            )  # fmt: skip
        text = _until(
            "the console's banner",
            lambda: self.log.read_text(errors="replace"),
            lambda t: "console: http" in t or self.proc.poll() is not None,
            60.0,
        )
        url = re.search(r"console: (http://\S+/)signin\?token=(\S+)", text)
        assert url, text
        self.url = url[1]
        # signed in with the printed one-time URL, as the operator at the terminal does
        self.cookies = http.cookiejar.CookieJar()
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(self.cookies))
        self.opener.open(f"{self.url}signin?token={url[2]}", timeout=10).close()
        self.csrf = self.api("GET", "session")["csrf"]

    def cookie(self) -> str:
        """The session cookie, for the WebSocket handshake."""
        return "; ".join(f"{c.name}={c.value}" for c in self.cookies)

    def api(self, method: str, path: str, body: Any = None) -> Any:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(
            self.url + "api/" + path, data=data, method=method,
            headers={"Content-Type": "application/json",
                     "X-CSRF-Token": getattr(self, "csrf", "")},
        )  # fmt: skip
        with self.opener.open(req, timeout=10) as r:
            return json.loads(r.read())

    def close(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGCONT)  # a frozen one first thaws
        for proc in (self.proc, self.cell):
            proc.terminate()
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        print("--- the console's log ---\n" + self.log.read_text(errors="replace"))


@pytest.fixture
def console(tmp_path: Path) -> Iterator[Console]:
    c = Console(tmp_path)
    try:
        yield c
    finally:
        c.close()


@pytest.mark.slow  # about 6 s each
@pytest.mark.parametrize(
    "sig", [signal.SIGSTOP, signal.SIGKILL, signal.SIGINT], ids=lambda s: s.name
)
def test_a_console_that_freezes_dies_or_is_stopped_mid_jog_stops_the_arm(
    console: Console, sig: signal.Signals
) -> None:
    """Frozen: the robot's watchdog takes control away; killed: its connection closes; Ctrl-C:
    it stops its jog and releases control itself. Each time a controlled stop, far from where
    the jog was heading."""
    console.api("POST", "control", {"take": True})
    console.api("POST", "power", {"on": True})
    _until("power on", lambda: console.api("GET", "status"), lambda s: s["powered"], 10.0)
    with RobotClient(*console.robot, timeout=10.0, client_name="observer") as observer:
        start = float(observer.herej()[0])
        ws_url = console.url.replace("http://", "ws://") + "ws"
        with ws_client.connect(
            ws_url, open_timeout=10, additional_headers={"Cookie": console.cookie()}
        ) as ws:
            ws.send(json.dumps({"type": "jog", "mode": "joint", "axis": 1, "direction": 1,
                                "speed": 5}))  # fmt: skip

            def held_status() -> Any:
                ws.send(json.dumps({"type": "hold"}))  # the operator keeps the button down
                return observer.status()

            _until("the jog", held_status, lambda s: s.moving, 10.0)
            os.kill(console.proc.pid, sig)  # with the button still held
            _until(
                "a stop without control",
                observer.status,
                lambda s: not s.moving and not s.controlled,
                15.0,
            )
            moved = float(observer.herej()[0]) - start
            # jogging on, J1 would have gone to its limit (~155 degrees) at ~18 deg/s
            assert 0.0 < moved < 60.0, f"J1 moved {moved:.1f} degrees"
            if sig != signal.SIGSTOP:
                code = console.proc.wait(20)
                # Ctrl-C: "interrupted", as every welding command (docs/WELDING.md)
                assert code == (130 if sig == signal.SIGINT else -sig)
                return
            os.kill(console.proc.pid, signal.SIGCONT)
            thawed = _until(
                "the thawed console's status",
                lambda: console.api("GET", "status"),
                lambda s: s["owner"] in ("lost", "nobody") and not s["jogging"],
                15.0,
            )
            assert not thawed["moving"]
    # thawed, the operator takes control again: the console works on
    console.api("POST", "control", {"take": True})
    _until(
        "control again",
        lambda: console.api("GET", "status"),
        lambda s: s["owner"] == "console",
        10.0,
    )
