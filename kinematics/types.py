"""The project's numeric type names, one declaration each (issue 33): a float64 array, the
VAL3 location and its identity. Every package above ``spec`` imports them from here; the
location and its identity are declared in :mod:`spec.params` (a plain tuple, no numpy, beside
the wire's ``Location``) and re-exported.

Why a location is a tuple and not an array: it is a record of two units (mm, degrees) whose
angles do not add as a vector's components do, it is hashable and immutable, and it is what
the tool database and the job files hold. Joints, transforms and point sets are arrays.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import SupportsFloat

import numpy as np
import numpy.typing as npt

from spec.params import IDENTITY_LOC, Loc

__all__ = ["IDENTITY_LOC", "FloatArray", "Loc", "as_loc"]

#: Any float64 array: joints (6,), transforms (4, 4) or (N, 4, 4), point sets (N, 3), ...
FloatArray = npt.NDArray[np.float64]


def as_loc(values: Iterable[SupportsFloat]) -> Loc:
    """Six numbers (a list, an array, a wire location's values) as a :data:`Loc` of Python
    floats; ValueError unless there are exactly six."""
    v = [float(x) for x in values]
    if len(v) != 6:
        raise ValueError(f"a location has 6 values (x, y, z, rx, ry, rz), got {len(v)}")
    return (v[0], v[1], v[2], v[3], v[4], v[5])
