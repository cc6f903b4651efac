"""spec.files: atomic output; a failed write names the user's file, not the temporary one."""

from __future__ import annotations

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
