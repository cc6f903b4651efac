"""Triangulation geometry of the seam-tracking camera: the sensor's calibration (pure).

Sensor frame S (mm): origin at the centre of the measuring range, where the camera's optical
axis crosses the laser plane; x_S in the welding direction (along the seam); z_S along the
laser, from the sensor towards the workpiece; y_S = z_S × x_S across the seam. The laser
plane is x_S = 0, so the stripe runs across the seam.

Default geometry (``CameraGeometry()``), chosen like compact laser-welding seam trackers:

- laser: plane x_S = 0, source 60 mm above the origin (at z_S = -60);
- camera: pinhole trailing the laser, centre at (-D sin θ, 0, -D cos θ) with working distance
  D = 64 mm and triangulation angle θ = 45° between the optical axis and the laser, so the
  baseline (laser-to-camera distance across the laser direction) is D sin θ ≈ 45.3 mm;
- lens f = 16 mm, pixel pitch 10 µm, 512 columns × 256 rows, principal point at the centre;
- hence ≈ 40 µm per column across the seam (field of view ≈ 20.5 mm wide at z_S = 0) and
  ≈ 57 µm per row in depth near the origin (z_S from ≈ -6.7 mm at row 0 to ≈ +7.8 mm at
  row 255; ≈ 14.5 mm deep). Ideal pinhole: no lens distortion, so the calibration the
  detector uses is exact.

Image coordinates: column u grows with y_S, row v grows with z_S (farther away).

This module is the one home of the calibration: the renderer (where a column's line meets
the scene, which row a hit lands on), the detector (stripe rows to profile points, where a
fitted profile line crosses a column, the seam's column) and the emulated cell (the seam's
column, hence its time in the readout) all call these methods. The laser-plane formulas run on plain
floats (a few points: no numpy call overhead) or on arrays, written once for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, TypeVar, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinematics.types import FloatArray

# float or array: each formula is written once and runs on either
_N = TypeVar("_N", float, FloatArray)
# "all nonzero" as a count: ndarray.all() goes through a Python wrapper, and a count costs
# half a logical reduction
_COUNT = np.count_nonzero


class CameraError(ValueError):
    """Invalid camera geometry, render setting or readout window."""


@dataclass(frozen=True)
class CameraGeometry:
    """Pinhole camera over a laser plane; lengths in mm, angles in degrees."""

    columns: int = 512
    rows: int = 256
    pixel_pitch_mm: float = 0.010
    focal_length_mm: float = 16.0
    triangulation_angle_deg: float = 45.0
    working_distance_mm: float = 64.0
    laser_standoff_mm: float = 60.0

    def __post_init__(self) -> None:
        if not (8 <= self.columns <= 8192 and 8 <= self.rows <= 8192):
            raise CameraError("columns and rows must be 8..8192")
        if not 5.0 <= self.triangulation_angle_deg <= 85.0:
            raise CameraError("triangulation angle must be 5..85 degrees")
        for name in ("pixel_pitch_mm", "focal_length_mm", "working_distance_mm"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise CameraError(f"{name} must be positive")
        th = math.radians(self.triangulation_angle_deg)
        # the constants every formula takes, computed once (a detector calls some of them
        # a dozen times a frame on plain floats)
        object.__setattr__(self, "_sin", math.sin(th))
        object.__setattr__(self, "_cos", math.cos(th))
        object.__setattr__(self, "_f", self.focal_length_mm / self.pixel_pitch_mm)
        object.__setattr__(self, "_u0", (self.columns - 1) / 2.0)
        object.__setattr__(self, "_v0", (self.rows - 1) / 2.0)
        # plane_point in closed form: the row v1 of rays parallel to the laser plane, and
        # z = K/(v1 - v) - D/c, y = (u - u0)·(c/f)·K/(v1 - v) with K = D·f·s/c²
        c, f, d = self._cos, self._f, self.working_distance_mm
        object.__setattr__(self, "_v1", self._v0 + f * self._sin / c)
        object.__setattr__(self, "_plane_k", d * self._sin / c)  # K·c/f
        object.__setattr__(self, "_f_over_c", f / c)
        object.__setattr__(self, "_d_over_c", d / c)

    _sin: float = field(init=False, repr=False, compare=False, default=0.0)
    _cos: float = field(init=False, repr=False, compare=False, default=0.0)
    _f: float = field(init=False, repr=False, compare=False, default=0.0)
    _u0: float = field(init=False, repr=False, compare=False, default=0.0)
    _v0: float = field(init=False, repr=False, compare=False, default=0.0)
    _v1: float = field(init=False, repr=False, compare=False, default=0.0)
    _plane_k: float = field(init=False, repr=False, compare=False, default=0.0)
    _f_over_c: float = field(init=False, repr=False, compare=False, default=0.0)
    _d_over_c: float = field(init=False, repr=False, compare=False, default=0.0)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return self._f

    @property
    def principal_point(self) -> tuple[float, float]:
        """(u0, v0) in pixels: the chip centre."""
        return self._u0, self._v0

    @property
    def baseline_mm(self) -> float:
        """Distance from the laser line to the camera centre across the laser direction (mm)."""
        return self.working_distance_mm * self._sin

    @property
    def center(self) -> FloatArray:
        """Camera centre in S (3,) mm."""
        d = self.working_distance_mm
        return np.array([-d * self._sin, 0.0, -d * self._cos])

    @property
    def axes(self) -> FloatArray:
        """Camera axes in S as rows (3, 3): x_c (along columns), y_c (along rows), z_c."""
        s, c = self._sin, self._cos
        return np.array([[0.0, 1.0, 0.0], [-c, 0.0, s], [s, 0.0, c]])

    @overload
    def plane_point(self, u: float, v: float) -> tuple[float, float]: ...
    @overload
    def plane_point(self, u: NDArray[Any], v: FloatArray) -> tuple[FloatArray, FloatArray]: ...
    def plane_point(self, u: Any, v: Any) -> tuple[Any, Any]:
        """(y, z) in S (mm) of the laser-plane point seen at pixel (u, v) (floats or arrays
        of one shape); NaN where the ray runs parallel to the plane.

        With k = (u - u0)/f and t = (v - v0)/f (f in pixels), the ray meets x_S = 0 at
        z = t·D / (sin θ - t·cos θ) and y = k·(D + z·cos θ); in closed form, with the
        row v1 = v0 + f·tan θ of the rays parallel to the plane and r = (D·tan θ)/(v1 - v):
        z = r·f/cos θ - D/cos θ and y = (u - u0)·r. One division; the profile of every
        frame goes through here.
        """
        r = _over(self._plane_k, self._v1 - v)
        y = u - self._u0
        y *= r
        z = r * self._f_over_c
        z -= self._d_over_c
        return y, z

    def pixel_to_sensor(self, u: ArrayLike, v: ArrayLike) -> FloatArray:
        """Points on the laser plane seen at pixel (u, v) (any shape) -> (..., 3) mm in S."""
        y, z = self.plane_point(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
        return np.stack([np.zeros_like(z), y, z], axis=-1)

    def project(self, points: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Pixel coordinates (u, v) of points (..., 3) in S.

        Camera coordinates of (x, y, z): X = y, Y = z·sin θ - x·cos θ,
        Z = D + x·sin θ + z·cos θ.
        """
        p = np.asarray(points, dtype=np.float64)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        s, c = self._sin, self._cos
        zc = self.working_distance_mm + x * s + z * c
        u0, v0 = self.principal_point
        f = self.focal_px
        return u0 + f * y / zc, v0 + f * (z * s - x * c) / zc

    def plane_column(self, y: _N, z: _N) -> _N:
        """Chip column (fractional) of the laser-plane point (0, y, z) mm in S (floats or
        arrays): :meth:`project`'s u with x = 0, so the same value to the last bit. The
        detector reports the seam's column with it and the cell its readout time; NaN where
        the point lies at the camera centre's depth."""
        return self._u0 + _over(self._f * y, self.working_distance_mm + z * self._cos)

    def camera_yz(self, points: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Camera-frame Y (along the rows) and Z (depth) of points (..., 3) in S, for
        :meth:`row_of`."""
        d = np.asarray(points, dtype=np.float64) - self.center
        ax = self.axes
        y: FloatArray = d @ ax[1]
        z: FloatArray = d @ ax[2]
        return y, z

    def row_of(self, cam_y: FloatArray, cam_z: FloatArray) -> FloatArray:
        """Image row of points with camera-frame coordinates Y = ``cam_y``, Z = ``cam_z``
        (broadcastable arrays): v0 + (Y / Z)·f, in place in a new array."""
        r: FloatArray = np.divide(cam_y, cam_z)
        r *= self.focal_px
        r += self.principal_point[1]
        return r

    def column_lines(self, u: ArrayLike, margin_px: float = 8.0) -> tuple[FloatArray, FloatArray]:
        """End points (..., 3) in S of the laser-plane line seen by column u.

        A at row -margin and B at row rows-1+margin; the line is affine in u. The margin
        lets a stripe centred just off the chip still light the edge rows with its tail.
        """
        u = np.asarray(u, dtype=np.float64)
        a = self.pixel_to_sensor(u, np.full_like(u, -margin_px))
        b = self.pixel_to_sensor(u, np.full_like(u, self.rows - 1 + margin_px))
        return a, b

    def line_point(self, u: _N, a: _N, b: _N) -> tuple[_N, _N]:
        """(y, z) in S (mm) where column u meets the profile line z = a + b·y of the laser
        plane (floats or arrays); NaN where the column's ray runs parallel to the line."""
        c, d = self._cos, self.working_distance_mm
        k = (u - self._u0) / self._f
        y = _over(k * (d + a * c), 1.0 - k * b * c)
        return y, a + b * y

    def line_row(self, u: _N, a: _N, b: _N) -> _N:
        """Image row where column u sees the profile line z = a + b·y (floats or arrays):
        the row of :meth:`line_point`; NaN where there is none."""
        s, c, d = self._sin, self._cos, self.working_distance_mm
        z = self.line_point(u, a, b)[1]
        return self._v0 + _over(self._f * z * s, d + z * c)

    def field_of_view(self) -> dict[str, float]:
        """Width at z_S = 0 and depth range along the laser (mm)."""
        u0, v0 = self.principal_point
        left = self.pixel_to_sensor(np.array(-0.5), np.array(v0))
        right = self.pixel_to_sensor(np.array(self.columns - 0.5), np.array(v0))
        top = self.pixel_to_sensor(np.array(u0), np.array(-0.5))
        bottom = self.pixel_to_sensor(np.array(u0), np.array(self.rows - 0.5))
        return {
            "width_mm": float(right[1] - left[1]),
            "z_min_mm": float(top[2]),
            "z_max_mm": float(bottom[2]),
            "depth_mm": float(bottom[2] - top[2]),
        }


def _over(num: float | _N, den: _N) -> _N:
    """num / den, NaN where den is 0 (a ray parallel to what it should meet): plain floats
    (the detector's few points: no numpy call overhead) without ZeroDivisionError, arrays
    without a warning."""
    if isinstance(den, float):
        return num / den if den != 0.0 else math.nan
    if _COUNT(den) == den.size:  # the usual case: a plain division, no warning possible
        return num / den
    out: FloatArray = np.full(np.broadcast_shapes(np.shape(num), np.shape(den)), math.nan)
    np.divide(num, den, out=out, where=den != 0.0)
    return out
