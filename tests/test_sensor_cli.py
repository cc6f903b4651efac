"""``python -m sensorsocket``: the server in a real subprocess (serve on port 0, UDP, graceful
SIGTERM, exit code 3 when unreachable); call, snapshot and the one-line usage errors with exit
code 2 through the same ``main()`` in-process, which spares an interpreter start-up (~0.5 s
on this machine) per command."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from sensorsocket.__main__ import main
from sensorsocket.pgm import read_pgm
from spec.datagrams import SensorData, Trigger, decode_datagram, encode_trigger
from spec.wire import SensorStatus

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def cli(*args: str, timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [PY, "-m", "sensorsocket", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
    )


def _serving_line(proc: subprocess.Popen[str]) -> str:
    """The server's "serving tcp … udp …" line: logged once it is up and stops cleanly on a
    signal (the start-up lines before it are skipped). A server silent for 20 s is killed."""
    assert proc.stderr is not None
    watchdog = threading.Timer(20.0, proc.kill)  # readline buffers: select() cannot tell
    watchdog.start()
    try:
        while line := proc.stderr.readline():
            if "serving tcp" in line:
                return line
    finally:
        watchdog.cancel()
    raise AssertionError("the server ended or stayed silent before it said it was serving")


class Served:
    def __init__(self, proc: subprocess.Popen[str], tcp: str, udp: tuple[str, int]) -> None:
        self.proc, self.tcp, self.udp = proc, tcp, udp


@pytest.fixture(scope="module")
def served() -> Iterator[Served]:
    proc = subprocess.Popen(
        [PY, "-m", "sensorsocket", "serve", "--port", "0", "--udp-port", "auto",
         "--clock", "sim", "--joint", "lap", "--seed", "7"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )  # fmt: skip
    assert proc.stderr is not None
    try:
        first = _serving_line(proc)
        m = re.search(r"tcp ([\d.]+):(\d+) udp ([\d.]+):(\d+)", first)
        assert m, first
        yield Served(proc, f"{m[1]}:{m[2]}", (m[3], int(m[4])))
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


class Ran:
    def __init__(self, returncode: int, stdout: str, stderr: str) -> None:
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture
def run(capsys: pytest.CaptureFixture[str]) -> Callable[..., Ran]:
    """``run(*argv)``: ``main(argv)`` in-process, with its exit code and captured output."""

    def go(*argv: str) -> Ran:
        capsys.readouterr()
        try:
            code = main(list(argv))
        except SystemExit as exc:  # argparse's exit, as the process would end
            code = exc.code if isinstance(exc.code, int) else 1
        out, err = capsys.readouterr()
        return Ran(code, out, err)

    return go


@pytest.fixture
def call(served: Served, run: Callable[..., Ran]) -> Callable[..., dict[str, object]]:
    def go(*args: str) -> dict[str, object]:
        r = run("call", served.tcp, *args)
        assert r.returncode == 0, r.stderr
        out = json.loads(r.stdout)
        assert isinstance(out, dict)
        return out

    return go


def test_call_acquire_and_get_data(call: Callable[..., dict[str, object]]) -> None:
    assert call("GetSettings")["columns"] == 512
    index = call("Acquire")["index"]
    data = call("GetData")
    assert data["index"] == index and data["status"] == int(SensorStatus.FOUND)
    seam = data["seam"]
    assert isinstance(seam, dict) and abs(seam["y"]) < 0.05 and abs(seam["z"]) < 0.05
    assert call("SetReadoutWindow", "0", "256") == {"acquisition_time": 0.00175}
    call("SetReadoutWindow", "0", "512")


def test_get_data_with_the_laser_off_says_so_and_how_to_switch_it_on(
    served: Served, run: Callable[..., Ran]
) -> None:
    # [SS-5.13] the case: status 2 alone read as "no seam"
    assert run("call", served.tcp, "SetLaser", "off").returncode == 0
    try:
        assert run("call", served.tcp, "Acquire").returncode == 0
        r = run("call", served.tcp, "GetData")
        assert r.returncode == 0 and json.loads(r.stdout)["status"] == int(SensorStatus.LASER_OFF)
        assert r.stderr == (
            "note: the sensor's laser is off (status LASER_OFF): switch it on with "
            f"`python -m sensorsocket call {served.tcp} SetLaser on --token-file FILE`\n"
        )
    finally:
        assert run("call", served.tcp, "SetLaser", "on").returncode == 0
    run("call", served.tcp, "Acquire")
    assert run("call", served.tcp, "GetData").stderr == ""


def test_call_errors(served: Served, run: Callable[..., Ran]) -> None:
    r = run("call", served.tcp, "SetReadoutWindow", "500", "100")
    assert r.returncode == 1 and r.stderr.startswith("error OUT_OF_RANGE")
    r = run("call", served.tcp, "NoSuchCommand")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_snapshot_writes_the_frame(served: Served, tmp_path: Path, run: Callable[..., Ran]) -> None:
    out = tmp_path / "frame.pgm"
    r = run("snapshot", served.tcp, "-o", str(out), "--acquire")
    assert r.returncode == 0, r.stderr
    image = np.asarray(read_pgm(out), dtype=np.uint8)
    assert image.shape == (256, 512) and read_pgm(out).dtype == np.uint8
    assert image.max() > 100 and np.median(image) < 30  # a bright stripe on a dark chip
    assert [p.name for p in tmp_path.iterdir()] == ["frame.pgm"]  # no temporary left
    assert "readout window" not in r.stdout


def test_snapshot_creates_a_missing_folder(
    served: Served, tmp_path: Path, run: Callable[..., Ran]
) -> None:
    """[issue 35 item 8] ``snapshot -o sub/f.pgm`` refused a missing folder while ``sync
    delay --json nodir/d.json`` created it: one rule now (spec/files.py), the folder made."""
    out = tmp_path / "sub" / "deeper" / "frame.pgm"
    r = run("snapshot", served.tcp, "-o", str(out), "--acquire")
    assert r.returncode == 0, r.stderr
    assert read_pgm(out).shape == (256, 512)


def test_snapshot_a_file_that_cannot_be_written_is_one_line(served: Served) -> None:
    # /proc takes no new files: refused before the call (not writable) or when writing
    done = cli("snapshot", served.tcp, "-o", "/proc/frame.pgm")
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.splitlines()) == 1
    assert "/proc" in done.stderr and ".tmp" not in done.stderr


def test_snapshot_says_a_readout_window_is_in_force(
    served: Served, tmp_path: Path, run: Callable[..., Ran], call: Callable[..., dict[str, object]]
) -> None:
    call("SetReadoutWindow", "128", "256")
    try:
        r = run("snapshot", served.tcp, "-o", str(tmp_path / "frame.pgm"), "--acquire")
    finally:
        call("SetReadoutWindow", "0", "512")
    assert r.returncode == 0, r.stderr
    assert "readout window in force: columns 128..383 of 512" in r.stdout


def test_udp_trigger_through_the_cli_server(served: Served) -> None:
    robot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    robot.settimeout(5.0)
    try:
        robot.sendto(encode_trigger(Trigger(42, 3.25)), served.udp)
        raw, _ = robot.recvfrom(2048)
    finally:
        robot.close()
    d = decode_datagram(raw)
    assert isinstance(d, SensorData) and (d.index, d.t_trigger) == (42, 3.25)
    assert d.status is SensorStatus.FOUND
    assert d.t_arrival <= d.t_exposure_start <= d.t_exposure_end


@pytest.mark.parametrize(
    "args",
    [
        ["serve", "--joint", "spiral"],
        ["serve", "--port", "70000"],
        ["serve", "--udp-port", "x"],
        ["serve", "--allow", "not-a-net"],
        ["serve", "--motion", "sine:2"],
        ["serve", "--token-file", "/nonexistent/token"],
        ["call", "127.0.0.1:notaport", "GetData"],
        ["call", "127.0.0.1:1", "SetLaser", "maybe"],
        ["snapshot", "127.0.0.1:1", "-o", "frame.jpg"],
        ["snapshot", "127.0.0.1:1"],
        ["frobnicate"],
        [],
    ],
)
def test_bad_arguments_one_line_exit_2(args: list[str], run: Callable[..., Ran]) -> None:
    r = run(*args)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr


def test_unreachable_server_exit_3() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, not listening: connection refused
        r = cli("call", f"127.0.0.1:{port}", "GetStatus")
    assert r.returncode == 3 and len(r.stderr.strip().splitlines()) == 1


def _stop_with(signals: tuple[signal.Signals, ...], timeout: float) -> tuple[int, str]:
    """Start a sensor server, send it ``signals`` once it serves: its exit code and stderr."""
    proc = subprocess.Popen(
        [PY, "-m", "sensorsocket", "serve", "--port", "0", "--udp-port", "off"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    assert proc.stderr is not None
    try:
        assert "udp off" in _serving_line(proc)
        for sig in signals:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


def test_sigterm_stops_gracefully() -> None:
    code, err = _stop_with((signal.SIGTERM,), timeout=10)
    assert code == 130, err  # as every tool ends on Ctrl-C or SIGTERM (docs/CLI.md)
    assert (
        err.rstrip().splitlines()[-1]
        == "python -m sensorsocket: interrupted: laser off, server closed"
    )
    assert "SIGTERM" in err and "stopped" in err and "Traceback" not in err


def test_a_second_signal_during_the_shutdown_is_not_a_traceback() -> None:
    """SIGINT then SIGTERM at once (an impatient operator): one clean stop, exit 130.

    Either may be handled first: two threads can take the two signals at the same moment,
    and the main thread runs whichever handler is pending when it looks (seen in CI)."""
    code, err = _stop_with((signal.SIGINT, signal.SIGTERM), timeout=20)
    assert code == 130, err
    assert len(re.findall(r"received SIG(?:INT|TERM), shutting down", err)) == 1, err
    assert "stopped" in err and "Traceback" not in err, err


def test_allow_list_applies_to_tcp_and_udp() -> None:
    """--allow 10.0.0.0/8: a loopback client is closed unread on TCP, its trigger is dropped
    unanswered on UDP, and the stop statistics count it [RS-7.7]."""
    proc = subprocess.Popen(
        [PY, "-m", "sensorsocket", "serve", "--port", "0", "--udp-port", "auto",
         "--clock", "sim", "--allow", "10.0.0.0/8"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )  # fmt: skip
    assert proc.stderr is not None
    try:
        m = re.search(r"tcp ([\d.]+):(\d+) udp ([\d.]+):(\d+)", _serving_line(proc))
        assert m
        with socket.create_connection((m[1], int(m[2])), timeout=5.0) as tcp:
            assert tcp.recv(100) == b""  # closed before any byte is read or sent
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.settimeout(0.5)
            udp.sendto(encode_trigger(Trigger(1, 1.0)), (m[3], int(m[4])))
            with pytest.raises(TimeoutError):
                udp.recvfrom(2048)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert '"refused_address": 1' in err
