"""Tests for spec.datagrams beyond the vectors: serial-number arithmetic of indices [SY-1.3]."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from spec.datagrams import INDEX_MODULUS, serial_diff, serial_newer

u32 = st.integers(0, INDEX_MODULUS - 1)


def test_serial_diff_across_the_wrap() -> None:
    top = INDEX_MODULUS - 1
    assert serial_diff(0, top) == 1 and serial_diff(top, 0) == -1
    assert serial_diff(5, 5) == 0
    assert serial_newer(0, top) and not serial_newer(top, 0) and not serial_newer(7, 7)
    # half-way is ambiguous in RFC 1982; it reads as behind, so neither is newer
    assert serial_diff(1 << 31, 0) == -(1 << 31)
    assert not serial_newer(1 << 31, 0) and not serial_newer(0, 1 << 31)


@given(u32, st.integers(-(1 << 31), (1 << 31) - 1))
def test_serial_diff_inverts_a_step(b: int, step: int) -> None:
    a = (b + step) % INDEX_MODULUS
    assert serial_diff(a, b) == step
    assert serial_newer(a, b) == (step > 0)
