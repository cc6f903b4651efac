"""The geometric Jacobian of the Stäubli arms and Yoshikawa's manipulability."""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np

from kinematics.arm import vector6
from kinematics.dgm import DgmMixin
from kinematics.errors import KinematicsError
from kinematics.transforms import check_transform
from kinematics.types import FloatArray


class JacobianMixin(DgmMixin):
    """Jacobian (6, 6) of the tool centre point, in the base or the tool frame."""

    def joint_axes(self, q_deg: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(axes (6, 3) unit vectors, points (6, 3) mm on each axis, ^B_N T (4, 4)) at
        joints (6,) deg, base frame: the joint axes the Jacobian and the arm's dynamics
        (:mod:`kinematics.dynamics`, link inertias about each axis) are built on. Points 4-6
        are the wrist centre."""
        q = vector6(q_deg)
        F = self.flange2base(q)
        t = [math.radians(v + o) for v, o in zip(q, self.joint_offsets_deg, strict=True)]
        s1, c1 = math.sin(t[0]), math.cos(t[0])
        s2, c2 = math.sin(t[1]), math.cos(t[1])
        s23, c23 = math.sin(t[1] + t[2]), math.cos(t[1] + t[2])
        s4, c4 = math.sin(t[3]), math.cos(t[3])
        a1, d = self.shoulder_offset_mm, self.lateral_offset_mm
        a2, d4 = self.upper_arm_mm, self.forearm_mm

        def rz1(x: float, y: float, z: float) -> list[float]:
            return [c1 * x - s1 * y, s1 * x + c1 * y, z]

        y1 = [-s1, c1, 0.0]
        z4 = rz1(s23, 0.0, c23)
        # Axis 5 = Rz(θ1)·Ry(θ23)·Rz(θ4)·ŷ.
        z5 = rz1(-c23 * s4, c4, s23 * s4)
        wc = rz1(a1 + a2 * s2 + d4 * s23, d, a2 * c2 + d4 * c23)
        axes = np.array([[0.0, 0.0, 1.0], y1, y1, z4, z5, F[:3, 2]])
        points = np.array(
            [[0.0, 0.0, 0.0], rz1(a1, 0.0, 0.0), rz1(a1 + a2 * s2, d, a2 * c2), wc, wc, wc]
        )
        return axes, points, F

    def jacobian(
        self, q_deg: Any, frame: Literal["base", "tool"] = "base", tool: Any = None
    ) -> FloatArray:
        """Geometric Jacobian (6, 6) at joints (6,) deg: rows (vx, vy, vz) mm/rad and
        (wx, wy, wz) rad/rad, columns per joint (per radian).

        The velocity is that of the tool centre point (flange centre without ``tool``, a
        tool2flange (4, 4) otherwise), expressed in the base frame or in the tool frame.
        """
        if frame not in ("base", "tool"):
            raise KinematicsError(f"jacobian: frame must be 'base' or 'tool', got {frame!r}")
        axes, points, F = self.joint_axes(q_deg)
        T = F if tool is None else F @ check_transform(tool, name="tool")
        J = np.empty((6, 6))
        J[:3] = np.cross(axes, T[:3, 3] - points).T
        J[3:] = axes.T
        if frame == "tool":
            Rt = T[:3, :3].T
            J[:3] = Rt @ J[:3]
            J[3:] = Rt @ J[3:]
        return J

    def manipulability(self, q_deg: Any) -> float:
        """Yoshikawa's measure sqrt(det(J·Jᵀ)) = |det J| of the flange Jacobian, in mm².

        Zero at a singularity; for this geometry it equals a2·d4·|sin θ3|·|r|·|sin θ5|, with
        r the wrist centre's distance ahead of axis 1 (mm), so it is frame-independent.
        """
        return float(abs(np.linalg.det(self.jacobian(q_deg))))
