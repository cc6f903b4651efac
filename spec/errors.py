"""Wire error codes and the one exception hierarchy that carries them.

Every rejection in this project raises a :class:`ProtocolError` subclass whose ``code`` is
the :class:`ErrorCode` sent in the error packet, so a server turns any rejection into the
right error packet in one place (PROTOCOL.md section 6, requirement RS-6.1).

Two families, as in h11: :class:`PeerError` is something the *peer* sent that breaks the
protocol (raised by the decoder and by servers); :class:`UsageError` is a mistake of the local
caller (encoding a value that cannot be put on the wire).
"""

from __future__ import annotations

from enum import IntEnum


class ErrorCode(IntEnum):
    """Error codes of the error packet (PROTOCOL.md section 6, table "Error codes")."""

    BAD_FRAME = 1
    BAD_CRC = 2
    UNSUPPORTED_VERSION = 3
    FRAME_TOO_LARGE = 4
    UNKNOWN_COMMAND = 5
    BAD_PARAMETERS = 6
    OUT_OF_RANGE = 7
    UNREACHABLE = 8
    SINGULARITY = 9
    NOT_POWERED = 10
    NOT_IN_CONTROL = 11
    BUSY = 12
    EMERGENCY_STOP = 13
    AUTH_FAILED = 14
    NOT_SUPPORTED = 15
    NO_DATA = 16
    BAD_STATE = 17
    TIMEOUT = 18
    INTERNAL_ERROR = 19


#: One-line meaning of every code, used by PROTOCOL.md's table, the decoder CLI and clients.
ERROR_MEANINGS: dict[ErrorCode, str] = {
    ErrorCode.BAD_FRAME: "malformed frame: bad magic, kind or flags",
    ErrorCode.BAD_CRC: "CRC-32 of the frame does not match its contents",
    ErrorCode.UNSUPPORTED_VERSION: "protocol major version not supported by the receiver",
    ErrorCode.FRAME_TOO_LARGE: "payload length above the receiver's maximum",
    ErrorCode.UNKNOWN_COMMAND: "command ID not implemented by this service",
    ErrorCode.BAD_PARAMETERS: "parameter count, type tag or encoding does not match the command",
    ErrorCode.OUT_OF_RANGE: "a value is outside its allowed range (e.g. joint limits)",
    ErrorCode.UNREACHABLE: "the requested location cannot be reached by the arm",
    ErrorCode.SINGULARITY: "the requested path crosses or ends in a singularity",
    ErrorCode.NOT_POWERED: "arm power is off",
    ErrorCode.NOT_IN_CONTROL: "this connection does not hold control",
    ErrorCode.BUSY: "resource busy: client limit reached or control held by another client",
    ErrorCode.EMERGENCY_STOP: "emergency stop is engaged",
    ErrorCode.AUTH_FAILED: "control token missing or wrong",
    ErrorCode.NOT_SUPPORTED: "command known but the capability is not offered",
    ErrorCode.NO_DATA: "no measurement or data available yet",
    ErrorCode.BAD_STATE: "command not allowed in the current state",
    ErrorCode.TIMEOUT: "a frame stopped half-way or the connection stayed idle too long",
    ErrorCode.INTERNAL_ERROR: "the server failed while executing the request",
}


class ProtocolError(Exception):
    """Base of every error that maps to a wire error code."""

    code: ErrorCode = ErrorCode.INTERNAL_ERROR

    def __init__(self, message: str, code: ErrorCode | None = None) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code
        self.message = message

    def __str__(self) -> str:
        return f"{self.code.name} ({int(self.code)}): {self.message}"


class PeerError(ProtocolError):
    """The peer sent something that breaks the protocol."""


class FrameError(PeerError):
    """The frame header is unusable; the receiver cannot find the next frame boundary."""

    code = ErrorCode.BAD_FRAME


class BadCrcError(PeerError):
    """The frame is delimited correctly but its CRC-32 does not match."""

    code = ErrorCode.BAD_CRC


class VersionError(PeerError):
    code = ErrorCode.UNSUPPORTED_VERSION


class FrameTooLargeError(PeerError):
    code = ErrorCode.FRAME_TOO_LARGE


class ParameterError(PeerError):
    """A parameter list that cannot be decoded or does not match the command."""

    code = ErrorCode.BAD_PARAMETERS


class DatagramError(PeerError):
    """A UDP datagram that must be counted and dropped (PROTOCOL.md section 9)."""

    code = ErrorCode.BAD_FRAME


class UsageError(ProtocolError, ValueError):
    """The local caller asked for something that cannot be encoded."""

    code = ErrorCode.BAD_PARAMETERS


class RemoteError(ProtocolError):
    """An error packet received from the peer, raised by clients."""

    def __init__(self, code: int, message: str, command: int = 0, request_id: int = 0) -> None:
        try:
            known = ErrorCode(code)
        except ValueError:
            known = ErrorCode.INTERNAL_ERROR
        super().__init__(message, known)
        self.raw_code = code
        self.command = command
        self.request_id = request_id

    def __str__(self) -> str:
        name = self.code.name if self.raw_code == int(self.code) else f"code {self.raw_code}"
        return f"{name} ({self.raw_code}): {self.message}"


def error_text(exc: BaseException) -> str:
    """What went wrong, for a one-line message to a user: an error reply keeps the code the
    server sent ("NOT_POWERED (10): ...": it says what to do); our own errors (no reply, a bad
    frame, closed) only their text, since their wire code would read as the server's; a
    socket error its reason, without "[Errno 111]"."""
    if isinstance(exc, RemoteError):
        return str(exc)
    if isinstance(exc, ProtocolError):
        return exc.message
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.strerror}: {exc.filename}" if exc.filename else exc.strerror
    return str(exc)
