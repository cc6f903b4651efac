"""One rule for the folders of a tool's output files (docs/CLI.md, "Output files"): a missing
folder is created, in one helper (spec/files.py), for every option that names an output."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from spec import cliargs
from spec.files import prepare_output_dir, write_atomically

#: Options that name a file or folder a tool writes.
OUTPUT_DESTS = {"output", "out", "json", "junit", "log", "plot", "table", "keep"}


def _parsers() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    from cell.__main__ import _parser as cell
    from conformance.cli import build_parser as conformance
    from robotsocket.__main__ import build_parser as robotsocket
    from sensorsocket.__main__ import _parser as sensorsocket
    from sync.__main__ import _parser as sync
    from welding.cli import _parser as welding

    makers: dict[str, Callable[[], argparse.ArgumentParser]] = {
        "cell": cell,
        "conformance": conformance,
        "robotsocket": robotsocket,
        "sensorsocket": sensorsocket,
        "sync": sync,
        "welding": welding,
    }
    for name, make in makers.items():
        yield name, make()


def _outputs(parser: argparse.ArgumentParser, path: str) -> Iterator[tuple[str, argparse.Action]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                if name != "console":  # welding/console/ is being refactored (issue 28/33)
                    yield from _outputs(sub, f"{path} {name}")
        elif action.dest in OUTPUT_DESTS and action.nargs != 0:
            yield f"{path} {action.option_strings[-1]}", action


def test_every_output_option_follows_the_one_rule() -> None:
    rule: set[Callable[[str], str]] = {cliargs.output_file, cliargs.output_dir}
    found = [(where, a.type) for name, p in _parsers() for where, a in _outputs(p, name)]
    assert len(found) > 10, found  # the scan finds the options
    assert [where for where, kind in found if kind not in rule] == []


def test_a_missing_folder_is_created_by_the_atomic_writer(tmp_path: Path) -> None:
    target = tmp_path / "new" / "folder" / "d.json"
    write_atomically(target, "{}\n")
    assert target.read_text() == "{}\n"


def test_output_options_create_the_folder_or_refuse_in_one_line(tmp_path: Path) -> None:
    assert cliargs.output_file(str(tmp_path / "a" / "b.json"))
    assert (tmp_path / "a").is_dir()
    assert prepare_output_dir(tmp_path / "c" / "d") == tmp_path / "c" / "d"
    (tmp_path / "file").write_text("")
    with pytest.raises(argparse.ArgumentTypeError, match="exists and is not a directory"):
        cliargs.output_dir(str(tmp_path / "file"))
    with pytest.raises(argparse.ArgumentTypeError, match="is a directory"):
        cliargs.output_file(str(tmp_path / "a"))
