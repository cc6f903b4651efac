"""The console's audit log: every operator action as one JSON line (issue 28 item 5).

Each line is written by one ``write()`` on a file opened with ``O_APPEND``, so a line is
never interleaved with another writer's (two consoles on one file, a log shipper) and a
reader sees whole lines only; it is flushed to disk before the action's reply goes out.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import threading
from collections import deque
from pathlib import Path
from typing import Any

__all__ = ["AuditLog", "default_audit_path"]


def default_audit_path(tools: str | Path) -> Path:
    """Beside the tool database: ``tools.json`` → ``tools.audit.jsonl``."""
    p = Path(tools)
    return p.with_name(f"{p.stem}.audit.jsonl")


class AuditLog:
    """Append-only JSON lines: time (UTC, ISO 8601), user, address, action, outcome, detail."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()

    def check(self) -> None:
        """OSError when the file cannot be appended to (the console says so at start)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        os.close(os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600))

    def record(
        self, user: str, address: str, action: str, outcome: str, **detail: Any
    ) -> dict[str, Any]:
        entry = {
            "time": dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds"),
            "user": user,
            "address": address,
            "action": action,
            "outcome": outcome,
            **detail,
        }
        data = (json.dumps(entry, ensure_ascii=False, default=str) + "\n").encode("utf-8")
        with self._lock:
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
            try:
                written = os.write(fd, data)  # one write: O_APPEND keeps the line whole
                if written != len(data):  # a full disk: say so rather than keep half a line
                    raise OSError(f"audit log {self.path}: wrote {written} of {len(data)} bytes")
                os.fsync(fd)
            finally:
                os.close(fd)
        return entry

    def tail(self, count: int = 200) -> list[dict[str, Any]]:
        """The last ``count`` entries, oldest first (a line that is not JSON is skipped)."""
        try:
            with self.path.open(encoding="utf-8", errors="replace") as f:
                lines = deque(f, maxlen=count)
        except FileNotFoundError:
            return []
        out = []
        for line in lines:
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
        return out
