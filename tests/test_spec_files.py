"""spec.files: atomic output; a failed write names the user's file, not the temporary one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from spec.files import atomic_path, write_atomically


def test_a_write_that_fails_names_the_target(tmp_path: Path) -> None:
    with pytest.raises(OSError) as failed:
        write_atomically("/proc/frame.pgm", b"P5")  # /proc takes no new files
    assert failed.value.filename == "/proc/frame.pgm"
    assert "/proc/frame.pgm" in str(failed.value) and ".tmp" not in str(failed.value)


def test_other_errors_pass_unchanged(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    with pytest.raises(ValueError, match="not mine"), atomic_path(target):
        raise ValueError("not mine")
    assert not target.exists() and list(tmp_path.iterdir()) == []
    write_atomically(target, "ok")
    assert target.read_text() == "ok"


def test_killed_writers_leave_nothing_behind_after_the_next_save(tmp_path: Path) -> None:
    # kill -9 in the middle of saves used to leave one orphaned temporary file per kill (#29)
    target = tmp_path / "t.json"
    code = (
        "import sys\n"
        "from spec.files import atomic_path\n"
        "with atomic_path(sys.argv[1]) as tmp:\n"
        "    tmp.write_bytes(b'x' * 38000)\n"
        "    print('writing', flush=True)\n"
        "    sys.stdin.read()\n"  # held here until killed
    )
    for _ in range(4):
        writer = subprocess.Popen([sys.executable, "-c", code, str(target)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)  # fmt: skip
        assert writer.stdout is not None and writer.stdout.readline() == "writing\n"
        writer.send_signal(signal.SIGKILL)
        writer.wait(timeout=30)
    # each writer swept the file its killed predecessor left: at most one is ever waiting
    assert len(list(tmp_path.glob(".t.*.tmp.json"))) == 1
    live = tmp_path / f".t.{os.getpid()}-00000000.tmp.json"  # a writer that still runs
    live.write_bytes(b"busy")
    write_atomically(target, "{}")
    assert target.read_text() == "{}"
    assert sorted(tmp_path.iterdir()) == sorted([target, live])
