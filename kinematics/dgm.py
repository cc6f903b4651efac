"""The DGM (paper eq. 3): VAL3 joints -> flange2base, one closed form for every form.

Geometry of every model (data in ``kinematics/models/*.json``), VAL3 joints all zero, arm
straight up; see ``kinematics/CONVENTIONS.md`` for the directions a pendant shows:

    flange2base = Rz(θ1)·Tx(a1)·Ty(d)·Ry(θ2)·Tz(a2)·Ry(θ3)·Tz(d4)·Rz(θ4)·Ry(θ5)·Rz(θ6)·Tz(d6)

with θi = qi + joint_offset_i (VAL3 joints q in degrees, encoder offsets as data), a1 the
shoulder offset (axis 1 to axis 2, along the arm's forward x), d the lateral offset (along
axis 2; the forearm plane sits d to the arm's left, +y at J1 = 0), a2 the upper arm (axis 2
to axis 3), d4 the forearm (axis 3 to the wrist centre) and d6 the wrist centre to the flange
face. Axes 2, 3 and 5 turn about +y, axes 1, 4 and 6 about +z of the moving frame, so a
positive J2, J3 or J5 tips the next link toward +x ("forward").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from kinematics.arm import ArmGeometry, batch6, vector6
from kinematics.types import FloatArray

#: Up to this many configurations flange2base_batch runs its arithmetic on Python floats.
_SMALL_BATCH = 12


def _flange_rows(s: Any, c: Any, lengths: tuple[float, ...]) -> tuple[tuple[Any, ...], ...]:
    """The 3 upper rows (4 entries each) of flange2base, from the sines and cosines of
    (θ1, ..., θ6, θ2 + θ3): ``s`` and ``c`` hold 7 floats (one configuration) or 7 arrays (a
    batch); the same operations in the same order either way, so both forms are bit-equal.
    ``lengths``: shoulder offset, lateral offset, upper arm, forearm, wrist to flange (mm)."""
    off, lat, l2, l3, d6 = lengths
    s1, s2, _, s4, s5, s6, s23 = s
    c1, c2, _, c4, c5, c6, c23 = c
    c5c6 = c5 * c6
    c5s6 = c5 * s6
    a00 = c4 * c5c6 - s4 * s6
    a01 = -c4 * c5s6 - s4 * c6
    a02 = c4 * s5
    a10 = s4 * c5c6 + c4 * s6
    a11 = c4 * c6 - s4 * c5s6
    a12 = s4 * s5
    a20 = -s5 * c6
    a21 = s5 * s6
    b00 = c23 * a00 + s23 * a20
    b01 = c23 * a01 + s23 * a21
    b02 = c23 * a02 + s23 * c5
    b22 = c23 * c5 - s23 * a02
    px = off + l2 * s2 + l3 * s23 + d6 * b02
    py = lat + d6 * a12
    return (
        (c1 * b00 - s1 * a10, c1 * b01 - s1 * a11, c1 * b02 - s1 * a12, c1 * px - s1 * py),
        (s1 * b00 + c1 * a10, s1 * b01 + c1 * a11, s1 * b02 + c1 * a12, s1 * px + c1 * py),
        (c23 * a20 - s23 * a00, c23 * a21 - s23 * a01, b22, l2 * c2 + l3 * c23 + d6 * b22),
    )


class DgmMixin(ArmGeometry):
    """flange2base of one configuration or of a batch."""

    def flange2base(self, q_deg: Any) -> FloatArray:
        """DGM (paper eq. 3): VAL3 joints (6,) deg -> flange2base (4, 4), or (N, 6) -> (N, 4, 4).

        Joint limits are not checked here (see ``check_joints``).
        """
        if isinstance(q_deg, np.ndarray) and q_deg.ndim == 2:
            return self.flange2base_batch(q_deg)
        q1, q2, q3, q4, q5, q6 = vector6(q_deg)
        o = self.joint_offsets_deg
        r = math.pi / 180.0
        t1, t2, t3 = (q1 + o[0]) * r, (q2 + o[1]) * r, (q3 + o[2]) * r
        t4, t5, t6 = (q4 + o[3]) * r, (q5 + o[4]) * r, (q6 + o[5]) * r
        # θ2 + θ3 summed in radians (the batch sums degrees): the single and the batch form
        # may differ in the last bit of θ23, as they always have.
        t23 = t2 + t3
        sin, cos = math.sin, math.cos
        row0, row1, row2 = _flange_rows(
            (sin(t1), sin(t2), 0.0, sin(t4), sin(t5), sin(t6), sin(t23)),
            (cos(t1), cos(t2), 0.0, cos(t4), cos(t5), cos(t6), cos(t23)),
            self._lengths,
        )
        return np.array((row0, row1, row2, (0.0, 0.0, 0.0, 1.0)))

    def flange2base_batch(self, q_deg: Any) -> FloatArray:
        """Vectorised DGM: VAL3 joints (N, 6) deg -> flange2base (N, 4, 4)."""
        q = batch6(q_deg)
        n = q.shape[0]
        ang = np.empty((7, n))
        np.add(q.T, self._offsets[:, None], out=ang[:6])
        ang[6] = ang[1] + ang[2]
        np.multiply(ang, math.pi / 180.0, out=ang)
        s = np.sin(ang)
        c = np.cos(ang)
        lengths = self._lengths
        out = np.empty((n, 4, 4))
        out[:, 3, :3] = 0.0
        out[:, 3, 3] = 1.0
        if n <= _SMALL_BATCH:
            # Python floats: below ~10 configurations the ~40 numpy calls of the array form
            # cost more than the arithmetic (same operations, same order: bit-equal).
            rows = [
                _flange_rows(sc, cc, lengths)
                for sc, cc in zip(s.T.tolist(), c.T.tolist(), strict=True)
            ]
            out[:, :3, :] = np.array(rows, dtype=np.float64).reshape(n, 3, 4)
        else:
            for i, row in enumerate(_flange_rows(s, c, lengths)):
                for j, value in enumerate(row):
                    out[:, i, j] = value
        return out
