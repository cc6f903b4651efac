"""Homogeneous transforms, VAL3 locations, quaternions, rotation vectors, interpolation.

Conventions (see ``kinematics/CONVENTIONS.md``):

* A transform ``a2b`` is a (4, 4) float64 array that maps coordinates in frame A to frame B,
  i.e. it is the paper's ^B_A T (frame A described in frame B). Batches are (N, 4, 4).
* ``concat`` multiplies in the order given, as the paper's eq. 2 reads:
  ``concat(flange2base, sensor2flange, seam2sensor) == seam2base``.
* A VAL3 location is (x, y, z, rx, ry, rz): mm and degrees, R = Rx(rx)·Ry(ry)·Rz(rz)
  (rotations about the moving axes x, then y', then z''). ``transform_to_location`` returns
  rx, rz in (-180, 180] and ry in [-90, 90].
* Quaternions are (w, x, y, z), unit norm, returned with w >= 0. Rotation vectors are
  axis·angle in radians. Angles are radians everywhere except at the VAL3-location edge.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from kinematics.errors import KinematicsError
from kinematics.types import FloatArray

#: Default tolerance of ``check_transform`` on orthonormality and the last row.
RIGID_TOL = 1e-6


def _float_array(value: Any, name: str) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise KinematicsError(f"{name}: not an array of numbers ({exc})") from None
    return arr


def _check_finite(arr: FloatArray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        raise KinematicsError(f"{name}: contains NaN or infinity")


def check_transform(T: Any, *, tol: float = RIGID_TOL, name: str = "transform") -> FloatArray:
    """Validate a rigid transform, (4, 4) or (N, 4, 4); return it as float64.

    Raises ``KinematicsError`` on a wrong shape, NaN/inf, a last row other than (0, 0, 0, 1),
    or a rotation part that is not orthonormal with determinant +1 (to ``tol``).
    """
    arr = _float_array(T, name)
    if arr.ndim not in (2, 3) or arr.shape[-2:] != (4, 4):
        raise KinematicsError(f"{name}: expected shape (4, 4) or (N, 4, 4), got {arr.shape}")
    _check_finite(arr, name)
    if np.any(np.abs(arr[..., 3, :] - (0.0, 0.0, 0.0, 1.0)) > tol):
        raise KinematicsError(f"{name}: last row must be (0, 0, 0, 1)")
    R = arr[..., :3, :3]
    gram = np.einsum("...ji,...jk->...ik", R, R)
    if np.any(np.abs(gram - np.eye(3)) > tol) or np.any(np.linalg.det(R) < 0.0):
        raise KinematicsError(f"{name}: rotation part is not orthonormal with det +1")
    return arr


def transform_from(R: Any, p: Any) -> FloatArray:
    """Assemble (..., 4, 4) from a rotation (..., 3, 3) and a translation (..., 3) in mm."""
    Rm = _float_array(R, "rotation")
    pv = _float_array(p, "translation")
    shape = np.broadcast_shapes(Rm.shape[:-2], pv.shape[:-1])
    T = np.zeros((*shape, 4, 4))
    T[..., :3, :3] = Rm
    T[..., :3, 3] = pv
    T[..., 3, 3] = 1.0
    return T


def invert(T: Any) -> FloatArray:
    """Inverse of a rigid transform, (4, 4) or (N, 4, 4): a2b -> b2a (no general inverse)."""
    arr = check_transform(T)
    R = arr[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(arr)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, arr[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def concat(*Ts: Any) -> FloatArray:
    """Product of transforms in the order given (broadcasts over batches).

    ``concat(flange2base, sensor2flange, seam2sensor)`` is seam2base (paper eq. 2).
    """
    if not Ts:
        raise KinematicsError("concat: need at least one transform")
    out = check_transform(Ts[0], name="concat[0]")
    for i, T in enumerate(Ts[1:], start=1):
        out = out @ check_transform(T, name=f"concat[{i}]")
    return out


# --- VAL3 locations ---------------------------------------------------------------------------


def _rot_xyz(rx: FloatArray, ry: FloatArray, rz: FloatArray) -> FloatArray:
    """Rx(rx)·Ry(ry)·Rz(rz) for angles in radians of any (equal) shape -> (..., 3, 3)."""
    sa, ca = np.sin(rx), np.cos(rx)
    sb, cb = np.sin(ry), np.cos(ry)
    sc, cc = np.sin(rz), np.cos(rz)
    R = np.empty((*np.shape(rx), 3, 3))
    R[..., 0, 0] = cb * cc
    R[..., 0, 1] = -cb * sc
    R[..., 0, 2] = sb
    R[..., 1, 0] = sa * sb * cc + ca * sc
    R[..., 1, 1] = ca * cc - sa * sb * sc
    R[..., 1, 2] = -sa * cb
    R[..., 2, 0] = sa * sc - ca * sb * cc
    R[..., 2, 1] = ca * sb * sc + sa * cc
    R[..., 2, 2] = ca * cb
    return R


def _xyz_from_rot(R: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of ``_rot_xyz``: (rx, ry, rz) in radians for (..., 3, 3) rotations.

    rz is computed from the rx actually chosen, so the triple reproduces R exactly even at
    the gimbal lock (ry = ±90°), where only rx ± rz is defined (then rx comes out ~0).
    """
    rx = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
    ry = np.arctan2(R[..., 0, 2], np.hypot(R[..., 0, 0], R[..., 0, 1]))
    s1, c1 = np.sin(rx), np.cos(rx)
    rz = np.arctan2(
        c1 * R[..., 1, 0] + s1 * R[..., 2, 0],
        c1 * R[..., 1, 1] + s1 * R[..., 2, 1],
    )
    return rx, ry, rz


def _wrap_deg(a: FloatArray) -> FloatArray:
    """Angles in degrees into (-180, 180]."""
    w = np.asarray(-((180.0 - a) % 360.0) + 180.0)
    return np.where(w == -180.0, 180.0, w)


def location_to_transform(loc: Sequence[float] | FloatArray) -> FloatArray:
    """VAL3 location (6,) = (x, y, z mm, rx, ry, rz degrees) -> transform (4, 4)."""
    arr = _float_array(loc, "location")
    if arr.shape != (6,):
        raise KinematicsError(f"location: expected 6 values (x,y,z,rx,ry,rz), got {arr.shape}")
    _check_finite(arr, "location")
    x, y, z, rx, ry, rz = (float(v) for v in arr)
    a, b, c = math.radians(rx), math.radians(ry), math.radians(rz)
    sa, ca, sb, cb, sc, cc = (
        math.sin(a),
        math.cos(a),
        math.sin(b),
        math.cos(b),
        math.sin(c),
        math.cos(c),
    )
    return np.array(
        [
            [cb * cc, -cb * sc, sb, x],
            [sa * sb * cc + ca * sc, ca * cc - sa * sb * sc, -sa * cb, y],
            [sa * sc - ca * sb * cc, ca * sb * sc + sa * cc, ca * cb, z],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def transform_to_location(T: Any) -> FloatArray:
    """Transform (4, 4) -> VAL3 location (6,): mm and degrees, rx, rz in (-180, 180].

    One transform in plain float arithmetic (~5x cheaper than the batch form on one
    matrix; a sensor converts every seam transform it reports): the same checks and the
    same formulas as :func:`check_transform` and :func:`transforms_to_locations`.
    """
    arr = _float_array(T, "transform")
    if arr.shape != (4, 4):
        check_transform(arr)  # the batch form's shape error, or its ndim error below
        raise KinematicsError("transform_to_location: expected one (4, 4); use the batch form")
    rows = arr.tolist()
    (r00, r01, r02, x), (r10, r11, r12, y), (r20, r21, r22, z), last = rows
    if not all(math.isfinite(v) for row in rows for v in row):
        raise KinematicsError("transform: contains NaN or infinity")
    tol = RIGID_TOL
    if any(abs(v - w) > tol for v, w in zip(last, (0.0, 0.0, 0.0, 1.0), strict=True)):
        raise KinematicsError("transform: last row must be (0, 0, 0, 1)")
    cols = ((r00, r10, r20), (r01, r11, r21), (r02, r12, r22))
    for i in range(3):
        for k in range(i, 3):
            a, b = cols[i], cols[k]
            g = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
            if abs(g - (1.0 if i == k else 0.0)) > tol:
                raise KinematicsError("transform: rotation part is not orthonormal with det +1")
    det = (
        r00 * (r11 * r22 - r12 * r21)
        - r01 * (r10 * r22 - r12 * r20)
        + r02 * (r10 * r21 - r11 * r20)
    )
    if det < 0.0:
        raise KinematicsError("transform: rotation part is not orthonormal with det +1")
    # _xyz_from_rot and _wrap_deg on floats; the transcendental functions stay numpy's (its
    # SIMD loops and libm differ in the last bit, and the batch form uses numpy's)
    rx, ry = np.arctan2((-r12, r02), (r22, np.hypot(r00, r01))).tolist()
    s1, c1 = float(np.sin(rx)), float(np.cos(rx))
    rz = float(np.arctan2(c1 * r10 + s1 * r20, c1 * r11 + s1 * r21))
    return np.array(
        [x, y, z, _wrap_deg_float(math.degrees(rx)), math.degrees(ry),
         _wrap_deg_float(math.degrees(rz))]
    )  # fmt: skip


def _wrap_deg_float(a: float) -> float:
    """:func:`_wrap_deg` of one angle (deg): the same floating-point steps."""
    w = -((180.0 - a) % 360.0) + 180.0
    return 180.0 if w == -180.0 else w


def locations_to_transforms(locs: Any) -> FloatArray:
    """Batch of VAL3 locations (N, 6) -> transforms (N, 4, 4)."""
    arr = _float_array(locs, "locations")
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise KinematicsError(f"locations: expected shape (N, 6), got {arr.shape}")
    _check_finite(arr, "locations")
    ang = np.radians(arr[:, 3:])
    return transform_from(_rot_xyz(ang[:, 0], ang[:, 1], ang[:, 2]), arr[:, :3])


def transforms_to_locations(Ts: Any) -> FloatArray:
    """Batch of transforms (N, 4, 4) -> VAL3 locations (N, 6)."""
    arr = check_transform(Ts)
    if arr.ndim != 3:
        raise KinematicsError(f"transforms: expected shape (N, 4, 4), got {arr.shape}")
    rx, ry, rz = _xyz_from_rot(arr[:, :3, :3])
    out = np.empty((arr.shape[0], 6))
    out[:, :3] = arr[:, :3, 3]
    out[:, 3] = _wrap_deg(np.degrees(rx))
    out[:, 4] = np.degrees(ry)
    out[:, 5] = _wrap_deg(np.degrees(rz))
    return out


# --- quaternions and rotation vectors ------------------------------------------------------


def _check_rotation(R: Any, name: str = "rotation") -> FloatArray:
    arr = _float_array(R, name)
    if arr.ndim < 2 or arr.shape[-2:] != (3, 3):
        raise KinematicsError(f"{name}: expected shape (..., 3, 3), got {arr.shape}")
    _check_finite(arr, name)
    return arr


def quaternion_from_matrix(R: Any) -> FloatArray:
    """Rotation (..., 3, 3) -> unit quaternion (..., 4) as (w, x, y, z) with w >= 0."""
    M = _check_rotation(R)
    tr = M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2]
    # Shepperd: build the quaternion from the largest of w, x, y, z to avoid cancellation.
    cand = np.stack(
        [
            np.stack([1 + tr, M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0],
                      M[..., 1, 0] - M[..., 0, 1]], axis=-1),
            np.stack([M[..., 2, 1] - M[..., 1, 2], 1 + 2 * M[..., 0, 0] - tr,
                      M[..., 0, 1] + M[..., 1, 0], M[..., 0, 2] + M[..., 2, 0]], axis=-1),
            np.stack([M[..., 0, 2] - M[..., 2, 0], M[..., 0, 1] + M[..., 1, 0],
                      1 + 2 * M[..., 1, 1] - tr, M[..., 1, 2] + M[..., 2, 1]], axis=-1),
            np.stack([M[..., 1, 0] - M[..., 0, 1], M[..., 0, 2] + M[..., 2, 0],
                      M[..., 1, 2] + M[..., 2, 1], 1 + 2 * M[..., 2, 2] - tr], axis=-1),
        ],
        axis=-2,
    )  # fmt: skip
    choice = np.argmax(np.stack([tr, M[..., 0, 0], M[..., 1, 1], M[..., 2, 2]], axis=-1), axis=-1)
    q = np.take_along_axis(cand, choice[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    out: FloatArray = np.where(q[..., :1] < 0.0, -q, q)
    return out


def matrix_from_quaternion(q: Any) -> FloatArray:
    """Quaternion (..., 4) as (w, x, y, z) -> rotation (..., 3, 3); q is normalised first."""
    arr = _float_array(q, "quaternion")
    if arr.ndim < 1 or arr.shape[-1] != 4:
        raise KinematicsError(f"quaternion: expected shape (..., 4), got {arr.shape}")
    _check_finite(arr, "quaternion")
    n = np.linalg.norm(arr, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise KinematicsError("quaternion: zero norm")
    w, x, y, z = np.moveaxis(arr / n, -1, 0)
    R = np.empty((*arr.shape[:-1], 3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotvec_from_matrix(R: Any) -> FloatArray:
    """Rotation (..., 3, 3) -> rotation vector (..., 3): unit axis times angle in [0, π] rad."""
    q = quaternion_from_matrix(R)
    w = q[..., 0]
    v = q[..., 1:]
    n = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(n, w)
    # Near identity angle/n -> 2/w; the series keeps full precision for tiny rotations.
    safe_n = np.where(n > 1e-12, n, 1.0)
    scale = np.where(n > 1e-12, angle / safe_n, 2.0 / w)
    return v * scale[..., None]


def matrix_from_rotvec(v: Any) -> FloatArray:
    """Rotation vector (..., 3) in radians -> rotation (..., 3, 3) (Rodrigues)."""
    arr = _float_array(v, "rotation vector")
    if arr.ndim < 1 or arr.shape[-1] != 3:
        raise KinematicsError(f"rotation vector: expected shape (..., 3), got {arr.shape}")
    _check_finite(arr, "rotation vector")
    theta = np.linalg.norm(arr, axis=-1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    # Taylor series below 1e-6 rad: sin(t)/t and (1-cos t)/t^2 lose digits there.
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    x, y, z = np.moveaxis(arr, -1, 0)
    K = np.zeros((*arr.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2] = -z, y
    K[..., 1, 0], K[..., 1, 2] = z, -x
    K[..., 2, 0], K[..., 2, 1] = -y, x
    out: FloatArray = np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)
    return out


def slerp(q0: Any, q1: Any, s: Any) -> FloatArray:
    """Spherical interpolation of unit quaternions (4,) along the shorter arc; s scalar or (N,)."""
    R0 = matrix_from_quaternion(q0)
    R1 = matrix_from_quaternion(q1)
    return quaternion_from_matrix(_rot_interp(R0, R1, _float_array(s, "s")))


def _rot_interp(R0: FloatArray, R1: FloatArray, s: FloatArray) -> FloatArray:
    rel = rotvec_from_matrix(np.swapaxes(R0, -1, -2) @ R1)
    return R0 @ matrix_from_rotvec(np.multiply.outer(s, rel))


def interpolate(T0: Any, T1: Any, s: Any) -> FloatArray:
    """Pose between T0 (s=0) and T1 (s=1): linear position, slerp orientation.

    T0, T1: (4, 4). s: scalar -> (4, 4), or (N,) -> (N, 4, 4). s outside [0, 1] extrapolates.
    """
    A = check_transform(T0, name="T0")
    B = check_transform(T1, name="T1")
    if A.ndim != 2 or B.ndim != 2:
        raise KinematicsError("interpolate: T0 and T1 must be single (4, 4) transforms")
    sv = _float_array(s, "s")
    if sv.ndim > 1:
        raise KinematicsError(f"interpolate: s must be a scalar or (N,), got {sv.shape}")
    _check_finite(sv, "s")
    R = _rot_interp(A[:3, :3], B[:3, :3], sv)
    p = A[:3, 3] + np.multiply.outer(sv, B[:3, 3] - A[:3, 3])
    return transform_from(R, p)
