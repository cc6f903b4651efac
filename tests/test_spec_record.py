"""Recording sessions: the client's ``record=`` and ``python -m spec record`` (a real proxy
subprocess between a real client and a real server), SIGTERM and SIGKILL, the UDP relay."""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from robotsocket.client import NotInControlError, RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.codec import FrameDecoder, Packet
from spec.pcapng import partial_path, read_capture, sessions
from spec.server import FramedServer
from spec.wire import PacketKind

if TYPE_CHECKING:
    from tests.conftest import BusyPort, Serve

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def robot_server(serve: Serve) -> FramedServer:
    return serve(RobotService(RobotEmulator()), None)


def frames(data: bytes) -> list[Packet]:
    decoder = FrameDecoder()
    decoder.feed(data)
    out = []
    for event in decoder.events():
        assert isinstance(event, Packet), event
        out.append(event)
    assert decoder.buffered == 0
    return out


def a_session(client: RobotClient) -> None:
    client.hello()
    client.herej()
    client.ping(b"x" * 100_000)  # a frame longer than one synthesized segment
    with pytest.raises(NotInControlError):
        client.joint_move((10.0, 0.0, 0.0, 0.0, 0.0, 0.0))


def check_recording(path: Path, server: tuple[str, int]) -> None:
    streams, _ = sessions(read_capture(path))
    assert len(streams) == 1
    (s,) = streams
    assert s.b[1] == server[1]  # the client opened it: a is the client
    requests, replies = frames(s.bytes_from(True)), frames(s.bytes_from(False))
    assert [p.kind for p in requests] == [PacketKind.REQUEST] * 4
    assert [p.kind for p in replies] == [PacketKind.REPLY] * 3 + [PacketKind.ERROR]
    assert [p.request_id for p in replies] == [p.request_id for p in requests]
    assert replies[2].params == (b"x" * 100_000,)


def test_the_client_records_its_connection(robot_server: FramedServer, tmp_path: Path) -> None:
    path = tmp_path / "client.pcapng"
    with RobotClient(*robot_server.address, record=path) as client:
        a_session(client)
        assert partial_path(path).exists() and not path.exists()
    assert path.exists() and not partial_path(path).exists()
    check_recording(path, robot_server.address)
    assert "127.0.0.1:" in read_capture(path).comments[0]


@pytest.fixture
def proxy(
    robot_server: FramedServer, tmp_path: Path
) -> Iterator[tuple[subprocess.Popen[str], int]]:
    host, port = robot_server.address
    cmd = [sys.executable, "-m", "spec", "record", "--listen", "0", "--to", f"{host}:{port}",
           "-o", str(tmp_path / "proxy.pcapng")]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    assert first.startswith("listening on 127.0.0.1:"), first + proc.stderr.read()
    listen_port = int(first.split()[2].rsplit(":", 1)[1].rstrip(","))
    yield proc, listen_port
    if proc.poll() is None:
        proc.kill()
    proc.wait(10)


def test_the_proxy_records_and_ends_on_sigterm(
    proxy: tuple[subprocess.Popen[str], int], robot_server: FramedServer, tmp_path: Path
) -> None:
    proc, port = proxy
    with RobotClient("127.0.0.1", port, timeout=10) as client:
        a_session(client)
        assert client.hello()["service"] == "robot"  # the same server, through the proxy
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    path = tmp_path / "proxy.pcapng"
    assert "recorded 1 connections" in out and path.exists()
    assert not partial_path(path).exists()
    # the Hello after the session is in there too: five requests
    streams, _ = sessions(read_capture(path))
    assert len(frames(streams[0].bytes_from(True))) == 5
    comment = read_capture(path).comments[0]
    assert f"relayed to 127.0.0.1:{robot_server.address[1]}" in comment


def test_a_killed_proxy_leaves_a_readable_file(
    proxy: tuple[subprocess.Popen[str], int], robot_server: FramedServer, tmp_path: Path
) -> None:
    proc, port = proxy
    client = RobotClient("127.0.0.1", port, timeout=10)
    a_session(client)
    # the proxy recorded each reply before passing it on: the file holds them all by now
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    client.close()
    part = partial_path(tmp_path / "proxy.pcapng")
    assert part.exists() and not (tmp_path / "proxy.pcapng").exists()
    check_recording(part, robot_server.address)
    tshark = shutil.which("tshark")
    if tshark is None:
        print("TSHARK NOT INSTALLED: the killed file was checked by our reader only")
        return
    r = subprocess.run([tshark, "-r", str(part)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.splitlines()) >= 11  # handshake and the eight data segments


def test_the_udp_relay_goes_both_ways(robot_server: FramedServer, tmp_path: Path) -> None:
    echo = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    echo.bind(("127.0.0.1", 0))
    echo.settimeout(10)

    def answer() -> None:
        data, source = echo.recvfrom(100)
        echo.sendto(data.upper(), source)

    t = threading.Thread(target=answer, daemon=True)
    t.start()
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    free = probe.getsockname()[1]
    probe.close()
    host, port = robot_server.address
    path = tmp_path / "udp.pcapng"
    cmd = [sys.executable, "-m", "spec", "record", "--listen", "0", "--to", f"{host}:{port}",
           "-o", str(path), "--udp", f"{free}:127.0.0.1:{echo.getsockname()[1]}"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        lines = [proc.stdout.readline() for _ in range(3)]
        assert lines[1].startswith(f"UDP 127.0.0.1:{free} relayed"), lines
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sender.settimeout(10)
        sender.sendto(b"trigger", ("127.0.0.1", free))
        assert sender.recvfrom(100)[0] == b"TRIGGER"
        sender.close()
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
        echo.close()
    _, datagrams = sessions(read_capture(path))
    assert [d.payload for d in datagrams] == [b"trigger", b"TRIGGER"]
    assert datagrams[0].dst == datagrams[1].src  # the echo server's address, both times


def test_bad_arguments_are_one_line_and_exit_2(busy_port: BusyPort, tmp_path: Path) -> None:
    taken = busy_port(False)
    for args in (
        ["--listen", str(taken), "--to", "127.0.0.1:1", "-o", str(tmp_path / "x.pcapng")],
        ["--listen", "0", "--to", "127.0.0.1:1", "-o", str(tmp_path)],
        ["--listen", "0", "--to", "127.0.0.1:1", "-o", "x", "--udp", "nonsense"],
    ):
        r = subprocess.run([sys.executable, "-m", "spec", "record", *args], cwd=ROOT,
                           capture_output=True, text=True, timeout=30)  # fmt: skip
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert not list(tmp_path.iterdir())


def test_a_background_recorder_ends_on_sigint(robot_server: FramedServer, tmp_path: Path) -> None:
    # `spec record … &` in a script starts with SIGINT ignored; `kill -INT` must still end it
    host, port = robot_server.address
    cmd = [sys.executable, "-m", "spec", "record", "--listen", "0", "--to", f"{host}:{port}",
           "-o", str(tmp_path / "bg.pcapng")]  # fmt: skip
    ignore_sigint = lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)  # noqa: E731
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=ignore_sigint)  # fmt: skip
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("listening on")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert (tmp_path / "bg.pcapng").exists() and not partial_path(tmp_path / "bg.pcapng").exists()
