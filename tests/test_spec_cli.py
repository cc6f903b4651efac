"""``python -m spec`` as a user runs it: real subprocesses."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from spec.__main__ import cmd_vectors
from spec.exitcodes import ExitCode
from spec.vectorgen import load

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "spec", *args],
        capture_output=True,
        text=True,
        input=stdin,
        cwd=ROOT,
        timeout=60,
    )


def test_decode_hex_prints_every_field() -> None:
    hex_text = next(v["hex"] for v in load("frames.json") if v["name"] == "reply-herej")
    r = run("decode", hex_text)
    assert r.returncode == 0, r.stderr
    assert "Herej" in r.stdout and "REPLY" in r.stdout and "[10, -20, 90, 0, 45, 0]" in r.stdout
    assert "[deg]" in r.stdout and "crc32" in r.stdout


def test_decode_a_file_and_stdin(tmp_path: Path) -> None:
    raw = bytes.fromhex(next(v["hex"] for v in load("datagrams.json") if v["name"] == "trigger"))
    f = tmp_path / "trigger.bin"
    f.write_bytes(raw)
    r = run("decode", str(f))
    assert r.returncode == 0 and "TRIGGER" in r.stdout and "index            42" in r.stdout
    r = run("decode", "-", stdin=raw.hex(" "))
    assert r.returncode == 0 and "TRIGGER" in r.stdout


def test_decode_bad_input_is_one_line_and_an_exit_code() -> None:
    # not bytes at all: a usage error; bytes that break a rule of the spec: a failure
    for arg, code in (("not-hex", ExitCode.USAGE), ("5253", ExitCode.FAILED)):
        r = run("decode", arg)
        assert r.returncode == code, (arg, r.stderr)
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    r = run("decode", "52530100")
    assert r.returncode == ExitCode.FAILED and r.stderr.count("\n") == 1
    bad_crc = next(v["hex"] for v in load("frames.json") if v["name"] == "bad-crc")
    r = run("decode", bad_crc)
    assert r.returncode == ExitCode.FAILED and "BAD_CRC" in r.stderr


def test_doc_check_and_requirements_listing() -> None:
    assert run("doc", "--check").returncode == 0
    r = run("requirements")
    assert r.returncode == 0 and "RS-3.1" in r.stdout and "MUST" in r.stdout


def test_decode_a_capture_of_several_frames(tmp_path: Path) -> None:
    frames = [bytes.fromhex(v["hex"]) for v in load("frames.json") if v["valid"]][:3]
    capture = tmp_path / "capture.bin"
    capture.write_bytes(b"".join(frames))
    r = run("decode", str(capture))
    assert r.returncode == 0, r.stderr
    assert "== frame 3 of 3" in r.stdout
    capture.write_bytes(b"".join(frames) + frames[0][:5])
    r = run("decode", str(capture))
    assert r.returncode == ExitCode.FAILED and "truncated frame" in r.stderr
    # a capture cut short still shows the frames it holds, then where it stopped
    assert "== frame 3\n" in r.stdout and "== frame 4" not in r.stdout
    assert r.stderr.splitlines() == ["spec decode: invalid: BAD_FRAME (1): truncated frame at"
                                     f" byte {len(b''.join(frames))}: 5 of 16 bytes"]  # fmt: skip


def test_vectors_end_with_a_summary_and_the_shipped_capture_decodes() -> None:
    r = run("vectors")
    last = r.stdout.splitlines()[-1]
    vectors = load("frames.json") + load("datagrams.json")
    valid = sum(v["valid"] for v in vectors)
    expected = (
        f"{len(vectors)} vectors: {valid} valid, {len(vectors) - valid} invalid; all as expected"
    )
    assert r.returncode == 0 and last == expected
    r = run("decode", "spec/capture.bin")
    assert r.returncode == 0 and "== frame 6 of 6" in r.stdout


def test_vectors_exit_1_naming_a_vector_not_as_marked(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = {**load("frames.json")[0], "name": "marked-wrongly", "valid": False, "error": "BAD_CRC"}
    monkeypatch.setattr("spec.vectorgen.load", lambda name: [bad] if name == "frames.json" else [])
    # cmd_vectors, not main: main sets SIGPIPE to its default, which would outlive this test
    assert cmd_vectors(argparse.Namespace(generate=False, force=False)) == ExitCode.FAILED
    last = capsys.readouterr().out.splitlines()[-1]
    assert last == "1 vectors: 0 valid, 1 invalid; 1 not as expected: frames.json:marked-wrongly"
