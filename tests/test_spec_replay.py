"""``python -m spec replay``: a recorded session sent again to real servers (subprocess CLI),
the same one, one with a planted difference, a slow one; and the comparison rules."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from robotsocket.client import NotInControlError, RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.codec import Packet, error_packet
from spec.errors import ErrorCode
from spec.exitcodes import ExitCode
from spec.messages import Request
from spec.params import Joints, Value
from spec.registry import CommandId
from spec.replay import compare
from spec.server import FramedServer, SessionView
from spec.wire import PacketKind

if TYPE_CHECKING:
    from tests.conftest import Serve

ROOT = Path(__file__).resolve().parents[1]


class Planted(RobotService):
    """A robot whose Herej reply is off by 0.5° on joint 2, or late by ``delay`` seconds."""

    def __init__(self, offset: float = 0.5, delay: float = 0.0) -> None:
        super().__init__(RobotEmulator())
        self.offset, self.delay = offset, delay

    def handle(self, session: SessionView, request: Request[Any]) -> tuple[Value, ...]:
        reply = super().handle(session, request)
        if request.command != CommandId.HEREJ:
            return reply
        time.sleep(self.delay)  # the planted slowness itself, not a wait in the test
        (joints,) = reply
        assert isinstance(joints, Joints)
        values = list(joints.values)
        values[1] += self.offset
        return (Joints(values),)


def addr(server: FramedServer) -> str:
    return "{}:{}".format(*server.address)


def record(address: tuple[str, int], path: Path) -> Path:
    with RobotClient(*address, record=path) as c:
        c.hello()
        c.status()
        c.herej()
        c.get_time()
        c.here()
        with pytest.raises(NotInControlError):
            c.joint_move((10.0, 0.0, 90.0, 0.0, 0.0, 0.0))
    return path


def replay(path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "spec", "replay", str(path), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)  # fmt: skip


def test_replay_against_the_same_server_finds_nothing(serve: Serve, tmp_path: Path) -> None:
    server = serve(RobotService(RobotEmulator()), None)
    path = record(server.address, tmp_path / "s.pcapng")
    r = replay(path, "--robot", addr(server), "--allow-motion", "-v")
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.splitlines()[-1] == "6 requests: 6 as recorded, 0 different"
    assert "#3 Herej id=3: as recorded" in r.stdout
    assert "not compared (clock readings): GetStatus.time, GetTime.time" in r.stdout


def test_replay_names_the_request_whose_reply_changed(serve: Serve, tmp_path: Path) -> None:
    path = record(serve(RobotService(RobotEmulator()), None).address, tmp_path / "s.pcapng")
    planted = serve(Planted(), None)
    r = replay(path, "--robot", addr(planted), "--allow-motion")
    assert r.returncode == 1, r.stdout + r.stderr
    lines = r.stdout.splitlines()
    (i,) = [i for i, line in enumerate(lines) if "DIFFERS" in line]
    assert lines[i].startswith("  #3 Herej id=3: DIFFERS")
    assert (
        lines[i + 1].strip() == "joints: recorded [0, 0, 90, 0, 90, 0], now [0, 0.5, 90, 0, 90, 0]"
    )
    assert lines[-1] == "6 requests: 5 as recorded, 1 different"


def test_replay_flags_an_answer_slower_than_recorded(serve: Serve, tmp_path: Path) -> None:
    path = record(serve(RobotService(RobotEmulator()), None).address, tmp_path / "s.pcapng")
    slow = serve(Planted(offset=0.0, delay=0.6), None)
    r = replay(path, "--robot", addr(slow), "--allow-motion", "--time-tolerance", "0.3")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "#3 Herej id=3: DIFFERS" in r.stdout and "(tolerance 300 ms)" in r.stdout
    assert r.stdout.splitlines()[-1] == "6 requests: 5 as recorded, 1 different"


def test_motion_needs_opt_in_and_bad_input_is_one_line(serve: Serve, tmp_path: Path) -> None:
    server = serve(RobotService(RobotEmulator()), None)
    path = record(server.address, tmp_path / "s.pcapng")
    r = replay(path, "--robot", addr(server))
    assert r.returncode == 2 and "(JointMove)" in r.stderr and "--allow-motion" in r.stderr
    garbage = tmp_path / "x.pcapng"
    garbage.write_text("nothing")
    for args, code in (
        ([str(garbage), "--robot", "127.0.0.1:1"], 2),
        ([str(path)], 2),
        ([str(path), "--sensor", "127.0.0.1:1"], 2),  # a robot session: nothing for a sensor
        ([str(path), "--robot", "127.0.0.1:1", "--allow-motion"], 3),  # nobody listening
    ):
        r = subprocess.run([sys.executable, "-m", "spec", "replay", *args], cwd=ROOT,
                           capture_output=True, text=True, timeout=60)  # fmt: skip
        assert r.returncode == code, (args, r.stdout, r.stderr)
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr


def reply(*params: Value) -> Packet:
    return Packet(PacketKind.REPLY, CommandId.GET_TIME, 1, params)


@pytest.mark.parametrize(
    ("recorded", "now", "expected"),
    [
        (reply(1.0), reply(2.0), []),  # GetTime.time: a clock reading, not compared
        (error_packet(5, 1, ErrorCode.BUSY, "a"), error_packet(5, 1, ErrorCode.BUSY, "b"), []),
        (error_packet(5, 1, ErrorCode.BUSY, ""), error_packet(5, 1, ErrorCode.NOT_POWERED, ""),
         ["error code: recorded BUSY, now NOT_POWERED"]),
        (reply(1.0), error_packet(5, 1, ErrorCode.BUSY, "held"),
         ["recorded reply, now error BUSY (held)"]),
        (reply(1.0), None, ["recorded reply, now no answer"]),
        (reply(1.0), reply(1.0, 2), ["1 parameters recorded, now 2"]),
    ],
)  # fmt: skip
def test_compare(recorded: Packet, now: Packet | None, expected: list[str]) -> None:
    assert compare(recorded, now, CommandId.GET_TIME, 1e-6) == expected


def test_compare_floats_within_the_tolerance() -> None:
    def herej(*values: float) -> Packet:
        return Packet(PacketKind.REPLY, CommandId.HEREJ, 1, (Joints(values),))

    assert compare(herej(1.0, 2.0), herej(1.0 + 1e-9, 2.0), CommandId.HEREJ, 1e-6) == []
    assert compare(herej(1.0, 2.0), herej(1.1, 2.0), CommandId.HEREJ, 1e-6) == [
        "joints: recorded [1, 2], now [1.1, 2]"
    ]
    assert compare(herej(1.0), herej(1.1), CommandId.HEREJ, 1e-6, frozenset({"Herej.joints"})) == []


def conformance(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "conformance", "robot", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def test_conformance_runs_a_recording_as_a_case(serve: Serve, tmp_path: Path) -> None:
    path = record(serve(RobotService(RobotEmulator()), None).address, tmp_path / "field.pcapng")
    same = serve(RobotService(RobotEmulator()), None)
    only = ("--select", "replay.*", "-v")
    r = conformance(addr(same), "--replay", str(path), "--allow-motion", *only)
    # SUBSET: the emulated robot claims every profile but sync (the summary's scope: line)
    assert r.returncode == ExitCode.SUBSET, r.stdout + r.stderr
    assert "pass           replay.field" in r.stderr
    assert "6 requests over 1 connection: every answer as recorded" in r.stdout
    # a field failure turned into a regression test: the changed answer fails the case
    r = conformance(addr(serve(Planted(), None)), "--replay", str(path), "--allow-motion", *only)
    assert r.returncode == ExitCode.FAILED, r.stdout + r.stderr
    assert "fail           replay.field" in r.stderr
    assert "#3 Herej id=3: joints: recorded [0, 0, 90, 0, 90, 0], now [0, 0.5" in r.stdout
    # the recording moves the arm: without --allow-motion the case is skipped, not run
    r = conformance(addr(same), "--replay", str(path), *only)
    assert "skipped        replay.field" in r.stderr, r.stdout + r.stderr
    for bad in (str(tmp_path / "missing.pcapng"), str(ROOT / "README.md")):
        r = conformance(addr(same), "--replay", bad)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith("conformance: --replay: "), r.stderr
