"""Tests for sync.network: the modelled one-way network of simulated time."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from sync.network import DelayLink


def test_fixed_delay_delivers_in_send_order_at_send_plus_delay() -> None:
    link = DelayLink(delay_s=5e-3)
    for k in range(5):
        link.send(k * 1e-3, bytes([k]))
    assert link.deliver(0.0069) == [(5e-3, b"\x00"), (6e-3, b"\x01")]
    assert [d for _, d in link.deliver(1.0)] == [b"\x02", b"\x03", b"\x04"]
    assert link.deliver(2.0) == []
    assert link.counts == {"sent": 5, "lost": 0, "duplicated": 0, "delayed": 0, "delivered": 5}


def test_faults_are_counted_and_reorder() -> None:
    link = DelayLink(
        delay_s=1e-3,
        rng=np.random.default_rng(3),
        loss=0.1,
        duplicate=0.1,
        reorder=0.1,
        reorder_delay_s=0.02,
    )
    n = 2000
    for k in range(n):
        link.send(k * 4e-3, k.to_bytes(2, "big"))
    out = link.deliver(100.0)
    c = link.counts
    assert 100 < c["lost"] < 300 and 100 < c["duplicated"] < 300 and c["delayed"] > 100
    assert len(out) == c["delivered"] == n - c["lost"] + c["duplicated"]
    arrivals = [t for t, _ in out]
    assert arrivals == sorted(arrivals)
    order = [int.from_bytes(d, "big") for _, d in out]
    assert any(b < a for a, b in itertools.pairwise(order))  # reordered
    assert len(set(order)) == n - c["lost"]


def test_bad_parameters_are_rejected() -> None:
    with pytest.raises(ValueError, match="delay_s"):
        DelayLink(delay_s=1e-3, jitter_s=3e-3, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="probability"):
        DelayLink(loss=1.5, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="rng"):
        DelayLink(loss=0.1)
