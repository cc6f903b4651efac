"""The framed server shell and client over real loopback sockets (port 0, timeouts)."""

from __future__ import annotations

import socket
import threading
import time
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec import wire
from spec.client import ClientTimeout, ConnectionClosed, FramedClient
from spec.codec import FrameDecoder, Packet, encode_packet, request
from spec.errors import ErrorCode, ProtocolError, RemoteError
from spec.messages import Request, WaitEndMoveRequest
from spec.params import Joints, Value
from spec.registry import CommandId
from spec.server import (
    FRAME_ALLOWANCE_BYTES,
    FramedServer,
    Identity,
    ServerPolicy,
    Service,
    Session,
    SessionView,
    _sendmsg_all,
    parse_networks,
)
from spec.wire import PacketKind

if TYPE_CHECKING:
    from tests.conftest import Serve


class EchoRobot(Service):
    """Answers Herej with fixed joints, fails on purpose on GetJointLimits."""

    identity = Identity("robot", vendor="test", model="echo")

    urgent = frozenset({int(CommandId.EMERGENCY_STOP)})
    blocking = frozenset({int(CommandId.WAIT_END_MOVE)})

    def __init__(self) -> None:
        self.lost_control: list[int] = []
        self.stopped = threading.Event()

    def implemented(self) -> tuple[int, ...]:
        return (
            CommandId.HEREJ,
            CommandId.ENABLE_POWER,
            CommandId.GET_JOINT_LIMITS,
            CommandId.WAIT_END_MOVE,
            CommandId.EMERGENCY_STOP,
        )

    def handle(self, session: SessionView, request: Request[Any]) -> tuple[Value, ...]:
        if request.command == CommandId.HEREJ:
            return (Joints([1, 2, 3, 4, 5, 6]),)
        if request.command == CommandId.ENABLE_POWER:
            return ()
        if isinstance(request, WaitEndMoveRequest):  # "the move ends" when EmergencyStop comes
            return (self.stopped.wait(request.timeout),)
        if request.command == CommandId.EMERGENCY_STOP:
            self.stopped.set()
            return ()
        raise ZeroDivisionError("deliberate handler bug")

    def on_control_lost(self, session: SessionView) -> None:
        self.lost_control.append(session.id)


@pytest.fixture
def server(serve: Serve) -> FramedServer:
    return serve(EchoRobot(), ServerPolicy(max_clients=4, frame_timeout=0.5))


def raw_conn(srv: FramedServer) -> socket.socket:
    s = socket.create_connection(srv.address, timeout=3)
    return s


def read_packets(sock: socket.socket, n: int) -> list[Packet]:
    decoder = FrameDecoder()
    out: list[Packet] = []
    while len(out) < n:
        data = sock.recv(65536)
        if not data:
            break
        decoder.feed(data)
        out.extend(e for e in decoder.events() if isinstance(e, Packet))
    return out


def test_hello_reports_identity_commands_and_limits(server: FramedServer) -> None:
    with FramedClient(*server.address) as c:
        info = c.hello()
    assert info["version"] == "1.3" and info["service"] == "robot" and info["model"] == "echo"
    commands = set(info["commands"].values)  # type: ignore[union-attr]
    assert {CommandId.HELLO, CommandId.PING, CommandId.HEREJ} <= commands
    assert CommandId.HERE not in commands  # [RS-5.3] only what it implements
    assert info["max_clients"] == 4


def test_hello_with_another_major_version_is_refused(server: FramedServer) -> None:
    with FramedClient(*server.address) as c, pytest.raises(RemoteError) as info:
        c.call(CommandId.HELLO, 2, 0, "future-client")
    assert info.value.code is ErrorCode.UNSUPPORTED_VERSION


def test_unknown_and_unimplemented_commands(server: FramedServer) -> None:
    """A command of another service or of no service is unknown [RS-5.1]; one of the robot
    service that this robot does not offer is NOT_SUPPORTED, whatever its parameters [RS-5.62]
    [RS-6.4]."""
    with FramedClient(*server.address) as c:
        for command, code in (
            (CommandId.GET_DATA, ErrorCode.UNKNOWN_COMMAND),
            (0x7777, ErrorCode.UNKNOWN_COMMAND),
            (CommandId.HERE, ErrorCode.NOT_SUPPORTED),
        ):
            with pytest.raises(RemoteError) as info:
                c.call(command)
            assert info.value.code is code
        with pytest.raises(RemoteError) as info:
            c.call(CommandId.JOINT_MOVE, "not joints")  # needs control, wrong type: offered?
        assert info.value.code is ErrorCode.NOT_SUPPORTED
        assert "JointMove" in str(info.value)
        assert c.ping(b"still alive") == b"still alive"  # [RS-5.1] connection stays open


def test_bad_parameters_are_refused_before_execution(server: FramedServer) -> None:
    with FramedClient(*server.address) as c:
        with pytest.raises(RemoteError) as info:
            c.call(CommandId.HEREJ, 1)
        assert info.value.code is ErrorCode.BAD_PARAMETERS
        with pytest.raises(RemoteError) as info:
            c.call(CommandId.TAKE_CONTROL, 5)
        assert info.value.code is ErrorCode.BAD_PARAMETERS


def test_control_is_needed_and_held_by_one_connection(server: FramedServer) -> None:
    with FramedClient(*server.address) as a, FramedClient(*server.address) as b:
        with pytest.raises(RemoteError) as info:
            a.call(CommandId.ENABLE_POWER)
        assert info.value.code is ErrorCode.NOT_IN_CONTROL
        a.take_control()
        a.take_control()  # the holder may take it again
        a.call(CommandId.ENABLE_POWER)
        with pytest.raises(RemoteError) as info:
            b.take_control()
        assert info.value.code is ErrorCode.BUSY
        with pytest.raises(RemoteError) as info:
            b.call(CommandId.ENABLE_POWER)
        assert info.value.code is ErrorCode.NOT_IN_CONTROL
        b.release_control()  # harmless without control [RS-7.11]
        a.release_control()
        b.take_control()
        b.call(CommandId.ENABLE_POWER)


def test_losing_the_controlling_connection_calls_the_service_hook(server: FramedServer) -> None:
    c = FramedClient(*server.address)
    c.take_control()
    c.close()
    deadline = time.monotonic() + 3
    service = server.service
    assert isinstance(service, EchoRobot)
    while not service.lost_control and time.monotonic() < deadline:
        time.sleep(0.01)
    assert service.lost_control
    assert server.control_holder is None


class SlowStopRobot(EchoRobot):
    """A controlled stop that lasts until the test lets it end."""

    def __init__(self) -> None:
        super().__init__()
        self.stop_started = threading.Event()
        self.stop_may_end = threading.Event()

    def on_control_lost(self, session: SessionView) -> None:
        self.stop_started.set()
        self.stop_may_end.wait(10.0)
        super().on_control_lost(session)


def test_a_new_controller_waits_for_the_lost_ones_controlled_stop() -> None:
    """[RS-7.10] control is not free while the lost controller's stop runs: TakeControl of
    another client is answered only after it, and the status says so meanwhile."""
    service = SlowStopRobot()
    with FramedServer(service) as srv:
        a = FramedClient(*srv.address)
        a.take_control()
        a.close()
        assert service.stop_started.wait(5.0)
        assert srv.control_holder is None and not srv.control_free
        took = threading.Event()
        with FramedClient(*srv.address) as b:

            def take() -> None:
                b.take_control()
                took.set()

            t = threading.Thread(target=take)
            t.start()
            assert not took.wait(0.3)  # a wait with a timeout: it must not happen at all
            service.stop_may_end.set()
            assert took.wait(5.0)
            t.join()
            assert srv.control_free is False and service.lost_control


def test_token_protects_control() -> None:
    srv = FramedServer(EchoRobot(), policy=ServerPolicy(token="s3cret")).start()
    try:
        with FramedClient(*srv.address) as c:
            with pytest.raises(RemoteError) as info:
                c.take_control("wrong")
            assert info.value.code is ErrorCode.AUTH_FAILED
            c.take_control("s3cret")
    finally:
        srv.shutdown()


def test_token_guessing_is_slowed_per_address() -> None:
    """[RS-7.20] after 3 wrong tokens even the right one is refused until the back-off ends,
    with the wait in the message; then it is accepted and the count starts again."""
    srv = FramedServer(EchoRobot(), policy=ServerPolicy(token="s3cret")).start()
    try:
        with FramedClient(*srv.address) as c:
            for _ in range(3):
                with pytest.raises(RemoteError, match="token missing or wrong"):
                    c.take_control("guess")
            with pytest.raises(RemoteError, match=r"retry in 0\.\d\d s") as info:
                c.call(CommandId.TAKE_CONTROL, "s3cret")  # the server's refusal, as sent
            assert info.value.code is ErrorCode.AUTH_FAILED
            # issue 35 item 8: the client waits out a short back-off and asks once more
            c.take_control("s3cret")
            c.release_control()
            with pytest.raises(RemoteError, match="token missing or wrong"):
                c.take_control("guess")  # reset by the success: a free failure again
            c.take_control("s3cret")
    finally:
        srv.shutdown()


def test_an_empty_token_is_refused_by_the_policy() -> None:
    with pytest.raises(ValueError, match="token is empty"):
        ServerPolicy(token=" ")


def test_handler_bug_becomes_internal_error_and_server_survives(server: FramedServer) -> None:
    with FramedClient(*server.address) as c:
        with pytest.raises(RemoteError) as info:
            c.call(CommandId.GET_JOINT_LIMITS)
        assert info.value.code is ErrorCode.INTERNAL_ERROR
        assert c.call(CommandId.HEREJ) == (Joints([1, 2, 3, 4, 5, 6]),)
    assert len(server.handler_errors) == 1
    server.handler_errors.clear()


def test_pipelined_requests_in_one_segment_are_answered_in_order(server: FramedServer) -> None:
    with raw_conn(server) as s:
        s.sendall(
            b"".join(encode_packet(request(CommandId.PING, i, bytes([i]))) for i in range(1, 21))
        )
        replies = read_packets(s, 20)
    assert [p.request_id for p in replies] == list(range(1, 21))
    assert [p.params[0] for p in replies] == [bytes([i]) for i in range(1, 21)]


def test_byte_by_byte_delivery(server: FramedServer) -> None:
    frame = encode_packet(request(CommandId.HEREJ, 77))
    with raw_conn(server) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for b in frame:
            s.send(bytes([b]))
        (reply,) = read_packets(s, 1)
    assert reply.kind is PacketKind.REPLY and reply.request_id == 77


def test_bad_crc_is_answered_and_the_connection_goes_on(server: FramedServer) -> None:
    bad = bytearray(encode_packet(request(CommandId.HEREJ, 5)))
    bad[-1] ^= 0xFF
    with raw_conn(server) as s:
        s.sendall(bytes(bad) + encode_packet(request(CommandId.HEREJ, 6)))
        err, ok = read_packets(s, 2)
    assert err.kind is PacketKind.ERROR and err.request_id == 5
    assert err.error is not None and err.error[0] == ErrorCode.BAD_CRC
    assert ok.kind is PacketKind.REPLY and ok.request_id == 6


def test_garbage_gets_bad_frame_then_close(server: FramedServer) -> None:
    with raw_conn(server) as s:
        s.sendall(b"GET / HTTP/1.1\r\n\r\n")
        (err,) = read_packets(s, 1)
        assert err.request_id == 0 and err.error is not None
        assert err.error[0] == ErrorCode.BAD_FRAME
        assert s.recv(10) == b""  # closed
    assert server.statistics()["rejected_by_code"]["BAD_FRAME"] == 1


def test_oversized_length_is_refused_before_reading(server: FramedServer) -> None:
    header = wire.HEADER.pack(wire.MAGIC, 1, 0, 1, 0, CommandId.PING, 9, wire.MAX_PAYLOAD)
    with raw_conn(server) as s:
        s.sendall(header)
        (err,) = read_packets(s, 1)
    assert err.error is not None and err.error[0] == ErrorCode.FRAME_TOO_LARGE


def test_a_frame_that_stops_half_way_times_out(server: FramedServer) -> None:
    with raw_conn(server) as s:
        s.sendall(b"R")
        t0 = time.monotonic()
        (err,) = read_packets(s, 1)
        waited = time.monotonic() - t0
        assert s.recv(10) == b""
    assert err.error is not None and err.error[0] == ErrorCode.TIMEOUT
    assert waited >= 0.4  # the 0.5 s frame timeout, not an immediate close
    with FramedClient(*server.address) as c:  # [RS-7.9] still serving
        assert c.ping() == b""


def test_a_trickled_frame_times_out_from_its_first_byte(server: FramedServer) -> None:
    """[RS-7.5] the frame timeout (0.5 s here) runs from the frame's first byte: bytes that
    keep trickling in (slowloris) do not hold the connection open."""
    frame = encode_packet(request(CommandId.HEREJ, 7))
    with raw_conn(server) as s:
        for i in range(0, len(frame), 4):  # 6 pieces, 0.15 s apart: 0.75 s in all
            try:
                s.sendall(frame[i : i + 4])
            except OSError:
                break  # closed by the server after its TIMEOUT
            time.sleep(0.15)
        (err,) = read_packets(s, 1)
    assert err.error is not None and err.error[0] == ErrorCode.TIMEOUT
    assert "not finished" in err.error[1]


def test_a_large_frame_gets_time_for_its_size() -> None:
    """[RS-7.5] the allowance: 1 s more for every 64 KiB of the frame received."""
    server = FramedServer(EchoRobot(), "127.0.0.1", 0, ServerPolicy(frame_timeout=5.0))
    try:
        decoder = FrameDecoder(max_payload=1 << 24)
        frame = encode_packet(request(CommandId.PING, 1, b"x" * 200_000))
        decoder.feed(frame[: 3 * FRAME_ALLOWANCE_BYTES])
        session = Session(server, socket.socket(), ("127.0.0.1", 1))
        deadline, why = server._deadline(session, decoder, 100.0, 100.0)
        session.sock.close()
    finally:
        server.shutdown()
    assert deadline == pytest.approx(100.0 + 5.0 + 3.0) and why


def test_idle_timeout_closes_a_silent_connection_not_a_busy_one(serve: Serve) -> None:
    """[RS-7.6] requests 0.1 s apart keep a connection with a 0.4 s idle timeout open for
    three times that; once it falls silent it gets TIMEOUT and is closed."""
    server = serve(EchoRobot(), ServerPolicy(max_clients=4, idle_timeout=0.4))
    with raw_conn(server) as s:
        for i in range(12):
            s.sendall(encode_packet(request(CommandId.HEREJ, i + 1)))
            (reply,) = read_packets(s, 1)
            assert reply.kind is PacketKind.REPLY and reply.request_id == i + 1
            time.sleep(0.1)
        (err,) = read_packets(s, 1)
        assert err.error is not None and err.error[0] == ErrorCode.TIMEOUT
        assert "idle" in err.error[1] and s.recv(10) == b""


def test_a_reserved_connection_is_closed_after_its_grace_even_while_sending(
    serve: Serve,
) -> None:
    """[RS-7.14] the reserved connection's deadline runs from its opening, not from its
    last byte: requests do not keep it open."""
    server = serve(EchoRobot(), ServerPolicy(max_clients=1, reserved_grace=0.3))
    with FramedClient(*server.address) as first:
        first.ping()
        with raw_conn(server) as s:
            (busy,) = read_packets(s, 1)
            assert busy.error is not None and busy.error[0] == ErrorCode.BUSY
            deadline = time.monotonic() + 5
            closed = False
            while not closed and time.monotonic() < deadline:
                try:
                    s.sendall(encode_packet(request(CommandId.HEREJ, 1)))
                    closed = not read_packets(s, 1)  # BUSY per request, nothing once closed
                except OSError:
                    closed = True
                time.sleep(0.02)
            assert closed


def test_client_over_the_limit_gets_busy(server: FramedServer) -> None:
    clients = [FramedClient(*server.address) for _ in range(4)]
    try:
        for c in clients:
            c.ping()
        with raw_conn(server) as s:
            (err,) = read_packets(s, 1)
            assert err.error is not None and err.error[0] == ErrorCode.BUSY
            assert s.recv(10) == b""
    finally:
        for c in clients:
            c.close()
    assert server.statistics()["refused_busy"] == 1


def test_allow_list_refuses_other_networks() -> None:
    policy = ServerPolicy(allow=parse_networks(["10.0.0.0/8"]))
    srv = FramedServer(EchoRobot(), policy=policy).start()
    try:
        with (
            pytest.raises((ConnectionClosed, ProtocolError, OSError)),
            FramedClient(*srv.address, timeout=2) as c,
        ):
            c.ping()
        assert srv.statistics()["refused_address"] == 1
    finally:
        srv.shutdown()
    with pytest.raises(ValueError, match="not a network"):
        parse_networks(["10.0.0.0/33"])


def test_client_timeout_is_typed() -> None:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    try:
        c = FramedClient(*listener.getsockname(), timeout=0.2)
        with pytest.raises(ClientTimeout):
            c.ping()
        assert not c.connected
    finally:
        listener.close()


def test_client_rejects_a_reply_with_the_wrong_request_id() -> None:
    from spec.errors import PeerError

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    import threading

    def serve() -> None:
        conn, _ = listener.accept()
        with conn:
            conn.recv(1000)
            conn.sendall(encode_packet(Packet(PacketKind.REPLY, CommandId.PING, 999, (b"",))))
            time.sleep(0.2)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        with FramedClient(*listener.getsockname(), timeout=2) as c, pytest.raises(PeerError):
            c.ping()
    finally:
        t.join(2)
        listener.close()


def test_statistics_account_for_frames_and_errors(server: FramedServer) -> None:
    with FramedClient(*server.address) as c:
        c.ping()
        with pytest.raises(RemoteError):
            c.call(0x7777)
    stats = server.statistics()
    assert stats["frames_in"] == 2 and stats["replies"] == 1 and stats["errors_sent"] == 1
    assert stats["connections"] == 1


def test_a_request_a_handler_still_holds_is_counted_in_but_not_answered(
    server: FramedServer,
) -> None:
    """frames_in counts a request on arrival: while WaitEndMove waits, it is one more than
    the replies and errors sent (the client's lease pings are answered meanwhile)."""

    def unanswered() -> int:
        stats = server.statistics()
        return int(stats["frames_in"] - stats["replies"] - stats["errors_sent"])

    service = server.service
    assert isinstance(service, EchoRobot)
    with FramedClient(*server.address) as c:
        c.take_control()
        assert unanswered() == 0
        waiting = threading.Thread(target=lambda: c.call(CommandId.WAIT_END_MOVE, 10.0))
        waiting.start()
        deadline = time.monotonic() + 5.0
        while unanswered() == 0:
            assert time.monotonic() < deadline, "the held request was never counted"
            time.sleep(0.01)
        assert unanswered() == 1
        service.stopped.set()
        waiting.join(5.0)
        assert not waiting.is_alive()
        assert unanswered() == 0


def test_statistics_count_every_request_of_concurrent_clients_exactly(serve: Serve) -> None:
    """The per-request counters take no lock: clients on eight threads lose no count, and
    each reply is counted when it arrives."""
    server = serve(EchoRobot(), ServerPolicy(max_clients=8))
    clients, calls = 8, 200
    errors: list[BaseException] = []

    def run() -> None:
        try:
            with FramedClient(*server.address) as c:
                for i in range(calls):
                    assert c.ping(b"x" * (i % 7)) == b"x" * (i % 7)
                    assert c.call(CommandId.HEREJ) == (Joints([1, 2, 3, 4, 5, 6]),)
                    assert server.statistics()["replies"] >= 2 * (i + 1)
        except BaseException as exc:  # noqa: BLE001  a client thread's failure, raised below
            errors.append(exc)

    threads = [threading.Thread(target=run) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors
    stats = server.statistics()
    assert stats["frames_in"] == stats["replies"] == 2 * clients * calls
    assert stats["bytes_in"] > 0 and stats["bytes_out"] > 0


# --- frames without CRC (SetFrameCrc, PROTOCOL.md 3.1) and large frames received in place ----


def test_frame_crc_off_sends_no_crc_frames_on_that_connection_only(server: FramedServer) -> None:
    big = bytes(range(256)) * 1024  # 256 KiB: the in-place receive path
    with FramedClient(*server.address, frame_crc=False) as c, FramedClient(*server.address) as d:
        assert not c.frame_crc_active and d.frame_crc_active
        assert c.ping(big) == big and c.ping(b"x") == b"x"
        assert d.ping(big) == big
        # Raw bytes: a third connection turns CRCs off and reads the flag and the trailer.
        s = raw_conn(server)
        s.sendall(encode_packet(request(CommandId.SET_FRAME_CRC, 1, False)))
        s.sendall(encode_packet(request(CommandId.PING, 2, b"abc")))
        raw = b""
        while len(raw) < 2 * wire.FRAME_OVERHEAD + 4 + 10:  # the two replies
            raw += s.recv(65536)
        s.close()
    first_len = wire.FRAME_OVERHEAD + wire.HEADER.unpack_from(raw)[7]
    first, second = raw[:first_len], raw[first_len:]
    assert first[5] == 0 and decode_reply(first) == (False,)  # [RS-3.16] its own reply: CRC
    assert second[5] == wire.FLAG_NO_CRC and second[-4:] == b"\0\0\0\0"
    decoder = FrameDecoder(accept_no_crc=True)
    decoder.feed(second)
    packet = decoder.next_event()
    assert isinstance(packet, Packet) and packet.params == (b"abc",)


def decode_reply(frame: bytes) -> tuple[Value, ...]:
    decoder = FrameDecoder()
    decoder.feed(frame)
    packet = decoder.next_event()
    assert isinstance(packet, Packet)
    return packet.params


def test_no_crc_frame_is_refused_where_crcs_were_not_turned_off() -> None:
    frame = encode_packet(Packet(PacketKind.REPLY, CommandId.PING, 7, (b"z",)), crc=False)
    decoder = FrameDecoder()
    decoder.feed(frame)
    event = decoder.next_event()
    assert not isinstance(event, Packet) and event is not None
    assert event.code is ErrorCode.BAD_CRC  # [RS-3.17] the trailer is checked as usual


def test_frame_crc_off_falls_back_when_the_server_lacks_set_frame_crc(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import spec.server

    monkeypatch.delitem(spec.server._COMMON, CommandId.SET_FRAME_CRC)
    with FramedServer(EchoRobot()) as srv, FramedClient(*srv.address, frame_crc=False) as c:
        assert c.frame_crc_active  # [RS-3.15] a 1.0 server keeps its CRCs
        assert c.ping(b"still fine") == b"still fine"


@pytest.mark.parametrize("piece", [1, 7, 4096, 70_000])
def test_large_frame_received_in_place_in_any_pieces(piece: int) -> None:
    payload = bytes(range(251)) * 600  # ~150 KB, above LARGE_FRAME
    frames = encode_packet(request(CommandId.PING, 1, payload)) + encode_packet(
        request(CommandId.PING, 2, b"next")
    )
    decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    got: list[Packet] = []
    pos = 0
    while pos < len(frames):
        view = decoder.get_buffer()
        if view is None:
            decoder.feed(frames[pos : pos + piece])
            pos += piece
        else:
            n = min(piece, len(view), len(frames) - pos)
            view[:n] = frames[pos : pos + n]
            decoder.buffer_updated(n)
            pos += n
        got.extend(e for e in decoder.events() if isinstance(e, Packet))
    assert [p.params for p in got] == [(payload,), (b"next",)]
    assert decoder.buffered == 0 and not decoder.in_frame


@settings(max_examples=150, deadline=None)
@given(
    cuts=st.lists(st.integers(1, 200_000), min_size=1, max_size=12),
    in_place=st.lists(st.booleans(), min_size=1, max_size=12),
)
def test_feed_and_in_place_receive_mix_in_any_order(cuts: list[int], in_place: list[bool]) -> None:
    """Whatever mix of feed() and get_buffer() delivers the bytes, the same frames come out."""
    payload = bytes(range(256)) * 400  # 100 KiB: a large frame
    stream = b"".join(
        encode_packet(request(CommandId.PING, rid, data))
        for rid, data in ((1, b"a"), (2, payload), (3, b"b"), (4, payload[:70_000]))
    )
    decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    got: list[Packet] = []
    pos, i = 0, 0
    while pos < len(stream):
        n = cuts[i % len(cuts)]
        view = decoder.get_buffer() if in_place[i % len(in_place)] else None
        i += 1
        if view is not None:
            n = min(n, len(view), len(stream) - pos)
            view[:n] = stream[pos : pos + n]
            decoder.buffer_updated(n)
        else:
            decoder.feed(stream[pos : pos + n])
            n = min(n, len(stream) - pos)
        pos += n
        got.extend(e for e in decoder.events() if isinstance(e, Packet))
    assert [p.request_id for p in got] == [1, 2, 3, 4]
    assert got[1].params == (payload,) and got[3].params == (payload[:70_000],)
    assert decoder.buffered == 0 and not decoder.in_frame


def test_stopping_request_overtakes_a_pending_wait_others_stay_in_order(
    server: FramedServer,
) -> None:
    """[RS-7.12] WaitEndMove runs on the worker; Herej queues behind it; EmergencyStop,
    urgent, is executed on arrival and its reply comes first."""
    with raw_conn(server) as s:
        s.sendall(
            encode_packet(request(CommandId.WAIT_END_MOVE, 1, 30.0))
            + encode_packet(request(CommandId.HEREJ, 2))
            + encode_packet(request(CommandId.EMERGENCY_STOP, 3))
        )
        replies = read_packets(s, 3)
    assert [p.request_id for p in replies] == [3, 1, 2]
    assert replies[1].params == (True,)


class ThreadNotingRobot(EchoRobot):
    """EchoRobot that notes which thread executes each request."""

    def __init__(self) -> None:
        super().__init__()
        self.threads: list[tuple[int, str]] = []

    def handle(self, session: SessionView, request: Request[Any]) -> tuple[Value, ...]:
        self.threads.append((int(request.command), threading.current_thread().name))
        return super().handle(session, request)


def test_requests_that_cannot_block_are_answered_by_the_thread_that_read_them(
    serve: Serve,
) -> None:
    """[RS-7.12] Herej crosses to no other thread (no hand-off, no extra wake-up per request):
    only WaitEndMove and what queues behind it run on the session's worker, EmergencyStop
    still overtakes, and once the worker is idle the next Herej is the reader's again."""
    service = ThreadNotingRobot()
    server = serve(service, ServerPolicy(max_clients=4))
    with raw_conn(server) as s:
        s.sendall(encode_packet(request(CommandId.HEREJ, 1)))
        read_packets(s, 1)
        s.sendall(
            encode_packet(request(CommandId.WAIT_END_MOVE, 2, 30.0))
            + encode_packet(request(CommandId.HEREJ, 3))
            + encode_packet(request(CommandId.EMERGENCY_STOP, 4))
        )
        assert [p.request_id for p in read_packets(s, 3)] == [4, 2, 3]
        # the worker counts a request as pending until just after its reply went out
        deadline = time.monotonic() + 5
        while any(x.busy for x in server.slots.served) and time.monotonic() < deadline:
            time.sleep(0.001)
        s.sendall(encode_packet(request(CommandId.HEREJ, 5)))
        read_packets(s, 1)

    def on_worker(command: int) -> list[bool]:
        return [name.endswith("-worker") for c, name in service.threads if c == command]

    assert on_worker(CommandId.HEREJ) == [False, True, False]
    assert on_worker(CommandId.WAIT_END_MOVE) == [True]
    assert on_worker(CommandId.EMERGENCY_STOP) == [False]


def test_a_close_is_seen_while_a_request_is_pending(server: FramedServer) -> None:
    service = server.service
    assert isinstance(service, EchoRobot)
    with raw_conn(server) as s:
        s.sendall(encode_packet(request(CommandId.TAKE_CONTROL, 1, "")))
        read_packets(s, 1)
        s.sendall(encode_packet(request(CommandId.WAIT_END_MOVE, 2, 30.0)))
        deadline = time.monotonic() + 5
        while not server.statistics()["frames_in"] >= 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    deadline = time.monotonic() + 5
    while not service.lost_control and time.monotonic() < deadline:
        time.sleep(0.01)
    assert service.lost_control, "the close was not seen while WaitEndMove was pending"
    assert not service.stopped.is_set()  # the wait itself is still running
    service.stopped.set()


def test_silent_controller_loses_control_by_the_watchdog(server: FramedServer) -> None:
    service = server.service
    assert isinstance(service, EchoRobot)
    with FramedClient(*server.address) as client:
        client.keepalive = False
        assert client.take_control("", 0.1) == 0.1
        for _ in range(5):  # frames inside the period keep the lease
            time.sleep(0.04)
            client.ping()
        assert not service.lost_control
        time.sleep(0.4)
        assert service.lost_control
        with pytest.raises(RemoteError) as err:
            client.call(CommandId.ENABLE_POWER)
        assert err.value.code == ErrorCode.NOT_IN_CONTROL and "watchdog" in err.value.message
    assert server.statistics()["watchdog_expired"] == 1


def test_watchdog_outside_the_limits_is_out_of_range(server: FramedServer) -> None:
    with FramedClient(*server.address) as client:
        for bad in (0.0, 0.001, 1e6, float("nan")):
            with pytest.raises(RemoteError) as err:
                client.take_control("", bad)
            assert err.value.code == ErrorCode.OUT_OF_RANGE
        assert client.take_control("") == ServerPolicy().watchdog  # the default


def test_emergency_stop_on_a_reserved_connection_of_a_full_server(server: FramedServer) -> None:
    """[RS-7.14] over the limit: BUSY (ID 0), then EmergencyStop executed, others BUSY."""
    service = server.service
    assert isinstance(service, EchoRobot)
    clients = [FramedClient(*server.address) for _ in range(4)]
    try:
        for c in clients:
            c.ping()
        with FramedClient(*server.address) as late:
            late.call(CommandId.EMERGENCY_STOP)  # skips the BUSY notice of the full server
            assert service.stopped.is_set()
            with pytest.raises(RemoteError) as err:
                late.call(CommandId.HEREJ)
            assert err.value.code == ErrorCode.BUSY
    finally:
        for c in clients:
            c.close()
    assert server.statistics()["reserved_connections"] == 1


def test_an_interrupted_call_leaves_no_stale_reply(server: FramedServer) -> None:
    """Ctrl-C while waiting for a reply: the next call gets its own reply, not the old one."""
    service = server.service
    assert isinstance(service, EchoRobot)
    with FramedClient(*server.address) as client:
        timer = threading.Timer(0.2, service.stopped.set)
        original = client._receive
        calls = 0

        def interrupted(timeout: float, command: int = -1, request_id: int = -1) -> Packet:
            nonlocal calls
            calls += 1
            if calls == 1:
                timer.start()
                raise KeyboardInterrupt  # as if Ctrl-C hit while waiting for WaitEndMove
            return original(timeout, command, request_id)

        client._receive = interrupted  # type: ignore[method-assign]
        with pytest.raises(KeyboardInterrupt):
            client.call(CommandId.WAIT_END_MOVE, 5.0)
        (joints,) = client.call(CommandId.HEREJ)  # the WaitEndMove reply comes first
        assert joints == Joints([1, 2, 3, 4, 5, 6])
        timer.join()


def test_an_interrupt_right_after_the_send_leaves_no_stale_reply(server: FramedServer) -> None:
    """Ctrl-C between the send and the wait for the reply (the race a SIGTERM'd `call` hit):
    the request is already marked abandoned, so its reply is dropped too."""
    service = server.service
    assert isinstance(service, EchoRobot)
    service.stopped.set()  # WaitEndMove answers at once
    with FramedClient(*server.address) as client:
        original = client._send
        sent = 0

        def send_then_interrupt(data: bytes) -> None:
            nonlocal sent
            original(data)
            sent += 1
            if sent == 1:
                raise KeyboardInterrupt

        client._send = send_then_interrupt  # type: ignore[method-assign]
        with pytest.raises(KeyboardInterrupt):
            client.call(CommandId.WAIT_END_MOVE, 5.0)
        (joints,) = client.call(CommandId.HEREJ)
        assert joints == Joints([1, 2, 3, 4, 5, 6])


class _ShortSends:
    """A socket stand-in whose sendmsg takes at most ``limit`` bytes a call (as a blocking
    send cut short by a timeout or a signal does), recording what went out."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.out = bytearray()
        self.calls = 0

    def sendmsg(self, buffers: list[bytes | memoryview]) -> int:
        self.calls += 1
        data = b"".join(bytes(b) for b in buffers)[: self.limit]
        self.out += data
        return len(data)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.binary(max_size=40), min_size=1, max_size=6), st.integers(1, 300))
def test_sendmsg_all_sends_every_byte_once_in_order(parts: list[bytes], limit: int) -> None:
    """A frame sent in pieces: whatever each sendmsg takes, every byte goes out exactly once,
    and a socket that takes it all needs one call."""
    size = sum(map(len, parts))
    sock = _ShortSends(limit)
    _sendmsg_all(sock, parts, size)  # type: ignore[arg-type]
    assert sock.out == b"".join(parts)
    if size <= limit:
        assert sock.calls == 1


def test_200_slowloris_connections_from_one_host_leave_room_for_another(serve: Serve) -> None:
    """[RS-7.24] 200 connections from 127.0.0.2 trickling header bytes: at most
    max_per_address of them are served, the rest get BUSY (EmergencyStop only); 127.0.0.1
    still gets Herej answered, on a server with the default limits."""
    server = serve(EchoRobot(), ServerPolicy())
    policy = server.policy
    flood: list[socket.socket] = []
    try:
        for _ in range(200):
            s = socket.socket()
            s.settimeout(5.0)
            s.bind(("127.0.0.2", 0))
            s.connect(server.address)
            s.sendall(b"R")  # the first byte of a frame that never finishes
            flood.append(s)
        deadline = time.monotonic() + 10.0
        while server.statistics()["refused_per_address"] < 200 - policy.per_address:
            assert time.monotonic() < deadline, server.statistics()
            time.sleep(0.01)
        assert server.statistics()["clients"] <= policy.per_address
        with FramedClient(*server.address, timeout=5.0) as c:
            assert c.call(CommandId.HEREJ) == (Joints([1, 2, 3, 4, 5, 6]),)
    finally:
        for s in flood:
            s.close()


def test_requests_beyond_the_pending_limit_get_busy_at_once(server: FramedServer) -> None:
    """[RS-7.27] behind a pending WaitEndMove at most MAX_PENDING requests wait (the
    WaitEndMove counts); each further one is answered BUSY on arrival and not executed;
    EmergencyStop still gets through and the waiting ones are answered in order."""
    from spec.server import MAX_PENDING

    extra = 5
    herejs = list(range(2, MAX_PENDING + 1 + extra))  # MAX_PENDING - 1 queue, `extra` do not
    with raw_conn(server) as s:
        s.sendall(
            encode_packet(request(CommandId.WAIT_END_MOVE, 1, 30.0))
            + b"".join(encode_packet(request(CommandId.HEREJ, i)) for i in herejs)
        )
        busy = read_packets(s, extra)
        s.sendall(encode_packet(request(CommandId.EMERGENCY_STOP, 999)))
        rest = read_packets(s, 1 + 1 + MAX_PENDING - 1)
    assert [p.request_id for p in busy] == herejs[-extra:]
    assert all(p.error is not None and p.error[0] == ErrorCode.BUSY for p in busy)
    assert all(p.command == CommandId.HEREJ and "pending" in p.error[1] for p in busy)  # type: ignore[index]
    assert [p.request_id for p in rest] == [999, 1, *herejs[:-extra]]
    assert all(p.kind is PacketKind.REPLY for p in rest)


def test_idle_timeout_runs_from_the_reply_to_a_long_request(serve: Serve) -> None:
    """[RS-7.28] a WaitEndMove longer than the idle timeout is not idleness, and the idle
    time starts again from its reply, not from the request's last byte."""
    server = serve(EchoRobot(), ServerPolicy(max_clients=4, idle_timeout=1.0))
    with raw_conn(server) as s:
        s.sendall(encode_packet(request(CommandId.WAIT_END_MOVE, 1, 2.0)))
        (waited,) = read_packets(s, 1)  # False after 2 s: nothing stopped it
        assert waited.kind is PacketKind.REPLY and waited.params == (False,)
        time.sleep(0.3)  # well inside the idle timeout counted from the reply
        s.sendall(encode_packet(request(CommandId.HEREJ, 2)))
        (reply,) = read_packets(s, 1)
    assert reply.kind is PacketKind.REPLY and reply.request_id == 2


@pytest.mark.parametrize("minor", [0, 1, 2])
def test_a_1_0_to_1_2_peer_is_answered_by_a_1_3_server(server: FramedServer, minor: int) -> None:
    """[RS-1.2] frames of an older minor version are accepted; the server answers with its
    own minor (3) and says so in Hello [RS-5.31]."""
    with raw_conn(server) as s:
        s.sendall(
            encode_packet(Packet(PacketKind.REQUEST, CommandId.HELLO, 1, (1, minor, "old"), minor))
            + encode_packet(Packet(PacketKind.REQUEST, CommandId.HEREJ, 2, (), minor))
        )
        hello, herej = read_packets(s, 2)
    assert hello.kind is PacketKind.REPLY and hello.params[0] == "1.3"
    assert herej.kind is PacketKind.REPLY and herej.params == (Joints([1, 2, 3, 4, 5, 6]),)
    assert hello.version_minor == herej.version_minor == wire.VERSION_MINOR == 3
