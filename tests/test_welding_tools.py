"""The tool and frame database: the file format, the edits, and concurrent writers."""

from __future__ import annotations

import json
import multiprocessing
from pathlib import Path

import pytest

from welding.tools import Entry, Tables, ToolDB, ToolDBError

LASER = Entry("laser", "laser", (0.0, 0.0, 200.0, 0.0, 0.0, 0.0), "focus")
SENSOR = Entry("sensor", "sensor", (40.0, 0.0, 200.0, 0.0, 0.0, 0.0))
TABLE = Entry("table", "frame", (600.0, 0.0, -300.0, 0.0, 0.0, 90.0))


def test_add_show_edit_remove_round_trip(tmp_path: Path) -> None:
    db = ToolDB(tmp_path / "tools.json")
    assert db.read().tools == {}
    for e in (LASER, SENSOR, TABLE):
        db.add(e)
    t = db.read()
    assert t.tool("laser") == LASER and t.tool("sensor") == SENSOR and t.frame("table") == TABLE
    assert t.revision == 3
    assert t.has_tool("flange") and t.has_frame("world") and not t.has_tool("table")
    edited = db.edit("table", location=(1.0, 2.0, 3.0, 0.0, 0.0, 0.0))
    assert edited.note == TABLE.note and db.read().frame("table") == edited
    assert db.remove("sensor") == SENSOR
    assert not db.read().has_tool("sensor")
    data = json.loads((tmp_path / "tools.json").read_text())
    assert data["format"] == "welding-tools" and data["version"] == 1 and data["revision"] == 5


def test_refused_changes_leave_the_file_alone(tmp_path: Path) -> None:
    db = ToolDB(tmp_path / "tools.json")
    db.add(LASER)
    before = db.path.read_bytes()
    with pytest.raises(ToolDBError, match="exists already"):
        db.add(LASER)
    with pytest.raises(ToolDBError, match="built in"):
        db.add(Entry("flange", "tool", LASER.location))
    with pytest.raises(ToolDBError, match="already used by a tool"):
        db.add(Entry("laser", "frame", LASER.location))
    with pytest.raises(ToolDBError, match="bad name"):
        db.add(Entry("a b", "tool", LASER.location))
    with pytest.raises(ToolDBError, match="not a finite number"):
        db.add(Entry("x", "tool", (0.0, 0.0, float("nan"), 0.0, 0.0, 0.0)))
    with pytest.raises(ToolDBError, match="no tool or frame"):
        db.remove("nothing")
    assert db.path.read_bytes() == before


def test_compare_and_swap(tmp_path: Path) -> None:
    db = ToolDB(tmp_path / "tools.json")
    db.add(LASER)
    seen = db.read().revision
    db.add(TABLE)  # someone else
    with pytest.raises(ToolDBError, match="changed"):
        db.update(lambda t: t.remove("laser"), expect_revision=seen)
    assert db.read().has_tool("laser")


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("{", "not valid JSON"),
        ("[]", "not a tool database"),
        ('{"format": "welding-tools", "version": 9}', "version 9"),
        ('{"format": "welding-tools", "version": 1, "tools": {"a": {"location": [1]}}}', "6"),
        ('{"format": "welding-tools", "version": 1, "tools": {"a": {"kind": "x", '
         '"location": [0,0,0,0,0,0]}}}', "kind"),
        ('{"format": "welding-tools", "version": 1, "frames": {"a": {"location": '
         '[0,0,0,0,0,0], "colour": 1}}}', "unknown fields"),
    ],
)  # fmt: skip
def test_bad_files_are_refused_with_a_reason(tmp_path: Path, text: str, pattern: str) -> None:
    path = tmp_path / "tools.json"
    path.write_text(text)
    with pytest.raises(ToolDBError, match=pattern):
        ToolDB(path).read()


def test_oversized_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "tools.json"
    path.write_bytes(b" " * (4 * 1024 * 1024 + 1))
    with pytest.raises(ToolDBError, match="larger than"):
        ToolDB(path).read()


def test_import_and_export(tmp_path: Path) -> None:
    a, b = ToolDB(tmp_path / "a.json"), ToolDB(tmp_path / "b.json")
    a.add(LASER)
    a.add(TABLE)
    a.export_to(tmp_path / "out.json")
    assert b.import_from(tmp_path / "out.json") == 2
    tb = b.read()
    assert tb.tools == {"laser": LASER} and tb.frames == {"table": TABLE}
    with pytest.raises(ToolDBError, match="exists already"):
        b.import_from(tmp_path / "out.json")
    assert b.import_from(tmp_path / "out.json", replace=True) == 2
    assert Tables.loads(tb.dumps()).tools == tb.tools


def _add_many(path: str, prefix: str, n: int) -> None:
    db = ToolDB(path)
    for i in range(n):
        db.add(Entry(f"{prefix}{i}", "tool", (float(i), 0.0, 0.0, 0.0, 0.0, 0.0)))


def test_concurrent_writers_never_lose_an_update(tmp_path: Path) -> None:
    path = str(tmp_path / "tools.json")
    ctx = multiprocessing.get_context("spawn")
    procs = [ctx.Process(target=_add_many, args=(path, p, 25)) for p in ("a", "b", "c")]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    t = ToolDB(path).read()
    assert len(t.tools) == 75
    assert t.revision == 75
