"""What the client does with each kind of answer to a call (spec/client.py): a scripted server
on a loopback socket answers the request with the frames a case names, built from the
request's own ID, so the reply check and the receive loop's fast return are both exercised."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator

import pytest

from spec.client import FramedClient
from spec.codec import FrameDecoder, Packet, encode_packet
from spec.errors import BadCrcError, ErrorCode, PeerError, RemoteError
from spec.registry import CommandId
from spec.wire import PacketKind

PING = int(CommandId.PING)
Script = Callable[[int], list[bytes]]  # request ID -> the frames sent back


def _frame(kind: PacketKind, command: int, request_id: int, *params: object) -> bytes:
    return encode_packet(Packet(kind, command, request_id, params))  # type: ignore[arg-type]


def _reply(rid: int) -> bytes:
    return _frame(PacketKind.REPLY, PING, rid, b"pong")


def _bad_crc(rid: int) -> bytes:
    frame = bytearray(_reply(rid))
    frame[-1] ^= 0xFF
    return bytes(frame)


@pytest.fixture
def scripted() -> Iterator[Callable[[Script], FramedClient]]:
    """A client connected to a server that answers its first request with ``script(id)``."""
    listener = socket.create_server(("127.0.0.1", 0))
    threads: list[threading.Thread] = []
    clients: list[FramedClient] = []

    def start(script: Script) -> FramedClient:
        def serve() -> None:
            conn, _ = listener.accept()
            with conn:
                decoder = FrameDecoder()
                event = None
                while event is None:
                    decoder.feed(conn.recv(4096))
                    event = decoder.next_event()
                assert isinstance(event, Packet)
                conn.sendall(b"".join(script(event.request_id)))
                conn.recv(4096)  # until the client closes

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        threads.append(thread)
        client = FramedClient(*listener.getsockname(), timeout=2.0)
        clients.append(client)
        return client

    yield start
    for client in clients:
        client.close()
    for thread in threads:
        thread.join(2.0)
    listener.close()


def test_the_reply_is_returned_after_events_and_late_replies(
    scripted: Callable[[Script], FramedClient],
) -> None:
    """Events [RS-3.14] and a reply to another request ID first: skipped, not returned."""
    client = scripted(
        lambda rid: [
            _frame(PacketKind.EVENT, PING, 0, b"event"),
            _frame(PacketKind.REPLY, PING, rid + 1000, b"other"),
            _reply(rid),
        ]
    )
    client._abandoned.add(1001)  # the ID of an interrupted call, as a late reply's
    assert client.call(PING, b"") == (b"pong",)
    assert client.connected


@pytest.mark.parametrize(
    ("script", "error", "match", "closed"),
    [
        (lambda rid: [_frame(PacketKind.REPLY, PING, rid + 7, b"")], PeerError, "id", True),
        (lambda rid: [_frame(PacketKind.REPLY, 0x0201, rid, b"")], PeerError, "0x0201", True),
        (lambda rid: [_frame(PacketKind.REQUEST, PING, rid, b"")], PeerError, "REQUEST", True),
        (lambda rid: [_frame(PacketKind.REPLY, PING, rid, 5)], PeerError, "BYTES", False),
        (lambda rid: [_bad_crc(rid)], BadCrcError, "CRC", True),
        (
            lambda rid: [_frame(PacketKind.ERROR, PING, rid, int(ErrorCode.BUSY), "busy")],
            RemoteError,
            "busy",
            False,
        ),
        (
            lambda rid: [_frame(PacketKind.ERROR, PING, 0, int(ErrorCode.BAD_FRAME), "bad")],
            RemoteError,
            "bad",
            False,
        ),
        (
            lambda rid: [_frame(PacketKind.ERROR, PING, rid + 3, int(ErrorCode.BUSY), "x")],
            PeerError,
            "does not match",
            True,
        ),
    ],
    ids=[
        "other-id",
        "other-command",
        "not-a-reply",
        "wrong-parameter-type",
        "bad-crc",
        "error-packet",
        "error-packet-id-0",
        "error-packet-other-id",
    ],
)
def test_every_answer_but_the_reply_raises_what_it_is(
    scripted: Callable[[Script], FramedClient],
    script: Script,
    error: type[Exception],
    match: str,
    closed: bool,
) -> None:
    """An error packet raises its RemoteError (the connection stays); a reply out of step or a
    broken frame raises PeerError and closes the connection (later replies would be misread)."""
    client = scripted(script)
    with pytest.raises(error, match=match):
        client.call(PING, b"")
    assert client.connected is not closed
