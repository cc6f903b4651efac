"""One set of seam names, from the cell's seam catalogue, in every command (issue 35 item 8:
``teach`` took straight|sine|corner while ``track`` took straight|offset|sine|arc)."""

from __future__ import annotations

import argparse

import pytest

from cell.__main__ import _parser as cell_parser
from cell.seams import SEAM_NAMES, SEAMS, cell_seam
from welding.cli import _parser as welding_parser


def _seam_choices(parser: argparse.ArgumentParser, path: str = "") -> dict[str, tuple[str, ...]]:
    """``--seam`` choices of every (sub)command, by its command path."""
    found: dict[str, tuple[str, ...]] = {}
    for action in parser._actions:
        if "--seam" in action.option_strings:
            found[path] = tuple(action.choices or ())
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_seam_choices(sub, f"{path} {name}".strip()))
    return found


def test_every_command_takes_the_catalogues_seam_names() -> None:
    choices = {**_seam_choices(welding_parser()), **{
        f"cell {k}": v for k, v in _seam_choices(cell_parser()).items()
    }}  # fmt: skip
    for command in ("teach", "calibrate", "track", "ilc", "record", "cell serve", "cell demo"):
        assert command in choices, sorted(choices)
    # welding/console/ is being refactored by another change: its own test below
    assert {c: v for c, v in choices.items() if v != SEAM_NAMES and c != "console"} == {}
    assert SEAM_NAMES == ("straight", "offset", "sine", "corner", "arc")


def test_a_name_maps_to_the_cells_shape_and_placement() -> None:
    assert cell_seam("arc") == ("jog", (0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    shape, placement = cell_seam("offset")
    assert shape == "straight" and placement == SEAMS["offset"].placement
    # an explicit placement error lies on top of the seam's own
    shape, placement = cell_seam("offset", (1.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert shape == "straight" and placement == pytest.approx((1.0, 5.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="straight, offset, sine, corner, arc"):
        cell_seam("zigzag")


def test_teach_takes_a_name_it_refused_before(capsys: pytest.CaptureFixture[str]) -> None:
    args = welding_parser().parse_args(["teach", "--emulate", "--seam", "arc"])
    assert args.seam == "arc"


def test_the_console_takes_the_catalogues_seam_names() -> None:
    """For the console's change: ``add_seam_option`` of welding.track_options gives it these."""
    assert _seam_choices(welding_parser())["console"] == SEAM_NAMES
