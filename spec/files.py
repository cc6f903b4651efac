"""Atomic file output for every tool of the project: a reader (a user, a CI system) sees the
old file or the whole new one, never half of it; nothing is left behind on failure.

One rule for the folders of an output (docs/CLI.md, "Output files"): a missing folder is
created, as ``mkdir -p`` would, by :func:`prepare_output_path` (a file) or
:func:`prepare_output_dir` (a folder of files); command lines call them when they parse the
option (``spec.cliargs.output_file`` / ``output_dir``), so a path that cannot be written is
refused before any work, and :func:`atomic_path` applies the same rule to every write."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path


def prepare_output_path(path: str | os.PathLike[str]) -> Path:
    """Make sure a file can be written at ``path`` (its directory is created if missing) and
    return it; ValueError naming the problem otherwise. Command lines call it before a long
    run, so a bad path fails at once instead of after the work."""
    target = Path(path)
    if target.is_dir():
        raise ValueError(f"{target} is a directory; give a file name")
    prepare_output_dir(target.parent)
    return target


def prepare_output_dir(path: str | os.PathLike[str]) -> Path:
    """Make sure ``path`` is a folder files can be written into (created if missing) and
    return it; ValueError naming the problem otherwise (the rule of
    :func:`prepare_output_path`)."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise ValueError(f"{target} exists and is not a directory")
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create directory {target}: {exc.strerror}") from None
    if not os.access(target, os.W_OK):
        raise ValueError(f"directory {target} is not writable")
    return target


def _temporary_name(target: Path, pid: int) -> Path:
    return target.with_name(f".{target.stem}.{pid}-{secrets.token_hex(4)}.tmp{target.suffix}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def sweep_stale_temporaries(target: Path) -> list[Path]:
    """Remove the temporary files of ``target`` left by writers that no longer run (a
    ``kill -9`` during a save) and return them; a live writer's file is left alone."""
    removed: list[Path] = []
    prefix, suffix = f".{target.stem}.", f".tmp{target.suffix}"
    try:
        siblings = list(target.parent.iterdir())
    except OSError:
        return removed
    for candidate in siblings:
        name = candidate.name
        if not (name.startswith(prefix) and name.endswith(suffix)):
            continue
        pid_text = name[len(prefix) : -len(suffix)].split("-", 1)[0]
        if not pid_text.isdigit() or _alive(int(pid_text)):
            continue
        with suppress(OSError):
            candidate.unlink()
            removed.append(candidate)
    return removed


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; synced to disk and renamed over ``path``
    on success.

    The temporary name keeps the suffix (libraries choose the format by it) and carries the
    writer's process ID, so the next save sweeps what a killed writer left behind. It is
    created with the process's umask, so the result has the usual permissions (not mkstemp's
    0600). The sync before the rename keeps a power cut from leaving an empty file in place
    of the old one.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)  # the one rule: a missing folder is made
    sweep_stale_temporaries(target)
    tmp = _temporary_name(target, os.getpid())
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, target)
    except OSError as exc:
        if exc.filename not in (str(tmp), tmp):
            raise
        # The user named the target, not our temporary file: say that one (same errno/type).
        raise type(exc)(exc.errno, exc.strerror, str(target)) from None
    finally:
        tmp.unlink(missing_ok=True)


def write_atomically(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` atomically."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with atomic_path(path) as tmp, open(tmp, "xb") as f:
        f.write(raw)
