"""Time the Wireshark dissector over a large capture (not part of ``python -m bench``: it
needs tshark). ``python -m bench.dissect_capture [--mb 100] [--keep FILE]``

The capture is a robot and sensor session as the recorder writes it: GetImage replies
(512 x 256 MONO8, 128 KiB each, split over segments) between Herej and GetStatus round trips,
until it holds ``--mb`` megabytes. tshark reads it twice: without the dissector (the TCP/IP
baseline) and with it (every frame dissected, CRC-32 checked, requests linked to replies),
and the difference is the dissector's time.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from spec import cliargs, dissector
from spec.codec import Packet, encode_packet
from spec.exitcodes import ExitCode
from spec.params import Image, Joints
from spec.pcapng import PcapngWriter, TcpFlow
from spec.registry import CommandId
from spec.wire import PacketKind


def build(path: Path, megabytes: float) -> int:
    """Write the capture; returns the number of RobotSocket/SensorSocket frames in it."""
    rng = np.random.default_rng(1)
    client = (ipaddress.ip_address("10.0.0.1"), 40000)
    robot = TcpFlow(client, (ipaddress.ip_address("10.0.0.2"), 4000))
    sensor = TcpFlow((client[0], 40001), (ipaddress.ip_address("10.0.0.3"), 2000))
    pixels = rng.integers(0, 256, 512 * 256, dtype=np.uint8).tobytes()
    image = Image(512, 256, pixels)
    frames = 0
    stamp = 1_700_000_000_000_000_000
    with PcapngWriter(path, "bench.dissect_capture") as w:
        w.write_all(robot.handshake() + sensor.handshake(), stamp)
        rid = 0
        while os.path.getsize(w.partial) < megabytes * 1e6:
            rid += 1
            stamp += 4_000_000
            for flow, req, rep in (
                (robot, Packet(PacketKind.REQUEST, CommandId.HEREJ, rid),
                 Packet(PacketKind.REPLY, CommandId.HEREJ, rid, (Joints(rng.normal(size=6)),))),
                (robot, Packet(PacketKind.REQUEST, CommandId.ROBOT_STATUS, rid), None),
            ):  # fmt: skip
                w.write_all(flow.data(True, encode_packet(req)), stamp)
                frames += 1
                if rep is not None:
                    w.write_all(flow.data(False, encode_packet(rep)), stamp + 200_000)
                    frames += 1
            w.write_all(sensor.data(True, encode_packet(
                Packet(PacketKind.REQUEST, CommandId.GET_IMAGE, rid))), stamp)  # fmt: skip
            reply = Packet(PacketKind.REPLY, CommandId.GET_IMAGE, rid, (rid, image))
            w.write_all(sensor.data(False, encode_packet(reply)), stamp + 1_000_000)
            frames += 2
    return frames


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.dissect_capture")
    parser.add_argument("--mb", type=float, default=100.0, help="size of the capture, MB")
    parser.add_argument(
        "--keep", metavar="FILE", type=cliargs.output_file, help="keep the capture here"
    )
    args = parser.parse_args()
    tshark = shutil.which("tshark")
    if tshark is None:
        print("tshark is not installed (apt-get install tshark)", file=sys.stderr)
        return ExitCode.USAGE  # nothing was started
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.keep) if args.keep else Path(tmp) / "big.pcapng"
        frames = build(path, args.mb)
        size = os.path.getsize(path) / 1e6
        times = {}
        lua = ["-X", f"lua_script:{dissector.LUA_PATH}"]
        for label, load, field in (
            ("tcp/ip only", [], "tcp.len"),
            ("dissector", lua, "rsock.crc.status"),
        ):
            start = time.perf_counter()
            cmd = [tshark, "-n", "-2", *load, "-r", str(path), "-T", "fields", "-e", field]
            r = subprocess.run(cmd, capture_output=True, text=True)
            times[label] = time.perf_counter() - start
            if r.returncode:
                print(r.stderr, file=sys.stderr)
                return ExitCode.FAILED
            if label == "dissector":
                statuses = r.stdout.split()
                good = sum(s.split(",").count("1") for s in statuses)
        print(f"dissected {good} frames with a good CRC-32 of {frames}")
        print(
            f"capture {size:.1f} MB, {frames} frames; tshark -r: TCP/IP only "
            f"{times['tcp/ip only']:.1f} s, with the dissector {times['dissector']:.1f} s "
            f"({size / times['dissector']:.1f} MB/s)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
