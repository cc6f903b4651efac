"""Benchmarks of the project, each measured against a baseline in the same run.

Every ``bench/bench_<area>.py`` module exposes ``run() -> list[Result]``; ``python -m bench``
runs them all and writes one JSON list of results.
"""
