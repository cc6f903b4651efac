"""Seeded fuzzing: the decoders raise only their own errors, never anything else."""

from __future__ import annotations

from spec import fuzz


def test_5000_random_and_mutated_inputs_raise_only_codec_errors() -> None:
    report = fuzz.run(5000, seed=20261121)
    assert report.inputs == 5000
    assert report.failures == []
    # The corpus reaches every layer of the decoder, not just the magic check.
    for code in ("BAD_FRAME", "BAD_CRC", "FRAME_TOO_LARGE", "BAD_PARAMETERS"):
        assert report.rejected[code] > 0, code
    assert report.packets > 0


def test_fuzz_is_deterministic_for_a_seed() -> None:
    a, b = fuzz.run(300, seed=7), fuzz.run(300, seed=7)
    assert (a.packets, a.rejected) == (b.packets, b.rejected)
