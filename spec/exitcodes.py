"""The exit codes of every command line of the project, in one table (docs/CLI.md).

A script or a CI system reads these, so one number means one thing in every tool: a robot
that refused, a harness that found a MUST failure and a tracked weld out of tolerance all end
with FAILED; a measurement the tool cannot vouch for ends with UNTRUSTED, never with a
plausible number and exit 0.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["ExitCode"]


class ExitCode(IntEnum):
    """Process exit status of the project's command lines (docs/CLI.md, "Exit codes")."""

    #: Done; conformant; within tolerance; every target met.
    OK = 0
    #: The endpoint refused (an error reply), a MUST requirement failed, a move stopped short of
    #: its target, a result out of its tolerance, a benchmark target missed.
    FAILED = 1
    #: A bad command line or input file: nothing was sent or started.
    USAGE = 2
    #: The endpoint cannot be reached or does not speak the protocol.
    UNREACHABLE = 3
    #: A result that cannot be trusted (too short, too noisy, the machine too slow to judge):
    #: the tool says why instead of printing it as if it were good.
    UNTRUSTED = 4
    #: The conformance harness: only SHOULD requirements failed (with ``--strict``).
    SHOULD_FAILED = 5
    #: The conformance harness: conformant to the profiles the endpoint claims, not to all of
    #: the protocol version.
    SUBSET = 6
    #: The conformance harness: no case was selected.
    NOTHING_SELECTED = 7
    #: Stopped by Ctrl-C (128 + SIGINT): the tool's controlled stop ran.
    INTERRUPTED = 130
    #: The reader of our standard output went away (``… | head``; 128 + SIGPIPE).
    BROKEN_PIPE = 141
