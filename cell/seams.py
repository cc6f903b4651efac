"""The emulated cell's seam catalogue: the one list of seam names every command accepts
(``cell serve``, ``welding teach|track|calibrate|ilc|… --emulate --seam NAME``).

A seam is the scene's shape (:class:`sensorsocket.scene.SeamPath` and friends) and where the
workpiece lies off its nominal place: ``offset`` is the straight seam 5 mm to the side, what a
workpiece placement error does to a tracker.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.transforms import location_to_transform, transform_to_location
from kinematics.types import IDENTITY_LOC, Loc, as_loc

__all__ = ["SEAMS", "SEAM_NAMES", "Seam", "cell_seam"]


@dataclass(frozen=True)
class Seam:
    """One seam of the catalogue: ``shape`` (the cell's scene path: straight, sine, corner,
    jog) and ``placement`` (the workpiece's error off its nominal place; mm, deg)."""

    shape: str
    placement: Loc
    description: str


SEAMS: dict[str, Seam] = {
    "straight": Seam("straight", IDENTITY_LOC, "a straight seam along x"),
    "offset": Seam(
        "straight",
        (0.0, 5.0, 0.0, 0.0, 0.0, 0.0),
        "the straight seam 5 mm off the nominal path (a workpiece placement error)",
    ),
    "sine": Seam("sine", IDENTITY_LOC, "the paper's y = 2 sin(2π·5x/250), R ≈ 32 mm"),
    "corner": Seam("corner", IDENTITY_LOC, "a 90° corner (legs at ±45° to x)"),
    # R = 32 mm arcs (the paper's sine radius) turning 15 deg: a 4.9 mm jog off the path
    "arc": Seam("jog", IDENTITY_LOC, "two R = 32 mm arcs turning 15°: a 4.86 mm jog"),
}
#: The names, in the order ``--help`` lists them.
SEAM_NAMES: tuple[str, ...] = tuple(SEAMS)


def cell_seam(name: str, workpiece_error: Loc = IDENTITY_LOC) -> tuple[str, Loc]:
    """(``seam``, ``workpiece_error``) of :class:`cell.cell.EmulatedCell` for the catalogue's
    ``name``; an explicit ``workpiece_error`` lies on top of the seam's own placement.
    ValueError names the seams when ``name`` is none of them."""
    try:
        seam = SEAMS[name]
    except KeyError:
        raise ValueError(f"seam must be one of {', '.join(SEAM_NAMES)}, got {name!r}") from None
    if workpiece_error == IDENTITY_LOC:
        return seam.shape, seam.placement
    if seam.placement == IDENTITY_LOC:
        return seam.shape, workpiece_error
    both = location_to_transform(np.array(seam.placement)) @ location_to_transform(
        np.array(workpiece_error)
    )
    return seam.shape, as_loc(transform_to_location(both))
