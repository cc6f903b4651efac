"""Workpiece, seam and sensor motion for the camera emulator (pure, numpy only).

Frames (paper section IV): base **B** (mm), workpiece **W**, sensor tool **S**, seam **G**.

Workpiece frame W: the seam runs along x_W as the curve ``y_W = f(x_W)`` (straight: f = 0;
the paper's Fig. 10: ``f(x) = 2 sin(2π·5x/250)`` mm, i.e. amplitude 2 mm, wavelength 50 mm);
z_W points out of the material towards the sensor. Across the seam the surface height is a
piecewise-linear function of the signed lateral distance ``l`` from the seam::

    z_W = h(l),  l = (y_W - f(x_W)) / sqrt(1 + f'(x_W)^2)

``l`` is the first-order normal distance (exact for a straight seam, and exactly linear along
any line of constant x_W, which is what the laser plane cuts in the nominal pose).

Joint profiles h(l) (mm), seam point on the curve l = 0 at height ``seam_height``:

- butt: plates at h = 0 (left, l < -gap/2) and h = mismatch (right, l > gap/2); nothing in
  the gap (no stripe). Seam point: gap centre at mean plate height.
- fillet (corner): h = |l| / tan(opening/2), an inside corner opening towards the sensor.
  Seam point: the corner.
- lap: upper plate h = thickness on ``upper_side`` (-1: l < 0), lower plate h = 0 on the
  other side. Seam point: the inside corner on the lower plate at the upper plate's edge.

Walls (the vertical face of a lap step) reflect no laser light and nothing is occluded or
shadowed: the emulator is a triangulation model, not a ray tracer.

Seam frame G (truth): origin at the seam point, x_G along the seam tangent, z_G = -z_W (into
the material, like z_S in the nominal pose), y_G = z_G × x_G.

Sensor poses are provided by a callable ``sensor2base(times (N,) s) -> (N, 4, 4) mm``. A
provider whose poses interpolate a few node poses may also offer them with the per-time weights
(:class:`NodePoseProvider`): the camera's straight-seam path is linear in the pose, so it works
on the nodes and combines with the weights instead of on N poses.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol, cast

import numpy as np
from numpy.typing import ArrayLike

from kinematics.types import FloatArray

PoseProvider = Callable[[FloatArray], FloatArray]
"""``sensor2base(times (N,) seconds) -> (N, 4, 4)`` homogeneous transforms in mm."""
NodePoses = Callable[[FloatArray], "tuple[FloatArray, FloatArray] | None"]
"""``node_poses(times (N,) s) -> (nodes (M, 16), weights (M, N))`` or None, see
:class:`NodePoseProvider`."""


class NodePoseProvider(Protocol):
    """A pose provider whose poses are weighted sums of a few node poses.

    ``node_poses(times)`` returns node poses (M, 16) (4x4 row-major, mm) and weights (M, N)
    with ``pose(times[i]) = sum_j weights[j, i] * nodes[j]`` up to rounding (the poses of
    ``__call__``), or None when it cannot (then the caller asks ``__call__``)."""

    def __call__(self, times: FloatArray) -> FloatArray: ...

    def node_poses(self, times: FloatArray) -> tuple[FloatArray, FloatArray] | None: ...


def node_poses_of(provider: PoseProvider) -> NodePoses | None:
    """The ``node_poses`` hook of ``provider`` (:class:`NodePoseProvider`), None if it has
    none."""
    hook = getattr(provider, "node_poses", None)
    return cast("NodePoses", hook) if callable(hook) else None


class SceneError(ValueError):
    """A scene, joint or pose parameter is invalid."""


class JointType(StrEnum):
    """Joint geometry; the detector looks for the matching seam feature."""

    BUTT = "butt"  # feature: gap between two plates
    FILLET = "fillet"  # feature: inside corner
    LAP = "lap"  # feature: step at the upper plate's edge


@dataclass(frozen=True)
class Piece:
    """One linear piece of the profile: h = a + b·l for lo <= l < hi (mm)."""

    lo: float
    hi: float
    a: float
    b: float


@dataclass(frozen=True)
class Joint:
    """Cross-section of the joint (see module docstring); lengths in mm, angles in degrees."""

    kind: JointType
    gap_mm: float = 0.0
    mismatch_mm: float = 0.0
    opening_deg: float = 90.0
    thickness_mm: float = 1.0
    upper_side: int = -1

    def __post_init__(self) -> None:
        if not isinstance(self.kind, JointType):
            raise SceneError(f"unknown joint type {self.kind!r}")
        if self.gap_mm < 0 or self.gap_mm > 20:
            raise SceneError(f"gap must be 0..20 mm, got {self.gap_mm}")
        if abs(self.mismatch_mm) > 10:
            raise SceneError(f"mismatch must be within ±10 mm, got {self.mismatch_mm}")
        if not 20.0 <= self.opening_deg <= 170.0:
            raise SceneError(f"fillet opening must be 20..170 degrees, got {self.opening_deg}")
        if not 0.0 < self.thickness_mm <= 10.0:
            raise SceneError(f"lap thickness must be in (0, 10] mm, got {self.thickness_mm}")
        if self.upper_side not in (-1, 1):
            raise SceneError("upper_side must be -1 or +1")

    @classmethod
    def butt(cls, gap_mm: float = 0.5, mismatch_mm: float = 0.0) -> Joint:
        return cls(JointType.BUTT, gap_mm=gap_mm, mismatch_mm=mismatch_mm)

    @classmethod
    def fillet(cls, opening_deg: float = 90.0) -> Joint:
        return cls(JointType.FILLET, opening_deg=opening_deg)

    @classmethod
    def lap(cls, thickness_mm: float = 1.0, upper_side: int = -1) -> Joint:
        return cls(JointType.LAP, thickness_mm=thickness_mm, upper_side=upper_side)

    def pieces(self) -> tuple[Piece, ...]:
        """The profile h(l) as linear pieces (mm)."""
        inf = math.inf
        if self.kind is JointType.BUTT:
            g = self.gap_mm / 2.0
            return (Piece(-inf, -g, 0.0, 0.0), Piece(g, inf, self.mismatch_mm, 0.0))
        if self.kind is JointType.FILLET:
            k = 1.0 / math.tan(math.radians(self.opening_deg) / 2.0)
            return (Piece(-inf, 0.0, 0.0, -k), Piece(0.0, inf, 0.0, k))
        t = self.thickness_mm
        if self.upper_side < 0:
            return (Piece(-inf, 0.0, t, 0.0), Piece(0.0, inf, 0.0, 0.0))
        return (Piece(-inf, 0.0, 0.0, 0.0), Piece(0.0, inf, t, 0.0))

    @property
    def seam_height_mm(self) -> float:
        """Height h of the seam point above z_W = 0 (mm)."""
        return self.mismatch_mm / 2.0 if self.kind is JointType.BUTT else 0.0


@dataclass(frozen=True)
class SeamPath:
    """Seam curve y_W = amplitude·sin(2π·x_W/wavelength) in the workpiece frame (mm).

    ``amplitude_mm = 0`` is a straight seam along x_W.
    """

    amplitude_mm: float = 0.0
    wavelength_mm: float = 50.0

    def __post_init__(self) -> None:
        if self.wavelength_mm <= 0 or not math.isfinite(self.wavelength_mm):
            raise SceneError("wavelength must be a positive number of mm")
        if not math.isfinite(self.amplitude_mm):
            raise SceneError("amplitude must be finite")

    @classmethod
    def straight(cls) -> SeamPath:
        return cls(0.0)

    @classmethod
    def paper_sine(cls) -> SeamPath:
        """The paper's Fig. 10: y = 2 sin(2π·5x/250) mm (5 Hz at 250 mm/s, 2 mm amplitude)."""
        return cls(2.0, 50.0)

    @property
    def straight_line(self) -> bool:
        return self.amplitude_mm == 0.0

    def y(self, x: FloatArray) -> FloatArray:
        """f(x) (mm), any shape."""
        if self.straight_line:
            return np.zeros_like(x)
        w: FloatArray = self.amplitude_mm * np.sin((2.0 * np.pi / self.wavelength_mm) * x)
        return w

    def slope(self, x: FloatArray) -> FloatArray:
        """f'(x), any shape."""
        if self.straight_line:
            return np.zeros_like(x)
        k = 2.0 * np.pi / self.wavelength_mm
        s: FloatArray = self.amplitude_mm * k * np.cos(k * x)
        return s

    def lateral(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """Signed lateral distance l from the seam of workpiece points (x, y) (mm)."""
        if self.straight_line:
            return y
        s = self.slope(x)
        out: FloatArray = (y - self.y(x)) / np.sqrt(1.0 + s * s)
        return out

    def min_radius_mm(self) -> float:
        """Minimum radius of curvature (mm); the paper quotes ≈ 32 mm for Fig. 10."""
        if self.straight_line:
            return math.inf
        k = 2.0 * math.pi / self.wavelength_mm
        return 1.0 / (abs(self.amplitude_mm) * k * k)


@dataclass(frozen=True)
class CornerPath(SeamPath):
    """A seam with one 90° corner: y_W = x_W up to the corner at x_W = ``corner_x_mm``, then
    y_W = 2·corner - x_W (two straight legs at ±45° to x_W, so the seam stays a function of
    x_W). ``lateral`` is then the exact distance to the leg on the same side of the corner."""

    corner_x_mm: float = 30.0

    @property
    def straight_line(self) -> bool:
        return False

    def y(self, x: FloatArray) -> FloatArray:
        out: FloatArray = self.corner_x_mm - np.abs(x - self.corner_x_mm)
        return out

    def slope(self, x: FloatArray) -> FloatArray:
        out: FloatArray = np.where(x < self.corner_x_mm, 1.0, -1.0) + 0.0 * x
        return out

    def lateral(self, x: FloatArray, y: FloatArray) -> FloatArray:
        out: FloatArray = (y - self.y(x)) / math.sqrt(2.0)
        return out

    def min_radius_mm(self) -> float:
        return 0.0


@dataclass(frozen=True)
class JogPath(SeamPath):
    """A seam that leaves the straight line by a jog: straight along x_W up to
    ``start_x_mm``, an arc of ``radius_mm`` turning by ``angle_deg``, a straight leg of
    ``straight_mm`` (along x_W), an arc back and straight again, ``offset_mm`` to the side."""

    start_x_mm: float = 30.0
    radius_mm: float = 32.0
    angle_deg: float = 15.0
    straight_mm: float = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.radius_mm > 0.0 and 0.0 < self.angle_deg < 60.0 and self.straight_mm >= 0):
            raise SceneError("jog: radius > 0, 0 < angle < 60 deg, straight >= 0")

    @property
    def straight_line(self) -> bool:
        return False

    def _knots(self) -> tuple[float, float, float, float, float, float]:
        r, th = self.radius_mm, math.radians(self.angle_deg)
        x1 = self.start_x_mm + r * math.sin(th)
        y1 = r * (1.0 - math.cos(th))
        x2 = x1 + self.straight_mm
        y2 = y1 + self.straight_mm * math.tan(th)
        x3 = x2 + r * math.sin(th)
        return x1, y1, x2, y2, x3, y2 + y1

    @property
    def offset_mm(self) -> float:
        return self._knots()[5]

    def y(self, x: FloatArray) -> FloatArray:
        x = np.asarray(x, dtype=np.float64)
        r, a = self.radius_mm, self.start_x_mm
        x1, y1, x2, _y2, x3, h = self._knots()
        t = math.tan(math.radians(self.angle_deg))
        arc1 = r - np.sqrt(np.maximum(r * r - (x - a) ** 2, 0.0))
        arc2 = h - r + np.sqrt(np.maximum(r * r - (x - x3) ** 2, 0.0))
        out: FloatArray = np.select(
            [x < a, x < x1, x < x2, x < x3], [0.0 * x, arc1, y1 + (x - x1) * t, arc2], h + 0.0 * x
        )
        return out

    def slope(self, x: FloatArray) -> FloatArray:
        x = np.asarray(x, dtype=np.float64)
        r, a = self.radius_mm, self.start_x_mm
        x1, _y1, x2, _y2, x3, _h = self._knots()
        t = math.tan(math.radians(self.angle_deg))
        d1 = np.sqrt(np.maximum(r * r - (x - a) ** 2, 1e-12))
        d2 = np.sqrt(np.maximum(r * r - (x - x3) ** 2, 1e-12))
        out: FloatArray = np.select(
            [x < a, x < x1, x < x2, x < x3],
            [0.0 * x, (x - a) / d1, t + 0.0 * x, -(x - x3) / d2],
            0.0 * x,
        )
        return out

    def min_radius_mm(self) -> float:
        return self.radius_mm


def _check_transform(t: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(t, dtype=np.float64)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise SceneError(f"{name} must be a finite 4x4 transform")
    r = a[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or abs(np.linalg.det(r) - 1) > 1e-6:
        raise SceneError(f"{name} rotation is not orthonormal and right-handed")
    if not np.allclose(a[3], [0, 0, 0, 1]):
        raise SceneError(f"{name} last row must be (0, 0, 0, 1)")
    return a.copy()


def invert_transforms(t: FloatArray) -> FloatArray:
    """Inverse of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(t)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, t[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def rot_x(angle_rad: float) -> FloatArray:
    """Rotation about x (3, 3)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class Scene:
    """A workpiece with one seam, placed in the base frame by ``workpiece2base`` (4, 4)."""

    joint: Joint
    path: SeamPath = field(default_factory=SeamPath)
    workpiece2base: FloatArray = field(default_factory=lambda: np.eye(4))
    brightness: float = 1.0  # relative laser-line brightness of the surface (reflectance)

    def __post_init__(self) -> None:
        w = _check_transform(self.workpiece2base, "workpiece2base")
        w.setflags(write=False)
        object.__setattr__(self, "workpiece2base", w)
        if not 0.0 <= self.brightness <= 100.0:
            raise SceneError("brightness must be in [0, 100]")
        inv = invert_transforms(w)
        inv.setflags(write=False)
        object.__setattr__(self, "_base2workpiece", inv)

    @property
    def base2workpiece(self) -> FloatArray:
        b: FloatArray = self._base2workpiece  # type: ignore[attr-defined]
        return b

    def seam_point_w(self, x: FloatArray) -> FloatArray:
        """Seam points in W at stations x (N,) -> (N, 3) mm."""
        return np.stack([x, self.path.y(x), np.full_like(x, self.joint.seam_height_mm)], axis=-1)

    def sensor_over_seam(
        self,
        x_mm: float,
        seam_y_mm: float = 0.0,
        seam_z_mm: float = 0.0,
        roll_deg: float = 0.0,
    ) -> FloatArray:
        """A sensor2base pose (4, 4) whose laser plane cuts the seam at station x_W = x_mm.

        x_S follows the seam tangent, z_S = -z_W (looking into the material), then the sensor
        is rolled about x_S by ``roll_deg``; the seam point lands at (0, seam_y, seam_z) in S.
        """
        x = np.array([x_mm], dtype=np.float64)
        p_w = self.seam_point_w(x)[0]
        tangent = np.array([1.0, float(self.path.slope(x)[0]), 0.0])
        tangent /= np.linalg.norm(tangent)
        z_s = np.array([0.0, 0.0, -1.0])
        y_s = np.cross(z_s, tangent)
        r_w = np.stack([tangent, y_s, z_s], axis=1) @ rot_x(math.radians(roll_deg))
        origin_w = p_w - r_w @ np.array([0.0, seam_y_mm, seam_z_mm])
        s2w = np.eye(4)
        s2w[:3, :3] = r_w
        s2w[:3, 3] = origin_w
        out: FloatArray = self.workpiece2base @ s2w
        return out

    def seam2sensor(self, sensor2base: FloatArray, iterations: int = 12) -> FloatArray:
        """True seam frame in the sensor frame where the laser plane x_S = 0 cuts the seam.

        sensor2base (N, 4, 4) -> (N, 4, 4) mm. Rows whose laser plane does not cut the seam
        within 1 µm after Newton's iterations are NaN.
        """
        s2b = np.asarray(sensor2base, dtype=np.float64).reshape(-1, 4, 4)
        s2w = self.base2workpiece @ s2b
        normal = s2w[:, :3, 0]  # laser-plane normal x_S in W
        origin = s2w[:, :3, 3]
        x = origin[:, 0].copy()
        h = self.joint.seam_height_mm
        for _ in range(iterations):
            p = np.stack([x, self.path.y(x), np.full_like(x, h)], axis=-1)
            g = np.einsum("ni,ni->n", normal, p - origin)
            dp = np.stack([np.ones_like(x), self.path.slope(x), np.zeros_like(x)], axis=-1)
            dg = np.einsum("ni,ni->n", normal, dp)
            with np.errstate(divide="ignore", invalid="ignore"):
                x = x - g / dg
        p = self.seam_point_w(x)
        dp = np.stack([np.ones_like(x), self.path.slope(x), np.zeros_like(x)], axis=-1)
        x_g = dp / np.linalg.norm(dp, axis=-1, keepdims=True)
        z_g = np.broadcast_to(np.array([0.0, 0.0, -1.0]), x_g.shape)
        y_g = np.cross(z_g, x_g)
        g2w = np.zeros((len(x), 4, 4))
        g2w[:, :3, 0], g2w[:, :3, 1], g2w[:, :3, 2] = x_g, y_g, z_g
        g2w[:, :3, 3] = p
        g2w[:, 3, 3] = 1.0
        out: FloatArray = invert_transforms(s2w) @ g2w
        residual = np.abs(np.einsum("ni,ni->n", normal, p - origin))
        out[~(residual < 1e-3)] = np.nan
        return out


def fixed_pose(sensor2base: ArrayLike) -> PoseProvider:
    """A pose provider that always returns ``sensor2base`` (4, 4)."""
    t = _check_transform(sensor2base, "sensor2base")

    def provider(times: FloatArray) -> FloatArray:
        n = np.shape(times)[0]
        return np.broadcast_to(t, (n, 4, 4)).copy()

    return provider


def scripted_pose(
    start: ArrayLike,
    *,
    velocity_mm_s: ArrayLike = (0.0, 0.0, 0.0),
    sine_amplitude_mm: float = 0.0,
    sine_frequency_hz: float = 0.0,
    sine_axis: ArrayLike = (0.0, 1.0, 0.0),
    t0_s: float = 0.0,
) -> PoseProvider:
    """Constant orientation, translating from ``start`` (4, 4) at t0.

    position(t) = start + v·(t - t0) + A·sin(2π f (t - t0))·axis, where ``velocity_mm_s`` is
    in the base frame and ``sine_axis`` in the sensor frame (default y_S: perpendicular to
    the seam, as in the paper's ΔT experiment with A = 2 mm, f = 0.1..10 Hz).
    """
    t_start = _check_transform(start, "start")
    v = np.asarray(velocity_mm_s, dtype=np.float64)
    axis = np.asarray(sine_axis, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise SceneError("velocity_mm_s must be 3 finite numbers")
    if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
        raise SceneError("sine_axis must be a non-zero 3-vector")
    if sine_frequency_hz < 0 or not math.isfinite(sine_frequency_hz):
        raise SceneError("sine_frequency_hz must be >= 0")
    axis_b = t_start[:3, :3] @ (axis / np.linalg.norm(axis))
    omega = 2.0 * math.pi * sine_frequency_hz

    def provider(times: FloatArray) -> FloatArray:
        dt = np.asarray(times, dtype=np.float64) - t0_s
        out = np.broadcast_to(t_start, (dt.shape[0], 4, 4)).copy()
        out[:, :3, 3] += (
            dt[:, None] * v + (sine_amplitude_mm * np.sin(omega * dt))[:, None] * axis_b
        )
        return out

    return provider
