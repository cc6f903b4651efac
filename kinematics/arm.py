"""The arm the kinematics pieces work on: the geometry they read and the input checks.

:class:`ArmGeometry` declares the attributes of a :class:`~kinematics.robot.RobotModel` that
the DGM (:mod:`kinematics.dgm`), the configurations and singularities
(:mod:`kinematics.config`), the Jacobian (:mod:`kinematics.jacobian`) and the IK
(:mod:`kinematics.ik`) use; ``RobotModel`` combines them and holds the data.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from kinematics.errors import KinematicsError
from kinematics.types import FloatArray

BoolArray = npt.NDArray[np.bool_]

#: Joint values this far outside a limit (degrees) still count as inside (round-off).
LIMIT_SLACK_DEG = 1e-9


class ArmGeometry:
    """Lengths in mm, angles in degrees (see :class:`~kinematics.robot.RobotModel`)."""

    name: str
    upper_arm_mm: float
    forearm_mm: float
    wrist_to_flange_mm: float
    shoulder_offset_mm: float
    lateral_offset_mm: float
    joint_offsets_deg: tuple[float, ...]
    #: Joint limits (6, 2) and offsets (6,) in degrees as read-only arrays.
    _limits: FloatArray
    _offsets: FloatArray
    #: Shoulder offset, lateral offset, upper arm, forearm, wrist to flange (mm).
    _lengths: tuple[float, ...]

    @property
    def reach_mm(self) -> float:
        """Distance from axis 2 to the wrist centre with the arm stretched (a2 + d4)."""
        return self.upper_arm_mm + self.forearm_mm


def vector6(q: Any, name: str = "joints") -> list[float]:
    """Joints (6,) as 6 finite Python floats, else KinematicsError naming ``name``."""
    try:
        vals = [float(v) for v in q]
    except (TypeError, ValueError):
        raise KinematicsError(f"{name}: expected 6 numbers") from None
    if len(vals) != 6:
        raise KinematicsError(f"{name}: expected 6 values, got {len(vals)}")
    for v in vals:
        if not math.isfinite(v):
            raise KinematicsError(f"{name}: contains NaN or infinity")
    return vals


def batch6(q: Any, name: str = "joints") -> FloatArray:
    """Joints (N, 6) as a finite float64 array, else KinematicsError naming ``name``."""
    try:
        arr = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise KinematicsError(f"{name}: expected an (N, 6) array of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise KinematicsError(f"{name}: expected shape (N, 6), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise KinematicsError(f"{name}: contains NaN or infinity")
    return arr
