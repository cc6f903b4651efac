"""Peer libraries and peer server processes for the side-by-side benchmarks (issue 20).

The peers (roboticstoolbox, OpenCV, SciPy, pyzmq, pyModbusTCP) come with the ``bench``
extra only; a benchmark whose peer is missing prints one line and skips that figure.
Servers, ours and the peers', run in a subprocess each, so every round trip crosses
processes as it does in a cell.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

# The port ends where the digits end: a server's stdout and stderr share the pipe, and its
# log line can land right behind the announced port (seen: "...:455392026-11-27 ...").
_ADDRESS = re.compile(r"(?:listening on|tcp|endpoint) (\d+\.\d+\.\d+\.\d+):(\d{1,5})(?!\d)")
_START_TIMEOUT_S = 30.0


def peer(module: str, what: str) -> ModuleType | None:
    """Import a peer library, or print one line saying which figure is skipped."""
    if importlib.util.find_spec(module.split(".")[0]) is None:
        print(f"  skip {what}: {module} not installed (pip install -e '.[bench]')", file=sys.stderr)
        return None
    return importlib.import_module(module)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextmanager
def server_process(args: list[str]) -> Iterator[tuple[str, int]]:
    """Run ``python <args>`` until it logs its address ('listening on HOST:PORT', 'tcp
    HOST:PORT' or 'endpoint HOST:PORT' on stdout or stderr); yield it, stop it afterwards."""
    proc = subprocess.Popen(
        [sys.executable, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        address = _read_address(proc)
        yield address
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def _read_address(proc: subprocess.Popen[str]) -> tuple[str, int]:
    assert proc.stdout is not None
    deadline = time.monotonic() + _START_TIMEOUT_S
    seen: list[str] = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line.rstrip())
        m = _ADDRESS.search(line)
        if m:
            return m.group(1), int(m.group(2))
    raise RuntimeError(f"server {proc.args!r} gave no address: {' | '.join(seen[-5:])}")


#: A pyModbusTCP server with a default data bank, on the port given as argv[1].
MODBUS_SERVER = """
import sys
from pyModbusTCP.server import ModbusServer
s = ModbusServer("127.0.0.1", int(sys.argv[1]), no_block=True)
s.start()
print(f"listening on 127.0.0.1:{sys.argv[1]}", flush=True)
import threading
threading.Event().wait()
"""

#: A pyzmq REP socket answering every request with the same ``argv[1]``-byte array.
ZMQ_REP_SERVER = """
import sys
import numpy as np
import zmq
ctx = zmq.Context()
rep = ctx.socket(zmq.REP)
rep.bind("tcp://127.0.0.1:*")
frame = np.random.default_rng(0).integers(0, 256, int(sys.argv[1]), dtype=np.uint8)
print("endpoint " + rep.getsockopt_string(zmq.LAST_ENDPOINT).removeprefix("tcp://"), flush=True)
while True:
    rep.recv()
    rep.send(frame, copy=False)
"""
