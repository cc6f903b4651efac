"""Seam location in the robot base frame (paper eqs. 2-3), batched.

    seam2base = flange2base(q) · sensor2flange · seam2sensor
    (^B_G T = DGM(q) · ^N_S T · ^S_G T)

Transforms are 4x4 homogeneous matrices, translations in mm. The kinematics are passed in as a
batch callable so this module does not depend on a particular robot model. This is the only
place that composes the chain: the matcher and the robot's sync core call :func:`seam2base`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["FlangeToBase", "seam2base", "seam_positions"]

FlangeToBase = Callable[[NDArray[np.float64]], NDArray[np.float64]]
"""Batch DGM: joints (M, 6) in degrees -> flange2base transforms (M, 4, 4), mm."""


def seam2base(
    joints: ArrayLike,
    flange2base: FlangeToBase,
    sensor2flange: ArrayLike,
    seam2sensor: ArrayLike,
) -> NDArray[np.float64]:
    """Compose eq. 2 for a batch of seam measurements.

    Args:
        joints: interpolated joints q(t_i^S), shape (M, 6), degrees.
        flange2base: batch DGM, (M, 6) degrees -> (M, 4, 4).
        sensor2flange: ^N_S T, the sensor tool, shape (4, 4).
        seam2sensor: ^S_G T per measurement, shape (M, 4, 4), or (4, 4) shared by all.

    Returns:
        ^B_G T, shape (M, 4, 4).
    """
    # the arrays keep the names of the frames they map, with a _m (matrix) suffix
    q = np.asarray(joints, dtype=np.float64)
    sensor2flange_m = np.asarray(sensor2flange, dtype=np.float64)
    seam2sensor_m = np.asarray(seam2sensor, dtype=np.float64)
    if q.ndim != 2:
        raise ValueError(f"joints must have shape (M, J), got {q.shape}")
    m = q.shape[0]
    if sensor2flange_m.shape != (4, 4):
        raise ValueError(f"sensor2flange must have shape (4, 4), got {sensor2flange_m.shape}")
    if seam2sensor_m.shape not in ((4, 4), (m, 4, 4)):
        raise ValueError(
            f"seam2sensor must have shape (4, 4) or ({m}, 4, 4), got {seam2sensor_m.shape}"
        )
    flange2base_m = np.asarray(flange2base(q), dtype=np.float64)
    if flange2base_m.shape != (m, 4, 4):
        raise ValueError(f"flange2base returned shape {flange2base_m.shape}, expected ({m}, 4, 4)")
    # (sensor2flange · seam2sensor) first: one batch product fewer when seam2sensor is shared.
    out: NDArray[np.float64] = np.matmul(flange2base_m, np.matmul(sensor2flange_m, seam2sensor_m))
    return out


def seam_positions(
    joints: ArrayLike,
    flange2base: FlangeToBase,
    sensor2flange: ArrayLike,
    seam2sensor: ArrayLike,
) -> NDArray[np.float64]:
    """Seam points in the base frame, shape (M, 3), mm: the translation of :func:`seam2base`."""
    return seam2base(joints, flange2base, sensor2flange, seam2sensor)[:, :3, 3].copy()
