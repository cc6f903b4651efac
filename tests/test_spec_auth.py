"""Token files, token comparison and the TakeControl back-off [RS-7.20] (fake clock)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from spec.auth import AuthBackoff, read_token_file, tokens_equal


def test_token_file_is_stripped(tmp_path: Path) -> None:
    path = tmp_path / "token"
    path.write_text("  s3cret\n", encoding="utf-8")
    assert read_token_file(path) == "s3cret"


@pytest.mark.parametrize("text", ["", "   ", "\n\n", "\t \r\n"])
def test_empty_token_file_is_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "token"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ValueError, match=f"token file {path} is empty"):
        read_token_file(path)


def test_missing_token_file_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"cannot read token file .*missing"):
        read_token_file(tmp_path / "missing")


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_unreadable_token_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "token"
    path.write_text("x", encoding="utf-8")
    path.chmod(0)
    with pytest.raises(ValueError, match="cannot read token file"):
        read_token_file(path)


def test_token_file_of_two_lines_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "token"
    path.write_text("one\ntwo\n", encoding="utf-8")
    with pytest.raises(ValueError, match="several lines"):
        read_token_file(path)


def test_binary_token_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "token"
    path.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="not UTF-8"):
        read_token_file(path)


def test_tokens_equal_handles_any_text() -> None:
    assert tokens_equal("abc", "abc")
    assert not tokens_equal("abc", "abd")
    assert not tokens_equal("", "abc")
    # hmac.compare_digest refuses non-ASCII str; the tokens are compared as UTF-8 bytes.
    assert tokens_equal("clé-ü", "clé-ü")
    assert not tokens_equal("clé", "cle")


def test_free_failures_then_doubling_up_to_the_cap() -> None:
    b = AuthBackoff(base=0.1, cap=1.0, threshold=3)
    now = 100.0
    delays = []
    for _ in range(9):
        assert b.wait("10.0.0.1", now) == 0.0
        _, delay = b.failed("10.0.0.1", now)
        delays.append(delay)
        now += delay
    assert delays == pytest.approx([0, 0, 0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0])


def test_refused_until_the_delay_has_passed() -> None:
    b = AuthBackoff(base=0.5, cap=10.0, threshold=1)
    count, delay = b.failed("a", 10.0)
    assert (count, delay) == (1, 0.5)
    assert b.wait("a", 10.0) == pytest.approx(0.5)
    assert b.wait("a", 10.3) == pytest.approx(0.2)
    assert b.wait("a", 10.5) == 0.0
    assert b.wait("b", 10.0) == 0.0  # per address


def test_success_resets_the_address() -> None:
    b = AuthBackoff(base=0.1, cap=1.0, threshold=2)
    b.failed("a", 0.0)
    b.failed("a", 0.0)
    b.succeeded("a")
    assert b.wait("a", 0.0) == 0.0
    assert b.failed("a", 1.0) == (1, 0.0)  # counting starts again


def test_old_failures_are_forgotten() -> None:
    b = AuthBackoff(base=0.1, cap=1.0, threshold=2, forget=60.0)
    b.failed("a", 0.0)
    assert b.failed("a", 1.0) == (2, 0.1)
    assert b.failed("a", 100.0) == (1, 0.0)


def test_table_is_bounded() -> None:
    b = AuthBackoff(base=0.1, cap=1.0, threshold=1, max_addresses=3)
    for i in range(10):
        b.failed(f"10.0.0.{i}", 0.0)
    assert len(b) == 3
    assert b.wait("10.0.0.9", 0.0) > 0.0  # the most recent stay
    assert b.wait("10.0.0.0", 0.0) == 0.0  # the oldest went first


def test_huge_failure_counts_stay_at_the_cap() -> None:
    b = AuthBackoff(base=0.1, cap=10.0, threshold=1)
    for _ in range(5000):
        _, delay = b.failed("a", 0.0)
    assert delay == 10.0


@pytest.mark.parametrize(
    "kwargs", [{"base": 0.0}, {"base": 2.0, "cap": 1.0}, {"threshold": 0}, {"max_addresses": 0}]
)
def test_bad_settings_are_refused(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        AuthBackoff(**kwargs)  # type: ignore[arg-type]
