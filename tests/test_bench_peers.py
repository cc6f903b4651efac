"""The benchmark harness finds a peer server's address in its output (bench/peers.py)."""

from __future__ import annotations

from bench.peers import _ADDRESS


def test_a_log_line_right_behind_the_announced_port_is_not_read_as_part_of_it() -> None:
    # stdout and stderr share one pipe: seen as one line in a bench run
    line = (
        "listening on 127.0.0.1:455392026-11-27 05:56:11,536 INFO    spec.server: robot server"
        " listening on 127.0.0.1:45539\n"
    )
    m = _ADDRESS.search(line)
    assert m is not None and (m.group(1), m.group(2)) == ("127.0.0.1", "45539")


def test_each_kind_of_announcement_gives_its_address() -> None:
    for line in ("listening on 10.0.0.2:4000\n", "tcp 127.0.0.1:1", "endpoint 127.0.0.1:65535"):
        m = _ADDRESS.search(line)
        assert m is not None and m.group(2) == line.split(":")[-1].strip()
