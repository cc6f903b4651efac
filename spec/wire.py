"""Wire layouts of protocol version 1.0, in one place (PROTOCOL.md sections 2-4 and 9).

All multi-byte fields are big-endian (network byte order) [RS-2.1]. Every layout is a named,
precompiled :class:`struct.Struct` with an explicit ``>``.
"""

from __future__ import annotations

import struct
from enum import IntEnum, StrEnum

#: Protocol version implemented here (PROTOCOL.md section 1).
VERSION_MAJOR = 1
VERSION_MINOR = 3
VERSION = f"{VERSION_MAJOR}.{VERSION_MINOR}"

#: Frame magic, ASCII "RS" (robot/sensor) [RS-3.1].
MAGIC = b"RS"
#: The servers' TCP ports in the paper (RobotSocket 4000, SensorSocket 2000): the port a
#: client or a command line uses when HOST alone is given.
ROBOT_PORT = 4000
SENSOR_PORT = 2000

#: Frame header: magic, version major, version minor, kind, flags, command ID, request ID,
#: payload length [RS-3.1].
HEADER = struct.Struct(">2sBBBBHII")
#: Frame trailer: CRC-32 (IEEE 802.3, as zlib.crc32) over header and payload [RS-3.6].
TRAILER = struct.Struct(">I")
#: Flags bit: this frame's trailer is 0, not a CRC (a connection where the client turned CRCs
#: off with SetFrameCrc) [RS-3.15]. Every other flag bit is reserved and 0 [RS-3.7].
FLAG_NO_CRC = 0x01
HEADER_SIZE = HEADER.size  # 16
TRAILER_SIZE = TRAILER.size  # 4
FRAME_OVERHEAD = HEADER_SIZE + TRAILER_SIZE

#: Largest payload any peer may send (16 MiB) [RS-3.5]; a receiver may announce less.
MAX_PAYLOAD = 16 * 1024 * 1024
#: Payload limit our servers use unless configured otherwise (a 512x256 image is 128 KiB).
DEFAULT_MAX_PAYLOAD = 4 * 1024 * 1024


class PacketKind(IntEnum):
    """Packet kind byte of the frame header (PROTOCOL.md section 3)."""

    REQUEST = 1
    REPLY = 2
    ERROR = 3
    EVENT = 4


class ParamType(IntEnum):
    """Type tag of one parameter in the self-describing parameter list (section 4)."""

    INT = 0x01
    FLOAT = 0x02
    BOOL = 0x03
    STRING = 0x04
    BYTES = 0x05
    FLOAT_ARRAY = 0x06
    INT_ARRAY = 0x07
    JOINTS = 0x08
    LOCATION = 0x09
    TRANSFORM = 0x0A
    MATRIX = 0x0B
    IMAGE = 0x0C


class PixelFormat(IntEnum):
    """Pixel format of an IMAGE parameter (section 4.12)."""

    MONO8 = 1
    MONO16 = 2


class PixelOrder(IntEnum):
    """Storage order of an IMAGE parameter's pixels (section 4.12).

    COLUMN_MAJOR is the order a column-wise read-out CMOS chip delivers them.
    """

    ROW_MAJOR = 0
    COLUMN_MAJOR = 1


BYTES_PER_PIXEL = {PixelFormat.MONO8: 1, PixelFormat.MONO16: 2}

PARAM_COUNT = struct.Struct(">H")
TAG = struct.Struct(">B")
I64 = struct.Struct(">q")
F64 = struct.Struct(">d")
U8 = struct.Struct(">B")
U32 = struct.Struct(">I")
LOCATION = struct.Struct(">6d")
TRANSFORM = struct.Struct(">16d")
MATRIX_SHAPE = struct.Struct(">II")
IMAGE_HEADER = struct.Struct(">HHBBI")
MAX_JOINTS = 16

#: Command ID ranges (section 5.1).
COMMON_RANGE = range(0x0001, 0x1000)
ROBOT_RANGE = range(0x1000, 0x2000)
SENSOR_RANGE = range(0x2000, 0x3000)
SYNC_RANGE = range(0x3000, 0x4000)
VENDOR_RANGE = range(0x8000, 0xC000)
EXPERIMENTAL_RANGE = range(0xC000, 0xFFFF)

# --- UDP datagrams of the synchronisation (section 9) ---------------------------------------

#: Datagram magic, ASCII "SY" [SY-1.1].
DATAGRAM_MAGIC = b"SY"


class DatagramKind(IntEnum):
    """Kind byte of a synchronisation datagram (section 9)."""

    TRIGGER = 1
    DATA = 2


class MoveOutcome(StrEnum):
    """How the last queued move ended: WaitEndMove's ``outcome`` (1.3) [RS-5.50]."""

    REACHED = "reached"  # it reached its target and the arm settled
    MOVING = "moving"  # the wait ended first: the move goes on
    STOPPED = "stopped"  # stopped short: the reason says by what
    FAILED = "failed"  # the robot could not execute it: the reason says why


class SensorStatus(IntEnum):
    """Status of a sensor data datagram and of GetData (section 9.3)."""

    FOUND = 0
    NOT_FOUND = 1
    LASER_OFF = 2
    OVERRUN = 3
    ERROR = 4

    def problem(self, sensor: str = "HOST:PORT") -> str:
        """What a measurement without a seam tells an operator, and what to do about it
        [SS-5.13]; "" for FOUND. ``sensor``: the sensor's address, for the command."""
        return _STATUS_PROBLEMS[self].format(sensor=sensor)


# One text per status, for every tool: "laser off" is never reported as "no seam" [SS-5.13].
_STATUS_PROBLEMS = {
    SensorStatus.FOUND: "",
    SensorStatus.NOT_FOUND: "the sensor does not see a seam (status NOT_FOUND): "
    "move the sensor over the seam",
    SensorStatus.LASER_OFF: "the sensor's laser is off (status LASER_OFF): switch it on with "
    "`python -m sensorsocket call {sensor} SetLaser on --token-file FILE`",
    SensorStatus.OVERRUN: "the sensor was still busy with the previous trigger "
    "(status OVERRUN): lower the trigger rate",
    SensorStatus.ERROR: "the sensor could not process its image (status ERROR): "
    "look at it with `python -m sensorsocket snapshot {sensor} -o frame.pgm`",
}


#: Datagram header: magic, version major, minor, kind, flags, index [SY-1.1].
DATAGRAM_HEADER = struct.Struct(">2sBBBBI")
#: Trigger body: robot send time t_i^T in seconds on the robot clock [SY-2.1].
TRIGGER_BODY = struct.Struct(">d")
#: Data body: status, reserved, seam2sensor location (6 x f64), quality, echoed t_i^T,
#: sensor-clock times of trigger arrival, exposure start and exposure end [SY-3.1].
DATA_BODY = struct.Struct(">BB6ddd3d")
TRIGGER_SIZE = DATAGRAM_HEADER.size + TRIGGER_BODY.size + TRAILER_SIZE  # 22
DATA_SIZE = DATAGRAM_HEADER.size + DATA_BODY.size + TRAILER_SIZE  # 104
