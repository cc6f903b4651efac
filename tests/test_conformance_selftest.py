"""The harness tests itself: small conforming servers score 100 %, and deliberately broken
servers are caught by the case IDs each test names. A hanging or crashing server gives
timeout or error, never fail.

The conforming servers here are minimal :class:`spec.server.Service` implementations (no
motion), independent of robotsocket/sensorsocket; the broken ones override one hook each, or
are tiny raw-socket servers for framing-level breakage.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import socket
import statistics
import struct
import threading
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Literal

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.context import Options
from conformance.model import Outcome
from conformance.runner import RunResult, Selection, exit_code, run
from kinematics.transforms import concat, invert, location_to_transform, transform_to_location
from spec import messages as M
from spec import wire
from spec.auth import AuthBackoff
from spec.codec import FrameDecoder, Packet, Rejected, decode_packet, encode_packet
from spec.control import Admission, Slots
from spec.datagrams import SensorData, Trigger, decode_datagram, encode_data, encode_trigger
from spec.errors import DatagramError, ErrorCode, ProtocolError
from spec.exitcodes import ExitCode
from spec.messages import RobotStatusReply
from spec.params import Image, Joints, Location, Matrix, Value
from spec.registry import BY_ID, check_params, commands_for, profiles_for
from spec.registry import CommandId as C
from spec.server import FramedServer, Identity, ServerPolicy, Service, Session, SessionView
from spec.wire import PacketKind, SensorStatus

SCALE = 0.1  # --timeout-scale of these tests: answers within 0.2 s, budgets a tenth
POLICY = ServerPolicy(
    max_clients=16, max_per_address=15, max_payload=64 * 1024, frame_timeout=0.3, idle_timeout=1.0
)

# --- minimal conforming services ------------------------------------------------------------


class MiniRobot(Service):
    """A robot service without motion: status, joints, Here, motion descriptor, I/O, log."""

    identity = Identity("robot", vendor="test", model="mini-robot", serial="1")
    COMMANDS: tuple[C, ...] = (
        C.ROBOT_STATUS,
        C.HEREJ,
        C.HERE,
        C.SET_MOTION_DESC,
        C.GET_MOTION_DESC,
        C.WAIT_END_MOVE,
        C.STOP_MOVE,
        C.RESET_MOTION,
        C.READ_IO,
        C.LIST_IO,
        C.GET_JOINT_LOG,
        C.GET_JOINT_LIMITS,
    )

    def __init__(self) -> None:
        self.q = [5.0, -10.0, 90.0, 0.0, 45.0, 0.0]
        self.mdesc = [10.0, 10.0, 10.0, 250.0, 45.0, 0.0]
        self.outputs = {"laser": False, "gas": False}
        self.inputs = {"ready": True}
        self.t0 = time.monotonic()

    def implemented(self) -> tuple[int, ...]:
        return tuple(int(c) for c in self.COMMANDS)

    def flange(self) -> Any:
        # Any smooth function of the joints will do for Here's frame algebra.
        q = self.q
        return location_to_transform([400 + q[0], q[1], 600 + q[2], q[3], q[4] + 90, q[5]])

    def handle(  # noqa: C901  a fake server: one branch per command it answers
        self, session: SessionView, request: M.Request[Any]
    ) -> tuple[Value, ...]:
        c, now = request.command, self.clock()
        if c == C.ROBOT_STATUS:
            mine, held = session.in_control, session.control_held
            return RobotStatusReply(False, False, False, 0, mine, held, 0, "", now).encode()
        if c == C.HEREJ:
            return (Joints(self.q),)
        if isinstance(request, M.HereRequest):
            t = concat(
                invert(location_to_transform(request.frame.as_tuple())),
                self.flange(),
                location_to_transform(request.tool.as_tuple()),
            )
            return (Location.of(transform_to_location(t)),)
        if c == C.GET_MOTION_DESC:
            return tuple(self.mdesc)
        if isinstance(request, M.SetMotionDescRequest):
            v = [float(x) for x in request.as_dict().values()]
            if not (all(0 < x <= 100 for x in v[:3]) and v[3] > 0 and v[4] > 0 and v[5] >= 0):
                raise ProtocolError("motion descriptor out of range", ErrorCode.OUT_OF_RANGE)
            self.mdesc = v
            return ()
        if isinstance(request, M.WaitEndMoveRequest):
            if not 0 < request.timeout <= 3600:
                raise ProtocolError("timeout out of (0, 3600] s", ErrorCode.OUT_OF_RANGE)
            return (True,)
        if c in (C.STOP_MOVE, C.RESET_MOTION):
            return ()
        if c == C.LIST_IO:
            return (",".join(self.outputs), ",".join(self.inputs))
        if isinstance(request, M.ReadIORequest):
            name = request.name
            if name in self.outputs:
                return (self.outputs[name], True)
            if name in self.inputs:
                return (self.inputs[name], False)
            raise ProtocolError(f"no I/O named {name!r}", ErrorCode.OUT_OF_RANGE)
        if isinstance(request, M.GetJointLogRequest):
            since = request.since
            if math.isnan(since):
                raise ProtocolError("since is NaN", ErrorCode.OUT_OF_RANGE)  # [RS-5.58]
            k1 = int((now - self.t0) / 0.004)
            k0 = max(0, k1 - 2500)
            rows = [[self.t0 + k * 0.004, *self.q] for k in range(k0, k1 + 1)]
            rows = [r for r in rows if r[0] > since]
            return (Matrix(len(rows), 7, [v for r in rows for v in r]), 0.004)
        if c == C.GET_JOINT_LIMITS:
            lims = [
                (-160, 160),
                (-137.5, 137.5),
                (-142.5, 142.5),
                (-270, 270),
                (-105, 120),
                (-270, 270),
            ]
            return (Matrix(6, 2, [v for r in lims for v in r]),)
        raise ProtocolError(f"{BY_ID[c].name} not implemented", ErrorCode.NOT_SUPPORTED)


class MiniSensor(Service):
    """A sensor service with a synthetic 64 x 32 camera."""

    identity = Identity("sensor", vendor="test", model="mini-sensor", serial="2")
    W, H = 64, 32

    def __init__(self) -> None:
        self.laser = True
        self.exposure = 1e-4
        self.window = (0, self.W)
        self.index = -1
        self.reading: tuple[Any, ...] | None = None
        self.lock = threading.Lock()

    def acq_time(self) -> float:
        return 3.5e-3 * self.window[1] / self.W

    def on_control_lost(self, session: SessionView) -> None:
        with self.lock:
            self.laser = False  # [RS-7.23] a lost controller's laser goes off

    def handle(  # noqa: C901  a fake server: one branch per command it answers
        self, session: SessionView, request: M.Request[Any]
    ) -> tuple[Value, ...]:
        c = request.command
        with self.lock:
            if c == C.SENSOR_STATUS:
                return (
                    self.laser,
                    self.index + 1,
                    self.index,
                    session.in_control,
                    session.control_held,
                    self.clock(),
                )
            if c == C.ACQUIRE:
                self.index += 1
                t = self.clock()
                if self.laser:
                    seam, status = Location(0, 1.25, 80, 0, 0, 0), int(SensorStatus.FOUND)
                else:
                    seam, status = Location(0, 0, 0, 0, 0, 0), int(SensorStatus.LASER_OFF)
                self.reading = (self.index, status, seam, 0.9, t, t + 1e-5, t + self.acq_time())
                return (self.index,)
            if c == C.GET_DATA:
                if self.reading is None:
                    raise ProtocolError("no measurement yet", ErrorCode.NO_DATA)
                return self.reading
            if isinstance(request, M.GetImageRequest):
                if self.reading is None:
                    raise ProtocolError("no image yet", ErrorCode.NO_DATA)
                # [SS-5.10] left-off width and height: the rest of the sensor.
                col = request.column or 0
                row = request.row or 0
                w = self.W - col if request.width is None else request.width
                h = self.H - row if request.height is None else request.height
                if not (
                    col >= 0
                    and row >= 0
                    and w > 0
                    and h > 0
                    and col + w <= self.W
                    and row + h <= self.H
                ):
                    raise ProtocolError("region outside the sensor", ErrorCode.OUT_OF_RANGE)
                return (self.index, Image(w, h, bytes(w * h)))
            if c == C.GET_PROFILE:
                if self.reading is None:
                    raise ProtocolError("no profile yet", ErrorCode.NO_DATA)
                return (self.index, Matrix(2, 3, [0, 1, 80, 1, 1, 80]))
            if isinstance(request, M.SetLaserRequest):
                self.laser = request.on
                return ()
            if isinstance(request, M.SetExposureRequest):
                e = request.exposure
                if not 1e-6 <= e <= 0.01:
                    raise ProtocolError("exposure out of range", ErrorCode.OUT_OF_RANGE)
                self.exposure = e
                return ()
            if isinstance(request, M.SetReadoutWindowRequest):
                first, cols = request.first_column, request.columns
                if not (first >= 0 and cols >= 16 and first + cols <= self.W):
                    raise ProtocolError("window out of range", ErrorCode.OUT_OF_RANGE)
                self.window = (first, cols)
                return (self.acq_time(),)
            if c == C.GET_SETTINGS:
                return (self.laser, self.exposure, *self.window, self.acq_time(), self.W, self.H)
            if c == C.GET_TRIGGER_ENDPOINT:
                return ("", 0)
        raise ProtocolError(f"{BY_ID[c].name} not implemented", ErrorCode.NOT_SUPPORTED)


@contextmanager
def serving(server: FramedServer) -> Iterator[tuple[str, int]]:
    server.start()
    try:
        yield server.address
    finally:
        server.shutdown()


def check(
    service: str,
    address: tuple[str, int],
    select: tuple[str, ...] = (),
    profile: str = "core",
    scale: float = SCALE,
) -> RunResult:
    options = Options(timeout_scale=scale)
    return run(service, address[0], address[1], options, Selection(profile, select))


def outcomes(result: RunResult) -> dict[str, Outcome]:
    return {r.case.id: r.outcome for r in result.results}


def problems(result: RunResult) -> dict[str, str]:
    return {r.case.id: f"{r.outcome.value}: {r.message}" for r in result.results if r.is_problem}


# --- the conforming servers score 100 % ------------------------------------------------------


@pytest.mark.slow
def test_minimal_robot_scores_100_percent() -> None:
    with serving(FramedServer(MiniRobot(), policy=POLICY)) as address:
        result = check("robot", address, profile="full")
    assert problems(result) == {}
    assert exit_code(result) == ExitCode.SUBSET  # conformant to the profiles it claims only
    assert result.scope() == (
        ["core", "crc-off"],
        ["motion", "cartesian", "alter", "alter-queue", "sync"],
    )
    got = outcomes(result)
    assert got["robot.here.frames"] is Outcome.PASS
    assert got["commands.robot.JointMove.reply"] is Outcome.NOT_APPLICABLE  # not offered
    assert got["robot.motion.queued"] is Outcome.SKIPPED  # needs --allow-motion
    assert got["timeouts.frame"] is Outcome.PASS


@pytest.mark.slow
def test_minimal_sensor_scores_100_percent() -> None:
    with serving(FramedServer(MiniSensor(), policy=POLICY)) as address:
        result = check("sensor", address, profile="full")
    assert problems(result) == {}
    assert exit_code(result) == 0
    got = outcomes(result)
    for case_id in (
        "sensor.getdata.no_data",
        "sensor.laser_off",
        "sensor.image.region",
        "limits.max_payload.accepted",
        "connections.max_clients",
    ):
        assert got[case_id] is Outcome.PASS, case_id


# --- broken TCP servers built on the shell ---------------------------------------------------


@pytest.fixture
def send_hook(monkeypatch: pytest.MonkeyPatch) -> Any:
    """Install a byte-level rewrite of every frame one server sends."""

    def install(server: FramedServer, mangle: Any) -> None:
        original = Session.send_parts

        def send_parts(self: Session, parts: list[bytes]) -> None:
            if self.server is not server:
                original(self, parts)
                return
            frame = b"".join(parts)
            data = mangle(frame, decode_packet(frame))
            if data:
                with self._send_lock:
                    self.sock.sendall(data)

        # Every frame a server sends goes through Session.send_parts.
        monkeypatch.setattr(Session, "send_parts", send_parts)

    return install


def _reseal(frame: bytes) -> bytes:
    return frame[:-4] + struct.pack(">I", zlib.crc32(frame[:-4]))


def _caught(result: RunResult, *case_ids: str) -> None:
    got = outcomes(result)
    for case_id in case_ids:
        assert got[case_id] is Outcome.FAIL, (case_id, problems(result).get(case_id, got[case_id]))
    assert exit_code(result) == ExitCode.FAILED


def test_wrong_request_id_echo_is_caught(send_hook: Any) -> None:
    server = FramedServer(MiniRobot(), policy=POLICY)

    def mangle(frame: bytes, packet: Packet) -> bytes:
        rid = (packet.request_id + 1) % (1 << 32) if packet.request_id else 0
        return _reseal(frame[:8] + struct.pack(">I", rid) + frame[12:])

    send_hook(server, mangle)
    with serving(server) as address:
        result = check(
            "robot", address, ("framing.reply.echo", "framing.pipelined.ordered", "framing.crc.bad")
        )
    _caught(result, "framing.reply.echo", "framing.pipelined.ordered", "framing.crc.bad")


def test_bad_crc_in_replies_is_caught(send_hook: Any) -> None:
    server = FramedServer(MiniSensor(), policy=POLICY)
    send_hook(server, lambda frame, packet: frame[:-1] + bytes([frame[-1] ^ 0x55]))
    with serving(server) as address:
        result = check("sensor", address, ("framing.ping.echo", "negotiation.hello.reply"))
    _caught(result, "framing.ping.echo", "negotiation.hello.reply")
    assert "RS-3.6" in {r.message.split("[")[-1].rstrip("]") for r in result.results}


def test_length_field_in_host_byte_order_is_caught(send_hook: Any) -> None:
    server = FramedServer(MiniSensor(), policy=POLICY)

    def mangle(frame: bytes, packet: Packet) -> bytes:
        (length,) = struct.unpack_from(">I", frame, 12)
        return _reseal(frame[:12] + struct.pack("<I", length) + frame[16:])

    send_hook(server, mangle)
    with serving(server) as address:
        result = check("sensor", address, ("framing.byte_order.header", "framing.ping.echo"))
    _caught(result, "framing.byte_order.header", "framing.ping.echo")
    failed = next(r for r in result.results if r.case.id == "framing.byte_order.header")
    assert failed.wire and any(e.direction == "<-" for e in failed.wire)  # bytes are shown


def test_error_frame_without_message_is_caught(send_hook: Any) -> None:
    server = FramedServer(MiniRobot(), policy=POLICY)

    def mangle(frame: bytes, packet: Packet) -> bytes:
        if packet.kind is not PacketKind.ERROR:
            return frame
        return encode_packet(
            Packet(packet.kind, packet.command, packet.request_id, packet.params[:1])
        )

    send_hook(server, mangle)
    with serving(server) as address:
        result = check("robot", address, ("framing.error.shape", "framing.kind.not_request"))
    _caught(result, "framing.error.shape", "framing.kind.not_request")


class WrongCodeServer(FramedServer):
    """Answers an unknown command, or one not offered, with BAD_PARAMETERS instead of
    UNKNOWN_COMMAND or NOT_SUPPORTED."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        try:
            return super()._execute(session, packet)
        except ProtocolError as exc:
            if exc.code in (ErrorCode.UNKNOWN_COMMAND, ErrorCode.NOT_SUPPORTED):
                raise ProtocolError("bad", ErrorCode.BAD_PARAMETERS) from None
            raise


def test_wrong_error_code_is_caught() -> None:
    with serving(WrongCodeServer(MiniRobot(), policy=POLICY)) as address:
        result = check("robot", address, ("framing.error.shape", "negotiation.hello.*"))
    _caught(result, "framing.error.shape", "negotiation.hello.commands_complete")


class OldHelloServer(FramedServer):
    """Frames carry its minor version; its Hello says 1.0 all the same [RS-5.31 broken]."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        params = super()._execute(session, packet)
        return ("1.0", *params[1:]) if packet.command == C.HELLO else params


def test_hello_version_unlike_the_frame_header_is_caught() -> None:
    with serving(OldHelloServer(MiniRobot(), policy=POLICY)) as address:
        result = check("robot", address, ("control.status_fields",))
    _caught(result, "control.status_fields")
    assert "RS-5.31" in problems(result)["control.status_fields"]


class ClosingServer(FramedServer):
    """Closes the connection on an unknown command instead of answering."""

    def _dispatch(self, session: Session, packet: Packet) -> None:
        if packet.command not in self._implemented:
            session.sock.shutdown(socket.SHUT_RDWR)
            return
        super()._dispatch(session, packet)


def test_closing_on_unknown_command_is_caught() -> None:
    with serving(ClosingServer(MiniRobot(), policy=POLICY)) as address:
        result = check("robot", address, ("framing.error.shape", "framing.reply.echo"))
    _caught(result, "framing.error.shape", "framing.reply.echo")
    assert "RS-6.2" in problems(result)["framing.error.shape"]


class NoControlCheckServer(FramedServer):
    """Lets every connection run control commands."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        holder = self.control_holder
        self.control_holder = session
        try:
            return super()._execute(session, packet)
        finally:
            if packet.command != C.TAKE_CONTROL:
                self.control_holder = holder


def test_missing_control_check_is_caught() -> None:
    with serving(NoControlCheckServer(MiniSensor(), policy=POLICY)) as address:
        result = check("sensor", address, ("commands.sensor.*.not_in_control", "control.*"))
    _caught(
        result,
        "commands.sensor.SetExposure.not_in_control",
        "commands.sensor.Acquire.not_in_control",
        "control.read_only_open",
    )


class NoParamCheckServer(FramedServer):
    """Skips the parameter check of one command (GetSettings takes anything)."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        if packet.command == C.GET_SETTINGS:
            packet = Packet(packet.kind, packet.command, packet.request_id, ())
        return super()._execute(session, packet)


def test_missing_parameter_check_is_caught() -> None:
    with serving(NoParamCheckServer(MiniSensor(), policy=POLICY)) as address:
        result = check("sensor", address, ("commands.sensor.GetSettings.*",))
    _caught(result, "commands.sensor.GetSettings.bad_params")
    assert outcomes(result)["commands.sensor.GetSettings.reply"] is Outcome.PASS


class UnlistedCommandService(MiniRobot):
    """Leaves GetJointLimits out of Hello's list."""

    def implemented(self) -> tuple[int, ...]:
        return tuple(c for c in super().implemented() if c != C.GET_JOINT_LIMITS)


class UnlistedServer(FramedServer):
    """Answers GetJointLimits although Hello does not list it."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        if packet.command == C.GET_JOINT_LIMITS:
            spec = BY_ID[C.GET_JOINT_LIMITS]
            check_params(spec.params, packet.params)
            return self.service.handle(session, M.request_of(spec.id, packet.params))
        return super()._execute(session, packet)


def test_command_missing_from_hello_is_caught() -> None:
    with serving(UnlistedServer(UnlistedCommandService(), policy=POLICY)) as address:
        result = check("robot", address, ("negotiation.hello.commands_complete",))
    _caught(result, "negotiation.hello.commands_complete")


class WrongStatusTypeRobot(MiniRobot):
    """Answers GetStatus with ``powered`` as the INT 1 instead of a BOOL."""

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        reply = super().handle(session, request)
        return (1, *reply[1:]) if request.command == C.ROBOT_STATUS else reply


def test_a_reply_field_of_the_wrong_type_is_a_fail_of_its_requirement() -> None:
    """The harness reads replies as typed messages: a wrong field type is the endpoint's FAIL
    of RS-5.5 naming the command and the field, not a harness fault (an AssertionError)."""
    with serving(FramedServer(WrongStatusTypeRobot(), policy=POLICY)) as address:
        result = check("robot", address, ("robot.here.frames", "commands.robot.GetStatus.reply"))
    _caught(result, "robot.here.frames", "commands.robot.GetStatus.reply")
    for case_id, message in problems(result).items():
        assert message.startswith("fail: GetStatus reply parameters do not match"), case_id
        assert message.endswith("[RS-5.5]"), case_id
        assert "harness fault" not in message
    (judged,) = [r for r in result.results if r.case.id == "robot.here.frames"]
    assert judged.actual == "GetStatus reply parameter 0 (powered) must be BOOL, got INT"


class ShortImageSensor(MiniSensor):
    """Answers GetImage of a region with the index alone, the image left out."""

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        reply = super().handle(session, request)
        region = isinstance(request, M.GetImageRequest) and request.column is not None
        return reply[:1] if region else reply


def test_a_reply_missing_a_field_is_a_fail_not_a_harness_fault() -> None:
    """A case that reads an answer it asked for with ``call`` decodes it too: a reply one
    parameter short fails RS-5.5 (it was an IndexError, a harness fault)."""
    with serving(FramedServer(ShortImageSensor(), policy=POLICY)) as address:
        result = check("sensor", address, ("sensor.acquire.data", "sensor.shapes.image_defaults"))
    _caught(result, "sensor.shapes.image_defaults")
    message = problems(result)["sensor.shapes.image_defaults"]
    assert message.startswith("fail: GetImage reply parameters do not match"), message
    assert message.endswith("[RS-5.5]"), message


class BadCrcClosesServer(FramedServer):
    """Closes the connection on a bad CRC instead of going on with the next frame."""

    def _reject(self, session: Session, event: Rejected) -> None:
        super()._reject(session, event)
        if event.code is ErrorCode.BAD_CRC:
            session.sock.shutdown(socket.SHUT_RDWR)


def test_closing_after_bad_crc_is_caught() -> None:
    with serving(BadCrcClosesServer(MiniSensor(), policy=POLICY)) as address:
        result = check("sensor", address, ("framing.crc.bad", "robustness.corpus.bad-crc"))
    _caught(result, "framing.crc.bad", "robustness.corpus.bad-crc")


# --- broken raw-socket servers ---------------------------------------------------------------


class RawServer:
    """A tiny TCP server in a thread; ``handle(conn)`` is the whole behaviour."""

    def __init__(self, handle: Any) -> None:
        self.handle = handle
        self.listener = socket.create_server(("127.0.0.1", 0))
        host, port = self.listener.getsockname()[:2]
        self.address: tuple[str, int] = (host, port)
        self.stop = threading.Event()
        self.conns: list[socket.socket] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def _serve(self) -> None:
        self.listener.settimeout(0.05)
        while not self.stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.conns.append(conn)
            threading.Thread(target=self._run, args=(conn,), daemon=True).start()

    def _run(self, conn: socket.socket) -> None:
        try:
            self.handle(conn, self)
        except OSError:
            pass
        finally:
            conn.close()

    def __enter__(self) -> tuple[str, int]:
        self.thread.start()
        return self.address

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.listener.close()
        for c in self.conns:
            try:
                c.close()
            except OSError:
                pass
        self.thread.join(2)


def _answer(req: Packet) -> Packet:
    """Answers of a tiny sensor that knows Hello, Ping and GetTime."""
    from spec.params import IntArray

    if req.command == C.HELLO:
        params: tuple[Value, ...] = (
            "1.0",
            "sensor",
            "raw",
            "raw",
            "0",
            "0",
            IntArray([1, 2, 3, 4, 5]),
            65536,
            16,
            300.0,
            5.0,
        )
    elif req.command == C.PING:
        params = req.params[:1] or (b"",)
    elif req.command == C.GET_TIME:
        params = (time.monotonic(),)
    else:
        return Packet(PacketKind.ERROR, req.command, req.request_id, (5, "unknown"))
    return Packet(PacketKind.REPLY, req.command, req.request_id, params)


def ignores_length(conn: socket.socket, server: RawServer) -> None:
    """Takes every received chunk as exactly one frame, whatever its length field says."""
    while True:
        chunk = conn.recv(65536)
        if not chunk:
            return
        if len(chunk) < 20:
            continue
        header = wire.HEADER.unpack_from(chunk)
        from spec.params import decode_params

        try:
            params = decode_params(chunk[16:-4])
        except Exception:  # noqa: BLE001  a fake server answers whatever it is sent
            params = ()
        req = Packet(PacketKind.REQUEST, header[5], header[6], params)
        conn.sendall(encode_packet(_answer(req)))


def never_answers(conn: socket.socket, server: RawServer) -> None:
    while conn.recv(65536):
        pass


def slow(conn: socket.socket, server: RawServer) -> None:
    decoder = FrameDecoder()
    while True:
        chunk = conn.recv(65536)
        if not chunk:
            return
        decoder.feed(chunk)
        for event in decoder.events():
            if isinstance(event, Packet):
                if event.command != C.HELLO:  # a slow endpoint, not a silent one
                    time.sleep(0.5)
                conn.sendall(encode_packet(_answer(event)))


def test_ignoring_the_length_field_is_caught() -> None:
    with RawServer(ignores_length) as address:
        result = check(
            "sensor",
            address,
            ("framing.coalesced", "framing.pipelined.ordered", "framing.length.over_limit"),
        )
    got = outcomes(result)
    assert got["framing.coalesced"] in (Outcome.FAIL, Outcome.TIMEOUT)
    assert got["framing.length.over_limit"] is Outcome.FAIL
    assert Outcome.FAIL in got.values()


def test_never_answering_runs_nothing_and_exits_unreachable() -> None:
    with RawServer(never_answers) as address:
        result = check("sensor", address, ("framing.*", "negotiation.*"))
    assert not result.reachable and "did not answer Hello" in result.negotiation_error
    assert result.results == []  # one line says why, not a timeout per case
    assert exit_code(result) == ExitCode.UNREACHABLE


def test_slow_answers_give_timeouts_not_fails() -> None:
    with RawServer(slow) as address:
        result = check("sensor", address, ("framing.ping.echo", "framing.reply.echo"))
    assert set(outcomes(result).values()) == {Outcome.TIMEOUT}
    assert exit_code(result) == ExitCode.UNREACHABLE


class CrashingServer(FramedServer):
    """Stops serving (as if the process died) after N requests."""

    limit = 40

    def _dispatch(self, session: Session, packet: Packet) -> None:
        with self._lock:
            self._stats["seen"] += 1
            seen = self._stats["seen"]
        if seen > self.limit:
            self._shutdown.set()
            self._listener.close()
            for s in list(self.slots.served):
                try:
                    s.sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
            return
        super()._dispatch(session, packet)


def test_crashing_server_gives_errors_not_fails() -> None:
    server = CrashingServer(MiniSensor(), policy=POLICY)
    with serving(server) as address:
        result = check("sensor", address, ("negotiation.*", "framing.*", "commands.*"))
    got = [r.outcome for r in result.results]
    assert Outcome.FAIL not in got
    assert Outcome.PASS in got  # the cases before the crash ran
    assert got[-1] is Outcome.ERROR  # the cases after it are errors ("not run")
    assert exit_code(result) == ExitCode.UNREACHABLE


def test_unreachable_endpoint_runs_nothing_and_exits_unreachable() -> None:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    address = sock.getsockname()[:2]
    sock.close()  # nobody listens there now
    result = check("robot", address, ("framing.*",))
    assert not result.reachable and "cannot connect" in result.negotiation_error
    assert result.results == []  # one line says why; no "not run" per case
    assert exit_code(result) == ExitCode.UNREACHABLE


# --- the UDP sync endpoint -------------------------------------------------------------------


class MiniTriggerListener:
    """A sensor trigger endpoint with switchable faults."""

    def __init__(
        self,
        *,
        drop_every: int = 0,
        duplicate: bool = False,
        answer_malformed: bool = False,
        no_dedup: bool = False,
        delay: float = 0.0,
        bad_times: bool = False,
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        host, port = self.sock.getsockname()[:2]
        self.address: tuple[str, int] = (host, port)
        self.drop_every, self.duplicate, self.delay = drop_every, duplicate, delay
        self.answer_malformed, self.no_dedup, self.bad_times = answer_malformed, no_dedup, bad_times
        self.seen: set[int] = set()
        self.count = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                raw, source = self.sock.recvfrom(2048)
            except (TimeoutError, OSError):
                continue
            t = time.monotonic()
            try:
                trig = decode_datagram(raw)
            except DatagramError:
                if self.answer_malformed:
                    self.sock.sendto(b"SY?", source)
                continue
            if not isinstance(trig, Trigger):
                continue
            if trig.index in self.seen and not self.no_dedup:
                continue
            self.seen.add(trig.index)
            self.count += 1
            if self.drop_every and self.count % self.drop_every == 0:
                continue
            end = t - 1e-3 if self.bad_times else t + 3.6e-3
            data = encode_data(
                SensorData(
                    trig.index,
                    SensorStatus.FOUND,
                    (0.0, 1.0, 80.0, 0.0, 0.0, 0.0),
                    0.9,
                    trig.t_trigger,
                    t,
                    t + 1e-4,
                    end,
                )
            )
            if self.delay:
                time.sleep(self.delay)
            for _ in range(2 if self.duplicate else 1):
                self.sock.sendto(data, source)

    def __enter__(self) -> tuple[str, int]:
        self.thread.start()
        return self.address

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(2)
        self.sock.close()


def sync_check(listener: MiniTriggerListener, select: tuple[str, ...] = ()) -> RunResult:
    with listener as address:
        return check("sync", address, select, profile="full", scale=0.5)


@pytest.mark.slow
def test_minimal_trigger_listener_scores_100_percent() -> None:
    result = sync_check(MiniTriggerListener())
    assert problems(result) == {}
    assert exit_code(result) == 0
    assert result.measurements["udp_trigger_to_data"]["loss"] == 0.0


def test_udp_endpoint_dropping_data_is_caught() -> None:
    result = sync_check(MiniTriggerListener(drop_every=3), ("sync.trigger.answer",))
    _caught(result, "sync.trigger.answer")


def test_udp_endpoint_duplicating_data_is_caught() -> None:
    result = sync_check(
        MiniTriggerListener(duplicate=True), ("sync.trigger.answer", "sync.duplicate.once")
    )
    _caught(result, "sync.trigger.answer", "sync.duplicate.once")


def test_udp_endpoint_answering_duplicate_triggers_is_caught() -> None:
    result = sync_check(MiniTriggerListener(no_dedup=True), ("sync.duplicate.once",))
    _caught(result, "sync.duplicate.once")


def test_udp_endpoint_answering_malformed_triggers_is_caught() -> None:
    result = sync_check(MiniTriggerListener(answer_malformed=True), ("sync.malformed.silent",))
    _caught(result, "sync.malformed.silent")


def test_udp_endpoint_answering_late_is_caught() -> None:
    result = sync_check(MiniTriggerListener(delay=0.12), ("sync.trigger.deadline",))
    _caught(result, "sync.trigger.deadline")


def test_udp_endpoint_with_timestamps_out_of_order_is_caught() -> None:
    result = sync_check(MiniTriggerListener(bad_times=True), ("sync.timestamps.order",))
    _caught(result, "sync.timestamps.order")


# --- fuzzing, expectations and the command line against a live server ------------------------


class DiesOnBadParameters(FramedServer):
    """Stops serving (a crash) on the first request whose parameters cannot be decoded."""

    def _reject(self, session: Session, event: Rejected) -> None:
        if event.code is ErrorCode.BAD_PARAMETERS:
            self._shutdown.set()
            self._listener.close()
            session.sock.shutdown(socket.SHUT_RDWR)
            return
        super()._reject(session, event)


def test_fuzz_failure_is_reported_with_a_replayable_input() -> None:
    server = DiesOnBadParameters(MiniSensor(), policy=POLICY)
    with serving(server) as address:
        options = Options(timeout_scale=SCALE, fuzz=40, seed=1)
        result = run("sensor", *address, options, Selection(select=("robustness.fuzz",)))
    (fuzz,) = result.results
    assert fuzz.outcome is Outcome.FAIL
    failure = fuzz.details["fuzz_failures"][0]
    assert failure["seed"] == 1 and bytes.fromhex(failure["hex"])
    # The failing input, sent alone, breaks a fresh server the same way: it replays.
    server2 = DiesOnBadParameters(MiniSensor(), policy=POLICY)
    with serving(server2) as (host, port):
        with socket.create_connection((host, port), timeout=1) as sock:
            sock.sendall(bytes.fromhex(failure["hex"]))
            sock.settimeout(1)
            try:
                while sock.recv(4096):
                    pass
            except OSError:
                pass
        time.sleep(0.3)
        with pytest.raises(OSError), socket.create_connection((host, port), timeout=1) as s2:
            s2.sendall(b"x")
            assert s2.recv(1)  # a closed listener refuses; reaching here would be a miss


def test_cli_expectations_and_reports(tmp_path: Any) -> None:
    from conformance.cli import main

    known = tmp_path / "known.txt"
    known.write_text("framing.crc.bad\nframing.ping.echo\n")
    out = tmp_path / "r.json"
    with serving(BadCrcClosesServer(MiniSensor(), policy=POLICY)) as (host, port):
        code = main(
            [
                "sensor",
                f"{host}:{port}",
                "--select",
                "framing.crc.bad",
                "--select",
                "framing.ping.echo",
                "--expect",
                str(known),
                "--timeout-scale",
                str(SCALE),
                "--json",
                str(out),
                "-q",
            ]
        )
    import json

    data = json.loads(out.read_text())
    cases = {c["id"]: c for c in data["cases"]}
    assert code == 0  # the only failure is a known one
    assert cases["framing.crc.bad"]["outcome"] == "fail"
    assert cases["framing.crc.bad"]["known_failure"] is True
    assert cases["framing.ping.echo"]["unexpected_pass"] is True


# --- the robot's synchronisation side ----------------------------------------------------------


class MiniSyncRobot(MiniRobot):
    """MiniRobot plus the synchronisation commands: sends triggers over UDP and matches the
    data that comes back by index, with the counters of PROTOCOL.md section 9."""

    COMMANDS = (
        *MiniRobot.COMMANDS,
        C.SET_SENSOR_ENDPOINT,
        C.SET_SYNC_DELAY,
        C.SET_SENSOR_TOOL,
        C.GET_SYNC_CONFIG,
        C.START_TRIGGERS,
        C.SCHEDULE_TRIGGERS,
        C.STOP_TRIGGERS,
        C.GET_SEAM_POINTS,
        C.GET_SYNC_STATISTICS,
    )
    LOSS_TIMEOUT = 0.1

    def __init__(
        self,
        *,
        count_duplicates: bool = True,
        any_source: bool = False,
        lag_blind: bool = False,
        exposed_late: Literal["counted", "uncounted", "absent"] = "counted",
    ) -> None:
        super().__init__()
        self.count_duplicates = count_duplicates
        self.any_source = any_source  # broken on purpose: takes data from anyone [SY-3.7]
        self.lag_blind = lag_blind  # broken on purpose: ignores late exposures [SY-3.8]
        # broken on purpose unless "counted": places late exposures right but its counter
        # stays 0, or it sends the eleven counters of a robot from before [SY-5.9]
        self.exposed_late = exposed_late
        self.lags: list[float] = []
        self.endpoint: tuple[str, int] = ("", 0)
        self.delta_t = 0.005
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.001)
        self.next_index = 7
        self.sent: dict[int, float] = {}  # index -> t_T, awaiting data
        self.lost: set[int] = set()
        self.done: set[int] = set()
        self.points: dict[int, list[float]] = {}
        self.stats = dict.fromkeys(
            (
                "sent",
                "received",
                "matched",
                "lost",
                "late",
                "duplicate",
                "reordered",
                "unknown",
                "expired",
                "malformed",
                "pending",
                "exposed_late",
            ),
            0,
        )
        self.to_send = 0
        self.rate = 0.0
        self.next_t = 0.0
        self.lock = threading.Lock()
        self.stop = threading.Event()
        threading.Thread(target=self._loop, daemon=True).start()

    def _loop(self) -> None:
        while not self.stop.is_set():
            now = time.monotonic()
            with self.lock:
                if self.to_send and now >= self.next_t and self.endpoint[1]:
                    i, self.next_index = self.next_index, self.next_index + 1
                    self.sent[i] = now
                    self.to_send -= 1
                    self.stats["sent"] += 1
                    self.sock.sendto(encode_trigger(Trigger(i, now)), self.endpoint)
                    self.next_t += 1.0 / self.rate  # on the schedule, not after the last send
                for i, t in list(self.sent.items()):
                    if now - t > self.LOSS_TIMEOUT:
                        del self.sent[i]
                        self.lost.add(i)
                        self.stats["lost"] += 1
            try:
                raw, src = self.sock.recvfrom(2048)
            except (TimeoutError, OSError):
                continue
            if not self.any_source and src[:2] != self.endpoint:
                continue  # [SY-3.7] only the sensor endpoint may send data
            with self.lock:
                self._on_data(raw)

    def _on_data(self, raw: bytes) -> None:
        try:
            d = decode_datagram(raw)
        except DatagramError:
            self.stats["malformed"] += 1
            return
        if not isinstance(d, SensorData):
            self.stats["malformed"] += 1
            return
        self.stats["received"] += 1
        i = d.index
        if i in self.done:
            self.stats["duplicate"] += 1 if self.count_duplicates else 0
        elif i in self.lost:
            self.stats["late"] += 1
        elif i not in self.sent:
            self.stats["unknown"] += 1
        else:
            t_t = self.sent.pop(i)
            if self.done and i < max(self.done):
                self.stats["reordered"] += 1
            self.done.add(i)
            self.stats["matched"] += 1
            self.points[i] = [
                i,
                t_t,
                t_t + self.delta_t + self._extra_lag(d),
                int(d.status),
                d.quality,
                *d.seam,
                *([0.0] * 6),
            ]

    def _extra_lag(self, d: SensorData) -> float:
        """[SY-3.8] the lag over the median of the earlier readings' when beyond 0.5 ms."""
        lag = d.t_exposure_start - d.t_arrival
        ref = statistics.median(self.lags[-64:]) if len(self.lags) >= 8 else lag
        self.lags.append(lag)
        if self.lag_blind or lag - ref <= 0.5e-3:
            return 0.0
        self.stats["exposed_late"] += 1 if self.exposed_late == "counted" else 0
        return lag - ref

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        c = request.command
        with self.lock:
            if isinstance(request, M.SetSensorEndpointRequest):
                self.endpoint = (request.host, request.port)
                return ()
            if isinstance(request, M.SetSyncDelayRequest):
                if not abs(request.delta_t) <= 1.0:
                    raise ProtocolError("delta_t beyond 1 s", ErrorCode.OUT_OF_RANGE)
                self.delta_t = request.delta_t
                return ()
            if c == C.SET_SENSOR_TOOL:
                return ()
            if c == C.GET_SYNC_CONFIG:
                return (
                    *self.endpoint,
                    self.delta_t,
                    Location(0, 0, 0, 0, 0, 0),
                    bool(self.to_send),
                    self.rate,
                )
            if isinstance(request, M.StartTriggersRequest | M.ScheduleTriggersRequest):
                if not self.endpoint[1]:
                    raise ProtocolError("no sensor endpoint", ErrorCode.BAD_STATE)
                if isinstance(request, M.StartTriggersRequest):
                    rate, count = request.rate, request.count
                    if not 0 < rate <= 1000 or count < 0:
                        raise ProtocolError("rate out of range", ErrorCode.OUT_OF_RANGE)
                    self.rate, self.to_send, self.next_t = rate, count, time.monotonic()
                    return (self.next_index,)
                times = request.times.values
                if any(b <= a for a, b in itertools.pairwise(times)):
                    raise ProtocolError("times must increase", ErrorCode.OUT_OF_RANGE)
                raise ProtocolError("scheduling not offered", ErrorCode.NOT_SUPPORTED)
            if c == C.STOP_TRIGGERS:
                self.to_send = 0
                return ()
            if isinstance(request, M.GetSeamPointsRequest):
                since = request.since
                rows = [self.points[i] for i in sorted(self.points) if i > since]
                return (Matrix(len(rows), 17, [v for r in rows for v in r]),)
            if c == C.GET_SYNC_STATISTICS:
                stats = {**self.stats, "pending": len(self.sent)}
                if self.exposed_late == "absent":
                    del stats["exposed_late"]
                return tuple(stats.values())
        return super().handle(session, request)


ROBOT_SYNC_CASES = ("robot.sync.*", "commands.sync.*")


def _check_sync_robot(
    service: MiniSyncRobot, select: tuple[str, ...], policy: ServerPolicy = POLICY
) -> RunResult:
    """The cases ``select`` against ``service`` on loopback; its trigger thread stops after."""
    try:
        with serving(FramedServer(service, policy=policy)) as address:
            return check("robot", address, select, scale=0.5)
    finally:
        service.stop.set()


def test_minimal_sync_robot_scores_100_percent() -> None:
    result = _check_sync_robot(MiniSyncRobot(), ROBOT_SYNC_CASES)
    assert problems(result) == {}
    got = outcomes(result)
    assert got["robot.sync.matching"] is Outcome.PASS
    assert got["robot.sync.before_endpoint"] is Outcome.PASS
    assert got["robot.sync.ranges"] is Outcome.PASS


def test_sync_cases_live_with_the_idle_timeout_the_robot_announces() -> None:
    """robot.sync.matching and .exposure_lag play the sensor over UDP for most of a second,
    during which their TCP connection has nothing to ask. A robot announcing an idle timeout
    of 0.3 s in Hello [RS-7.6] (which a conforming client lives with) must not see the
    harness go silent for longer: the cases keep the connection with Pings and pass."""
    short = dataclasses.replace(POLICY, idle_timeout=0.3)
    result = _check_sync_robot(
        MiniSyncRobot(), ("robot.sync.matching", "robot.sync.exposure_lag"), short
    )
    assert problems(result) == {}
    (entry,) = [r for r in result.results if r.case.id == "robot.sync.matching"]
    assert any(e.note.startswith("request Ping") for e in entry.wire)  # kept, not lucky


def test_robot_not_counting_duplicates_is_caught() -> None:
    result = _check_sync_robot(MiniSyncRobot(count_duplicates=False), ("robot.sync.matching",))
    _caught(result, "robot.sync.matching")
    assert "SY-3.2" in problems(result)["robot.sync.matching"]


def test_robot_placing_a_late_exposure_at_t_t_plus_delta_t_is_caught() -> None:
    result = _check_sync_robot(MiniSyncRobot(lag_blind=True), ("robot.sync.exposure_lag",))
    assert outcomes(result)["robot.sync.exposure_lag"] is Outcome.NON_STRICT  # a SHOULD
    assert "SY-3.8" in problems(result)["robot.sync.exposure_lag"]


@pytest.mark.parametrize("exposed_late", ["uncounted", "absent"])
def test_robot_not_counting_a_late_exposure_is_caught(
    exposed_late: Literal["uncounted", "absent"],
) -> None:
    """A robot that places the late reading right but leaves exposed_late at 0, or sends
    the eleven counters of a robot from before SY-5.9 (which the harness still decodes)."""
    result = _check_sync_robot(
        MiniSyncRobot(exposed_late=exposed_late), ("robot.sync.exposure_lag",)
    )
    assert outcomes(result)["robot.sync.exposure_lag"] is Outcome.NON_STRICT  # a SHOULD
    assert "SY-5.9" in problems(result)["robot.sync.exposure_lag"]


def test_robot_taking_data_from_anyone_is_caught() -> None:
    result = _check_sync_robot(MiniSyncRobot(any_source=True), ("robot.sync.foreign_data",))
    assert outcomes(result)["robot.sync.foreign_data"] is Outcome.NON_STRICT  # a SHOULD


class NoBackoffServer(FramedServer):
    """Compares every token, however many wrong ones came before [RS-7.20 broken]."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.control.backoff = AuthBackoff(threshold=1 << 30)


class ExtendingBackoff(AuthBackoff):
    """Counts an attempt refused during the back-off as a failure [RS-7.26 broken]."""

    def wait(self, address: str, now: float) -> float:
        if super().wait(address, now) > 0.0:
            self.failed(address, now)
        return super().wait(address, now)


class ExtendingBackoffServer(FramedServer):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.control.backoff = ExtendingBackoff()


@pytest.mark.parametrize(
    ("server_class", "want"),
    [
        (FramedServer, Outcome.PASS),
        (NoBackoffServer, Outcome.FAIL),
        (ExtendingBackoffServer, Outcome.FAIL),
    ],
)
def test_missing_token_backoff_is_caught(server_class: type[FramedServer], want: Outcome) -> None:
    policy = dataclasses.replace(POLICY, token="s3cret")
    with serving(server_class(MiniRobot(), policy=policy)) as address:
        options = Options(timeout_scale=SCALE, token="s3cret")
        result = run("robot", *address, options, Selection("core", ("control.token*",)))
    got = outcomes(result)
    assert got["control.token"] is Outcome.PASS
    assert got["control.token_backoff"] is want, problems(result)
    if server_class is ExtendingBackoffServer:
        assert "[RS-7.26]" in problems(result)["control.token_backoff"]


def test_capability_file_makes_cases_not_applicable(tmp_path: Any) -> None:
    import json

    from conformance.cli import main

    caps = tmp_path / "caps.json"
    caps.write_text(json.dumps({"not_offered": ["GetImage", "0x2004"]}))
    out = tmp_path / "r.json"
    with serving(FramedServer(MiniSensor(), policy=POLICY)) as (host, port):
        code = main(
            [
                "sensor",
                f"{host}:{port}",
                "--select",
                "commands.sensor.GetImage.*",
                "--select",
                "commands.sensor.GetProfile.reply",
                "--select",
                "sensor.image.*",
                "--capabilities",
                str(caps),
                "--json",
                str(out),
                "-q",
            ]
        )
    assert code == ExitCode.SUBSET  # GetImage not offered: the sensor core profile not covered
    data = json.loads(out.read_text())
    assert {c["outcome"] for c in data["cases"]} == {"not-applicable"}
    assert len(data["cases"]) == 5
    assert data["profiles"] == {"claimed": ["sync", "crc-off"], "not_covered": ["core"]}


def test_silent_udp_endpoint_gives_timeouts_not_fails() -> None:
    result = sync_check(MiniTriggerListener(drop_every=1), ("sync.trigger.*", "sync.duplicate.*"))
    assert {r.outcome for r in result.results} == {Outcome.TIMEOUT}
    assert exit_code(result) == ExitCode.UNREACHABLE


def test_set_frame_crc_that_keeps_the_crc_is_caught(monkeypatch: Any) -> None:
    import spec.server

    def says_off_keeps_crc(
        self: FramedServer, session: Session, request: M.SetFrameCrcRequest
    ) -> tuple[Value, ...]:
        return (request.enabled,)  # reports the new setting, never applies it

    monkeypatch.setitem(spec.server._COMMON, C.SET_FRAME_CRC, says_off_keeps_crc)
    server = FramedServer(MiniRobot(), policy=POLICY)
    with serving(server) as address:
        result = check("robot", address, ("framing.no_crc",))
    _caught(result, "framing.no_crc")


def test_server_without_set_frame_crc_is_not_applicable(monkeypatch: Any) -> None:
    import spec.server

    monkeypatch.delitem(spec.server._COMMON, C.SET_FRAME_CRC)
    server = FramedServer(MiniRobot(), policy=POLICY)
    with serving(server) as address:
        result = check("robot", address, ("framing.no_crc",))
    assert outcomes(result)["framing.no_crc"] is Outcome.NOT_APPLICABLE


# --- misattributions: a case fails only for its own rule [issue 32] ---------------------------


class NoKinematicsRobot(MiniRobot):
    """Lists the tool moves but answers Here with NOT_SUPPORTED (a robot without kinematics
    whose Hello says otherwise): every tool move case needs Here for a harmless target."""

    COMMANDS = (*MiniRobot.COMMANDS, C.TOOL_MOVE_J, C.TOOL_MOVE_L, C.TOOL_MOVE_TRAJECTORY)

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        if request.command == C.HERE:
            raise ProtocolError("no kinematics", ErrorCode.NOT_SUPPORTED)
        return super().handle(session, request)


def _sent(result: Any, case_id: str) -> list[Packet]:
    """The requests a case sent, decoded from its wire log."""
    entry = next(r for r in result.results if r.case.id == case_id)
    out: list[Packet] = []
    for conn in sorted({e.conn for e in entry.wire}):
        decoder = FrameDecoder()
        decoder.feed(b"".join(e.data for e in entry.wire if e.conn == conn and e.direction == "->"))
        out.extend(e for e in decoder.events() if isinstance(e, Packet))
    return out


def _received(entry: Any, conn: int) -> list[Packet]:
    decoder = FrameDecoder()
    decoder.feed(b"".join(e.data for e in entry.wire if e.conn == conn and e.direction == "<-"))
    return [e for e in decoder.events() if isinstance(e, Packet)]


@pytest.mark.parametrize("move", ["ToolMoveJ", "ToolMoveL", "ToolMoveTrajectory"])
def test_refused_precondition_blocks_the_case_instead_of_failing_it(move: str) -> None:
    """Misattribution 2 of issue 32: {move}.not_in_control needs Here for a harmless target.
    Here refused is a failed precondition (blocked, Here named), not a failure of RS-7.4; the
    move itself is never sent."""
    with serving(FramedServer(NoKinematicsRobot(), policy=POLICY)) as address:
        options = Options(timeout_scale=SCALE, allow_motion=True)
        result = run("robot", *address, options, Selection("core", (f"commands.robot.{move}.*",)))
    got = {r.case.id: r for r in result.results}
    blocked = got[f"commands.robot.{move}.not_in_control"]
    assert blocked.outcome is Outcome.BLOCKED, blocked.message
    assert "Here was refused" in blocked.message and "NOT_SUPPORTED" in blocked.message
    assert blocked.details["precondition"] == f"correct arguments for {move}"
    sent = {p.command for p in _sent(result, f"commands.robot.{move}.not_in_control")}
    assert C.HERE in sent and int(getattr(C, _CONST[move])) not in sent
    assert got[f"commands.robot.{move}.reply"].outcome is Outcome.BLOCKED
    assert not [r.case.id for r in result.results if r.outcome is Outcome.FAIL]
    # Here's own rule is judged by Here's own cases; the robot claims a subset of 1.x
    assert exit_code(result) == ExitCode.SUBSET


_CONST = {
    "ToolMoveJ": "TOOL_MOVE_J",
    "ToolMoveL": "TOOL_MOVE_L",
    "ToolMoveTrajectory": "TOOL_MOVE_TRAJECTORY",
}


class LegacyNotOfferedServer(FramedServer):
    """A 1.2 server: a command it does not offer gets UNKNOWN_COMMAND, not NOT_SUPPORTED."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        try:
            return super()._execute(session, packet)
        except ProtocolError as exc:
            if exc.code is ErrorCode.NOT_SUPPORTED:
                raise ProtocolError(exc.message, ErrorCode.UNKNOWN_COMMAND) from None
            raise


@pytest.mark.parametrize(
    ("server_class", "code"),
    [(FramedServer, ErrorCode.NOT_SUPPORTED), (LegacyNotOfferedServer, ErrorCode.UNKNOWN_COMMAND)],
)
def test_cartesian_commands_not_offered_are_a_scope_not_a_failure(
    server_class: type[FramedServer], code: ErrorCode
) -> None:
    """Misattribution 1 of issue 32: a robot without kinematics leaves Here and the tool
    moves out of Hello and answers them NOT_SUPPORTED (1.3) or UNKNOWN_COMMAND (1.2). Both are
    conformant to what they claim (exit SUBSET, no failure), and the summary says that the
    cartesian profile (and sync, motion, ...) was not covered."""
    from conformance.report import terminal

    service = CoreOnlyRobot()
    with serving(server_class(service, policy=POLICY)) as address:
        with socket.create_connection(address, timeout=2) as raw:  # the planted answer
            raw.sendall(encode_packet(Packet(PacketKind.REQUEST, C.HERE, 1, ())))
            decoder = FrameDecoder()
            while not (events := list(decoder.events())):
                decoder.feed(raw.recv(4096))
        answer = events[0]
        assert isinstance(answer, Packet) and answer.error is not None
        assert answer.error[0] == code
        result = check("robot", address, profile="core")
    assert problems(result) == {}, problems(result)
    got = outcomes(result)
    assert got["negotiation.hello.commands_complete"] is Outcome.PASS
    assert got["negotiation.profile.core"] is Outcome.PASS
    for move in ("Here", "ToolMoveJ", "ToolMoveL", "ToolMoveTrajectory"):
        assert got[f"commands.robot.{move}.reply"] is Outcome.NOT_APPLICABLE
    claimed, not_covered = result.scope()
    assert "cartesian" in not_covered and "sync" in not_covered and "core" in claimed
    assert "not covered (not offered): motion, cartesian" in terminal(result)
    assert exit_code(result) == ExitCode.SUBSET


class EstopRobot(MiniRobot):
    """MiniRobot with a software emergency stop (GetStatus reports it)."""

    COMMANDS = (*MiniRobot.COMMANDS, C.EMERGENCY_STOP, C.RESET_EMERGENCY_STOP)

    def __init__(self) -> None:
        super().__init__()
        self.estop = False
        self.estops = 0

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        if request.command == C.EMERGENCY_STOP:
            self.estop, self.estops = True, self.estops + 1
            return ()
        if request.command == C.RESET_EMERGENCY_STOP:
            self.estop = False
            return ()
        if request.command == C.ROBOT_STATUS:
            mine, held = session.in_control, session.control_held
            return (False, self.estop, False, 0, mine, held, 0, "", 0.0)
        return super().handle(session, request)


def test_emergency_stop_when_full_is_not_confused_with_an_earlier_answer() -> None:
    """Misattribution 3 of issue 32: on the reserved connection of a full server the harness
    sent GetStatus and then EmergencyStop; the server's BUSY for GetStatus arrives before
    EmergencyStop's reply. With a fresh request ID per request, matched by command and ID
    [RS-3.4], the harness reports the EmergencyStop as executed, which it was."""
    service = EstopRobot()
    policy = dataclasses.replace(POLICY, max_clients=3, max_per_address=3)
    with serving(FramedServer(service, policy=policy)) as address:
        options = Options(timeout_scale=SCALE, allow_motion=True)
        result = run(
            "robot", *address, options, Selection("full", ("robot.emergency_stop_when_full",))
        )
    (entry,) = result.results
    assert entry.outcome is Outcome.PASS, (entry.message, entry.actual)
    assert service.estops == 1 and not service.estop  # executed once, then reset
    # The trap was there: the connection that got EmergencyStop got an error for the
    # GetStatus before it, then the reply; the two requests had different IDs.
    for conn in sorted({e.conn for e in entry.wire}):
        answers = _received(entry, conn)
        stop = [p for p in answers if p.command == C.EMERGENCY_STOP]
        if stop:
            break
    status = [p for p in answers if p.command == C.ROBOT_STATUS]
    assert status and status[0].error is not None and status[0].error[0] == ErrorCode.BUSY
    assert stop[0].kind is PacketKind.REPLY and stop[0].request_id != status[0].request_id
    assert answers.index(status[0]) < answers.index(stop[0])


def test_answers_are_matched_by_command_and_fresh_request_id() -> None:
    """A late answer to an earlier request on the connection is never taken for the answer
    to the next one (the emergency_stop_when_full misattribution), and an explicit request
    ID moves the counter past it so the next request's ID is fresh [RS-3.4]."""
    from conformance.connection import Conn, WireLog

    ours, theirs = socket.socketpair()
    with ours, theirs:
        conn = Conn(ours, WireLog(), 1, 1.0)
        status_id = conn.request(C.ROBOT_STATUS, request_id=1)
        estop_id = conn.request(C.EMERGENCY_STOP)
        assert estop_id != status_id
        busy = Packet(PacketKind.ERROR, C.ROBOT_STATUS, status_id, (int(ErrorCode.BUSY), "full"))
        done = Packet(PacketKind.REPLY, C.EMERGENCY_STOP, estop_id, ())
        theirs.sendall(encode_packet(busy) + encode_packet(done))
        answer = conn.answer_to(C.EMERGENCY_STOP, estop_id)
    assert answer.kind is PacketKind.REPLY and answer.error is None
    assert conn.pending == {}


class PingSwallowingServer(FramedServer):
    """Answers everything but Ping (a proxy that swallows it)."""

    def _dispatch(self, session: Session, packet: Packet) -> None:
        if packet.command == C.PING:
            return
        super()._dispatch(session, packet)


def test_unanswered_ping_is_one_broken_rule_not_a_wall_of_timeouts() -> None:
    with serving(PingSwallowingServer(MiniRobot(), policy=POLICY)) as address:
        result = check("robot", address, profile="core")
    got = {r.case.id: r for r in result.results}
    assert "liveness probe: Hello (0x0001)" in result.liveness
    assert "RS-5.8" in result.liveness
    assert got["negotiation.ping.liveness"].outcome is Outcome.FAIL
    assert "RS-5.8" in got["negotiation.ping.liveness"].message
    timeouts = [r.case.id for r in result.results if r.outcome is Outcome.TIMEOUT]
    assert timeouts == []
    assert got["commands.common.Ping.reply"].outcome is Outcome.BLOCKED
    # the corpus checks that a connection goes on with the run's probe, not with Ping, so
    # it is judged on its own (issue 35: 31 corpus cases were blocked behind Ping)
    corpus = [r for r in result.results if r.case.id.startswith("robustness.corpus.")]
    assert corpus and all(r.outcome is Outcome.PASS for r in corpus), [
        (r.case.id, r.outcome, r.message) for r in corpus if r.outcome is not Outcome.PASS
    ]
    assert list(problems(result)) == ["negotiation.ping.liveness"]  # reported once
    passed = sum(r.outcome is Outcome.PASS for r in result.results)
    assert passed > 50  # everything that does not ride on Ping is judged on its own
    assert exit_code(result) == 1


class SwallowsJointLimits(FramedServer):
    """Never answers GetJointLimits: a case that sends it leaves a request unanswered."""

    def _dispatch(self, session: Session, packet: Packet) -> None:
        if packet.command == C.GET_JOINT_LIMITS:
            return
        super()._dispatch(session, packet)


_ISOLATION_CASES = (
    "commands.robot.GetJointLimits.reply",  # times out, its request left unanswered
    "commands.robot.GetJointLimits.bad_params",
    "commands.robot.GetStatus.reply",
    "commands.robot.Herej.reply",
    "commands.robot.GetMotionDesc.reply",
    "framing.reply.echo",
)


@settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck))
@given(order=st.permutations(_ISOLATION_CASES))
def test_no_outcome_depends_on_a_request_another_case_left_unanswered(
    order: list[str],
) -> None:
    """Each case's outcome is the same whichever cases ran before it, among them cases
    whose requests the endpoint never answered."""
    from conformance.context import Context, Shared
    from conformance.model import all_cases
    from conformance.runner import run_case

    by_id = {c.id: c for c in all_cases()}
    options = Options(timeout_scale=SCALE)

    def outcomes_in(ids: Any) -> dict[str, Outcome]:
        got = {}
        with serving(SwallowsJointLimits(MiniRobot(), policy=POLICY)) as (host, port):
            shared = Shared()
            for case_id in ids:
                ctx = Context("robot", host, port, options, None, shared)
                got[case_id] = run_case(by_id[case_id], ctx).outcome
        return got

    alone = {case_id: outcomes_in([case_id])[case_id] for case_id in _ISOLATION_CASES}
    assert alone["commands.robot.GetJointLimits.reply"] is Outcome.TIMEOUT
    assert alone["commands.robot.GetStatus.reply"] is Outcome.PASS
    assert outcomes_in(order) == alone


class CoreOnlyRobot(MiniRobot):
    """Claims the core profile only (no Here): a robot without kinematics or motion."""

    COMMANDS = tuple(c for c in MiniRobot.COMMANDS if c != C.HERE)


class SyncRobot(MiniRobot):
    """Claims core and sync (answers the sync commands' shapes, no UDP behind them)."""

    COMMANDS = (*MiniRobot.COMMANDS, *(C(c) for c in range(0x3001, 0x300A)))


@pytest.mark.parametrize(
    ("service", "claimed", "not_covered"),
    [
        (
            CoreOnlyRobot,
            ["core", "crc-off"],
            ["motion", "cartesian", "alter", "alter-queue", "sync"],
        ),
        (SyncRobot, ["core", "sync", "crc-off"], ["motion", "cartesian", "alter", "alter-queue"]),
    ],
)
def test_summary_states_the_verdict_with_its_scope(
    service: type[MiniRobot], claimed: list[str], not_covered: list[str]
) -> None:
    """A robot offering a subset of the profiles passes what it claims with the SUBSET exit
    code, and the summary names what was not covered."""
    from conformance.report import terminal

    with serving(FramedServer(service(), policy=POLICY)) as address:
        result = check("robot", address, ("negotiation.hello.*", "commands.robot.Herej.*"))
    assert problems(result) == {}
    assert result.scope() == (claimed, not_covered)
    text = terminal(result)
    assert f"not covered (not offered): {', '.join(not_covered)}" in text
    assert exit_code(result) == ExitCode.SUBSET


# --- one self-test server per profile subset [issue 32] --------------------------------------

_ROBOT_PROFILES = [p.name for p in profiles_for("robot")]
_SUBSETS = [
    ("core",),
    ("core", "motion"),
    ("core", "cartesian"),
    ("core", "sync"),
    ("core", "motion", "cartesian"),
    ("core", "motion", "alter", "alter-queue"),
    tuple(_ROBOT_PROFILES),
]


def _subset_robot(names: tuple[str, ...]) -> type[MiniRobot]:
    """A MiniRobot whose Hello lists exactly the commands of ``names`` (crc-off too: the
    shell always serves SetFrameCrc)."""
    offered = {int(c) for p in profiles_for("robot") if p.name in names for c in p.commands}
    common = {int(c) for c in C if c < 0x1000}
    commands = tuple(C(c) for c in sorted(offered - common))
    return type(f"Robot_{'_'.join(names)}", (MiniRobot,), {"COMMANDS": commands})


@pytest.mark.parametrize("names", _SUBSETS, ids=["+".join(n) for n in _SUBSETS])
def test_a_robot_claiming_a_profile_subset_is_judged_on_it(names: tuple[str, ...]) -> None:
    """Each subset of profiles: the claimed ones (and only they) are in the verdict's scope,
    every case of a command not offered is not-applicable (never a failure), the checks the
    shell makes for every offered command pass, and the exit code says "a subset" unless
    every profile is claimed."""
    service = _subset_robot(names)()
    select = ("negotiation.*", "commands.robot.*.bad_params", "commands.robot.*.not_in_control")
    with serving(FramedServer(service, policy=POLICY)) as address:
        result = check("robot", address, select)
    claimed, not_covered = result.scope()
    want = [n for n in _ROBOT_PROFILES if n in (*names, "crc-off")]
    assert claimed == want and not_covered == [n for n in _ROBOT_PROFILES if n not in want]
    assert problems(result) == {}, problems(result)
    offered = set(service.implemented())
    judged, left_out = 0, 0
    for r in result.results:
        needs = set(r.case.commands) - {int(c) for c in C if c < 0x1000}
        if needs and not needs <= offered:
            assert r.outcome is Outcome.NOT_APPLICABLE, (r.case.id, r.outcome)
            left_out += 1
        elif r.case.id.endswith(".bad_params"):
            assert r.outcome is Outcome.PASS, (r.case.id, r.outcome, r.message)
            judged += 1
    assert judged >= 8 and (left_out > 0) == bool(not_covered)
    assert exit_code(result) == (ExitCode.OK if not not_covered else ExitCode.SUBSET)


class CoreOnlySensor(MiniSensor):
    """A sensor without UDP triggering: the sensor core profile only."""

    def implemented(self) -> tuple[int, ...]:
        return tuple(int(c.id) for c in commands_for("sensor") if c.id != C.GET_TRIGGER_ENDPOINT)


def test_a_sensor_without_triggering_is_judged_on_its_core() -> None:
    with serving(FramedServer(CoreOnlySensor(), policy=POLICY)) as address:
        result = check("sensor", address, ("negotiation.*", "commands.sensor.*"))
    assert problems(result) == {}, problems(result)
    assert result.scope() == (["core", "crc-off"], ["sync"])
    assert outcomes(result)["commands.sensor.GetTriggerEndpoint.reply"] is Outcome.NOT_APPLICABLE
    assert exit_code(result) == ExitCode.SUBSET


# --- the rules that answer the vendor's guesses catch the servers that guessed wrong --------


class NanLogRobot(MiniRobot):
    """1.2 behaviour: GetJointLog since NaN answers an empty log."""

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        if isinstance(request, M.GetJointLogRequest) and math.isnan(request.since):
            return (Matrix(0, 7, []), 0.004)
        return super().handle(session, request)


class StickyErrorRobot(MiniRobot):
    """A refused SetMotionDesc sets GetStatus' last_error (only moves may)."""

    last = (0, "")

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        if request.command == C.ROBOT_STATUS:
            mine, held = session.in_control, session.control_held
            return (False, False, False, 0, mine, held, *self.last, 0.0)
        try:
            return super().handle(session, request)
        except ProtocolError as exc:
            self.last = (int(exc.code), exc.message)
            raise


class HolderFirstServer(FramedServer):
    """Checks the holder before the watchdog period: BUSY where OUT_OF_RANGE is due."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        holder = self.control_holder
        if packet.command == C.TAKE_CONTROL and holder is not None and holder is not session:
            raise ProtocolError("control is held", ErrorCode.BUSY)
        return super()._execute(session, packet)


class ParamsBeforeOfferedServer(FramedServer):
    """Checks the parameters of a registry command it does not offer before saying so:
    BAD_PARAMETERS where NOT_SUPPORTED is due (step 8 of RS-6.4 before step 10)."""

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        spec = BY_ID.get(packet.command)
        if spec is not None and packet.command not in self._specs:
            check_params(spec.params, packet.params, spec.name)
        return super()._execute(session, packet)


@pytest.mark.parametrize(
    ("server_class", "service_class", "case_id", "rule"),
    [
        (ParamsBeforeOfferedServer, CoreOnlyRobot, "errors.precedence", "RS-6.4"),
        (FramedServer, NanLogRobot, "robot.jointlog.since_nan", "RS-5.58"),
        (FramedServer, StickyErrorRobot, "robot.last_error.only_moves", "RS-5.51"),
        (HolderFirstServer, MiniRobot, "control.take_control.order", "RS-7.25"),
    ],
)
def test_a_server_that_guessed_what_1_2_left_open_is_caught(
    server_class: type[FramedServer], service_class: type[MiniRobot], case_id: str, rule: str
) -> None:
    with serving(server_class(service_class(), policy=POLICY)) as address:
        result = check("robot", address, (case_id,))
    (entry,) = result.results
    assert entry.outcome is Outcome.FAIL, (entry.outcome, entry.message)
    assert f"[{rule}]" in entry.message  # the rule of the case, named in its verdict


def test_the_precedence_case_passes_a_robot_that_does_not_offer_every_command() -> None:
    with serving(FramedServer(CoreOnlyRobot(), policy=POLICY)) as address:
        (entry,) = check("robot", address, ("errors.precedence",)).results
    assert entry.outcome is Outcome.PASS, (entry.outcome, entry.message)
    assert "offered<types<control" in entry.message


class SlowWaitRobot(MiniRobot):
    """Offers JointMove and power; a WaitEndMove takes 0.3 s (a move running), so requests
    sent behind it queue on the connection's worker."""

    COMMANDS = (*MiniRobot.COMMANDS, C.ENABLE_POWER, C.DISABLE_POWER, C.JOINT_MOVE)
    blocking = frozenset({int(C.WAIT_END_MOVE)})

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        if request.command in (C.ENABLE_POWER, C.DISABLE_POWER):
            return ()
        if request.command == C.JOINT_MOVE:
            return (1,)
        if isinstance(request, M.WaitEndMoveRequest):
            time.sleep(min(0.3, request.timeout))
            return (True,)
        return super().handle(session, request)


@pytest.mark.parametrize(("limit", "want"), [(None, Outcome.PASS), (4, Outcome.FAIL)])
def test_refusing_requests_queued_behind_a_wait_is_caught(
    monkeypatch: pytest.MonkeyPatch, limit: int | None, want: Outcome
) -> None:
    """[RS-7.27] a server that queues only 4 requests behind a pending WaitEndMove (the
    rule: at least 16) fails robot.motion.queued_behind_wait; ours passes."""
    import spec.server

    if limit is not None:
        monkeypatch.setattr(spec.server, "MAX_PENDING", limit)
    with serving(FramedServer(SlowWaitRobot(), policy=POLICY)) as address:
        options = Options(timeout_scale=SCALE, allow_motion=True)
        result = run(
            "robot", *address, options, Selection("full", ("robot.motion.queued_behind_wait",))
        )
    (entry,) = result.results
    assert entry.outcome is want, (entry.outcome, entry.message)
    if want is Outcome.FAIL:
        assert "[RS-7.27]" in entry.message


# --- issue 32's leftovers: the reserved slots' eviction, the joint speed's scaling ----------


class _NewestFirstSlots(Slots[Session]):
    """Makes room on a full server by closing the newest reserved connection, not the oldest
    (a stack where the rule wants a queue)."""

    def add(self, session: Session, admission: Admission, reserved: int) -> Session | None:
        if admission.reserved and len(self.reserved) >= reserved:
            evicted = self.reserved.pop()
            self.reserved.append(session)
            return evicted
        return super().add(session, admission, reserved)


class NewestFirstServer(FramedServer):
    """A server whose reserved connections make room newest first."""

    def __init__(self, service: Service, *, policy: ServerPolicy) -> None:
        super().__init__(service, policy=policy)
        self.slots = _NewestFirstSlots()


@pytest.mark.parametrize(
    ("server_class", "want"), [(FramedServer, Outcome.PASS), (NewestFirstServer, Outcome.FAIL)]
)
def test_a_full_server_that_closes_another_than_the_oldest_reserved_is_caught(
    server_class: type[FramedServer], want: Outcome
) -> None:
    """[RS-7.14] with every reserved slot taken, a new connection closes the oldest reserved
    one (row 16 of CONFORMANCE.md's guesses): ours passes, one that closes the newest fails."""
    with serving(server_class(MiniRobot(), policy=POLICY)) as address:
        result = check("robot", address, ("connections.reserved.oldest_closed",), "full")
    (entry,) = result.results
    assert entry.outcome is want, (entry.outcome, entry.message)
    if want is Outcome.PASS:  # POLICY: 15 served from one address, then 4 reserved
        assert entry.message == "4 reserved connection(s) held; connection 5 closed the oldest"
    else:
        assert "[RS-7.14]" in entry.message and entry.actual == "reserved connection(s) 4 closed"


class MovingRobot(MiniRobot):
    """Moves joint 1 in a straight line at ``deg_s`` degrees per second, times joint_speed in
    % when ``scales`` (else at that speed whatever the descriptor says); logs every 4 ms."""

    COMMANDS = (*MiniRobot.COMMANDS, C.ENABLE_POWER, C.DISABLE_POWER, C.JOINT_MOVE)
    blocking = frozenset({int(C.WAIT_END_MOVE)})

    def __init__(self, deg_s: float, *, scales: bool) -> None:
        super().__init__()
        self.deg_s, self.scales = deg_s, scales
        # (start time, duration, from, to) of the last move
        self.move = (0.0, 0.0, list(self.q), list(self.q))

    def joints_at(self, t: float) -> list[float]:
        t0, duration, a, b = self.move
        f = 1.0 if duration <= 0.0 else min(max((t - t0) / duration, 0.0), 1.0)
        return [x + (y - x) * f for x, y in zip(a, b, strict=True)]

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        now = self.clock()
        t0, duration, _, _ = self.move
        end = t0 + duration
        if request.command in (C.ENABLE_POWER, C.DISABLE_POWER):
            return ()
        if isinstance(request, M.JointMoveRequest):
            start, target = self.joints_at(now), list(request.joints.values)
            speed = self.deg_s * (self.mdesc[0] if self.scales else 1.0)
            travel = max(abs(b - a) for a, b in zip(start, target, strict=True))
            self.move = (now, travel / speed, start, target)
            return (1,)
        if request.command == C.HEREJ:
            return (Joints(self.joints_at(now)),)
        if request.command == C.ROBOT_STATUS:
            mine, held = session.in_control, session.control_held
            return RobotStatusReply(False, False, now < end, 0, mine, held, 0, "", now).encode()
        if isinstance(request, M.WaitEndMoveRequest):
            time.sleep(min(request.timeout, max(end - now, 0.0)))
            return (self.clock() >= end,)
        if isinstance(request, M.GetJointLogRequest):
            since = max(request.since, now - 10.0)
            times = [k * 0.004 for k in range(math.floor(since / 0.004) + 1, int(now / 0.004))]
            rows = [[t, *self.joints_at(t)] for t in times]
            return (Matrix(len(rows), 7, [v for r in rows for v in r]), 0.004)
        return super().handle(session, request)


@pytest.mark.parametrize(("scales", "want"), [(True, Outcome.PASS), (False, Outcome.FAIL)])
def test_a_robot_whose_joint_speed_does_not_scale_is_caught(scales: bool, want: Outcome) -> None:
    """[RS-5.57] joint 1 cruising at the same speed at 1 % and 2 % joint speed fails
    robot.motiondesc.joint_speed_scales; one that cruises twice as fast at 2 % passes."""
    with serving(FramedServer(MovingRobot(10.0, scales=scales), policy=POLICY)) as address:
        options = Options(timeout_scale=SCALE, allow_motion=True)
        selection = Selection("full", ("robot.motiondesc.joint_speed_scales",))
        result = run("robot", *address, options, selection)
    (entry,) = result.results
    assert entry.outcome is want, (entry.outcome, entry.message)
    if want is Outcome.FAIL:
        assert "[RS-5.57]" in entry.message and str(entry.actual).startswith("ratio 1.000")


class StoppedMoveRobot(MiniRobot):
    """Takes JointMove, but something outside the harness (another client's StopMove) stops
    every move at once: WaitEndMove says so at once, as 1.3 does [RS-5.50], or (``legacy``)
    as a 1.2 robot does, ``done`` false only, its GetStatus ``moving`` false [RS-5.59]."""

    COMMANDS = (*MiniRobot.COMMANDS, C.ENABLE_POWER, C.DISABLE_POWER, C.JOINT_MOVE)

    def __init__(self, *, legacy: bool) -> None:
        super().__init__()
        self.legacy = legacy

    def handle(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        if request.command in (C.ENABLE_POWER, C.DISABLE_POWER):
            return ()
        if isinstance(request, M.JointMoveRequest):
            return (1,)
        if isinstance(request, M.WaitEndMoveRequest):
            return (False,) if self.legacy else (False, "stopped", "StopMove by connection 7")
        return super().handle(session, request)


@pytest.mark.parametrize(
    ("legacy", "said"),
    [(False, "ended 'stopped' (StopMove by connection 7)"), (True, "stands still")],
)
def test_a_stopped_null_move_ends_the_wait_and_is_reported(legacy: bool, said: str) -> None:
    """JointMove.reply waits for the end of the null move it queued: a move the robot says
    was stopped (or, 1.2, that stands still short of its target) ends the wait at the first
    WaitEndMove, not after 30 s of them, and the case says how the move ended."""
    with serving(FramedServer(StoppedMoveRobot(legacy=legacy), policy=POLICY)) as address:
        options = Options(timeout_scale=SCALE, allow_motion=True)
        result = run(
            "robot", *address, options, Selection("core", ("commands.robot.JointMove.reply",))
        )
    (entry,) = result.results
    assert entry.outcome is Outcome.INFORMATIONAL, (entry.outcome, entry.message)
    assert said in entry.message and "not 'reached'" in entry.message, entry.message
    sent = [p.command for p in _sent(result, "commands.robot.JointMove.reply")]
    assert sent.count(C.WAIT_END_MOVE) == 1, sent


class TakeControlReplyServer(FramedServer):
    """Rewrites TakeControl's reply: ``extra`` appends fields (a newer minor version [RS-5.6]),
    ``as_int`` sends the period as an INT (a reply that breaks the table)."""

    def __init__(
        self, service: Service, *, extra: tuple[Value, ...] = (), as_int: bool = False
    ) -> None:
        super().__init__(service, policy=POLICY)
        self.extra, self.as_int = extra, as_int

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        params = super()._execute(session, packet)
        if packet.command != C.TAKE_CONTROL:
            return params
        if self.as_int:
            params = tuple(int(v) if isinstance(v, float) else v for v in params)
        return (*params, *self.extra)


def test_take_control_reads_the_granted_period_by_name() -> None:
    """The harness reads the lease TakeControl granted by field name: trailing fields a newer
    version appends are passed over, and a period of the wrong type blocks the case naming
    TakeControl's reply instead of passing for a 1.0 server that grants no period."""
    only = Selection("core", ("control.take_control.order",))
    options = Options(timeout_scale=SCALE)
    newer = TakeControlReplyServer(MiniRobot(), extra=("future", 7))
    with serving(newer) as address:
        (entry,) = run("robot", *address, options, only).results
    assert entry.outcome is Outcome.PASS, (entry.outcome, entry.message)
    with serving(TakeControlReplyServer(MiniRobot(), as_int=True)) as address:
        (entry,) = run("robot", *address, options, only).results
    assert entry.outcome is Outcome.BLOCKED, (entry.outcome, entry.message)
    assert "TakeControl's reply" in entry.message and "RS-5.5" in entry.message, entry.message
