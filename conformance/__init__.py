"""Conformance harness: checks any robot, sensor or UDP sync endpoint against PROTOCOL.md
through the public protocol only (``python -m conformance --help``)."""

from __future__ import annotations

TOOL = "conformance"
TOOL_VERSION = "0.1.0"
#: Version of the case suite; bump when cases are added, removed or change their verdicts.
SUITE_VERSION = "1.0.0"
