"""Analytic IK of the Stäubli arms: axes 4, 5, 6 meet in the wrist centre, so the IK is
closed-form with up to 8 solutions (the configurations of :data:`kinematics.config.CONFIGS`),
for one pose or vectorised over N poses."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np

from kinematics.arm import LIMIT_SLACK_DEG, BoolArray, batch6, vector6
from kinematics.config import (
    CONFIGS,
    SINGULAR_TOL,
    SINGULARITY_NAMES,
    Config,
    ConfigMixin,
    ConfigRequest,
)
from kinematics.errors import JointLimitError, KinematicsError, SingularityError, UnreachableError
from kinematics.transforms import RIGID_TOL, check_transform
from kinematics.types import FloatArray

#: Below this, the closed form degenerates and the free joint takes the preferred value.
_DEGENERATE = 1e-12


class IkSolution(NamedTuple):
    """One IK solution: VAL3 joints (6,) in degrees (read-only), its configuration, any
    singularities. A named tuple: up to eight are built per ik() call, and a frozen
    dataclass costs three times as much to build."""

    joints_deg: FloatArray
    config: Config
    singularities: tuple[str, ...] = ()

    # compared and hashed by identity, as before (a tuple's == would compare the arrays)
    def __eq__(self, other: object) -> bool:
        return self is other

    def __ne__(self, other: object) -> bool:
        return self is not other

    def __hash__(self) -> int:
        return id(self)

    def as_dict(self) -> dict[str, Any]:
        return {
            "joints": [float(v) for v in self.joints_deg],
            "config": self.config.as_dict(),
            "singularities": list(self.singularities),
        }


@dataclass(frozen=True, eq=False)
class IkBatch:
    """Batch IK result for N poses; the solution axis follows ``CONFIGS`` (8 entries).

    joints_deg: (N, 8, 6) degrees, NaN where ``valid`` is False. valid: (N, 8) reachable and
    inside the joint limits. reachable: (N, 8) geometrically reachable (limits ignored).
    singular: (N, 8, 3) flags for (wrist, elbow, shoulder).
    """

    joints_deg: FloatArray
    valid: BoolArray
    reachable: BoolArray
    singular: BoolArray


class _Ops(NamedTuple):
    """What the closed form calls, for Python floats (``_MATH``, one pose, a loop over the
    branches) or numpy arrays (``_NUMPY``, N poses, the branches broadcast on leading axes):
    the formula is written once, over either."""

    sqrt: Callable[[Any], Any]
    atan2: Callable[[Any, Any], Any]
    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    hypot: Callable[[Any, Any], Any]
    maximum: Callable[[Any, Any], Any]
    minimum: Callable[[Any, Any], Any]
    where: Callable[[Any, Any, Any], Any]
    any: Callable[[Any], Any]


def _where_one(cond: bool, a: float, b: float) -> float:
    return a if cond else b


_MATH = _Ops(math.sqrt, math.atan2, math.sin, math.cos, math.hypot, max, min, _where_one, bool)
_NUMPY = _Ops(
    np.sqrt, np.arctan2, np.sin, np.cos, np.hypot, np.maximum, np.minimum, np.where, np.any
)

#: Branch signs (+ first, as in ``CONFIGS``) for the batch: shoulder, elbow and wrist on the
#: leading axes -2, -3, -4 in front of the pose axis.
_SIGNS = (
    np.array([1.0, -1.0]).reshape(2, 1),
    np.array([1.0, -1.0]).reshape(2, 1, 1),
    np.array([1.0, -1.0]).reshape(2, 1, 1, 1),
)


class _Geometry(NamedTuple):
    """The model's constants of the closed form (mm)."""

    a1: float  # shoulder offset
    d: float  # lateral offset
    a2: float  # upper arm
    d4: float  # forearm
    d6: float  # wrist centre to flange
    len_tol: float  # below this a length is zero
    shoulder_tol: float  # |r| below this: shoulder singularity


# The closed form in five steps, each for one branch sign: T is the flange2base indexed
# T[row][col] (rows of floats, or a (4, 4, N) view); xp the operations. Each step returns
# what the caller reads first, then what the next step needs.


def _wrist_centre(g: _Geometry, T: Any, xp: _Ops) -> tuple[Any, Any, Any, Any, Any]:
    """(root, φ, wz, reachable by the shoulder, |w_xy|²): the wrist centre w has
    |w_xy|² = root² + d², azimuth φ, height wz above axis 2."""
    r0, r1, r2 = T[0], T[1], T[2]
    _, d, _, _, d6, tol, _ = g
    wx, wy, wz = r0[3] - d6 * r0[2], r1[3] - d6 * r1[2], r2[3] - d6 * r2[2]
    rho2 = wx * wx + wy * wy
    disc = rho2 - d * d
    reach = disc >= -2.0 * tol * max(abs(d), 1.0)
    return xp.sqrt(xp.maximum(disc, 0.0)), xp.atan2(wy, wx), wz, reach, rho2


def _shoulder(
    g: _Geometry, centre: tuple[Any, ...], sign: Any, pref1: Any, xp: _Ops
) -> tuple[Any, Any, Any, tuple[Any, ...]]:
    """Shoulder branch ``sign`` (+1 righty, -1 lefty) -> (θ1, reachable, shoulder singular,
    carry). ``pref1``: θ1 (radians) where the wrist centre is on axis 1, or None to keep the
    formula's value there."""
    root, phi, wz, reach_sh, rho2 = centre
    a1, d, a2, d4, _, tol, shoulder_tol = g
    r = sign * root
    t1 = phi - xp.atan2(d, r)
    if pref1 is not None:
        # Wrist centre on axis 1 (no lateral offset): θ1 is free, keep the current one.
        t1 = xp.where(rho2 < tol * tol, pref1, t1)
    x = r - a1
    c3 = (x * x + wz * wz - a2 * a2 - d4 * d4) / (2.0 * a2 * d4)
    reach = reach_sh & (abs(c3) <= 1.0 + 1e-12)
    return t1, reach, abs(r) < shoulder_tol, (t1, x, wz, c3)


def _arm_plane(T: Any, shoulder: tuple[Any, ...], xp: _Ops) -> tuple[Any, tuple[Any, ...]]:
    """A shoulder's carry -> (|sin θ3|, carry): the elbow angle's cosine and the flange
    orientation A = Rz(θ1)ᵀ·R in the arm's plane, shared by both elbows."""
    t1, x, wz, c3 = shoulder
    c3 = xp.maximum(xp.minimum(c3, 1.0), -1.0)
    s3abs = xp.sqrt(1.0 - c3 * c3)
    s1, c1 = xp.sin(t1), xp.cos(t1)
    r0, r1 = T[0], T[1]
    # A: rows 0 and 1 (row 2 is R's)
    a00, a01, a02 = c1 * r0[0] + s1 * r1[0], c1 * r0[1] + s1 * r1[1], c1 * r0[2] + s1 * r1[2]
    a10, a12 = -s1 * r0[0] + c1 * r1[0], -s1 * r0[2] + c1 * r1[2]
    return s3abs, (c3, s3abs, xp.atan2(x, wz), a00, a01, a02, a10, a12)


def _elbow(
    g: _Geometry, T: Any, arm: tuple[Any, ...], sign: Any, xp: _Ops
) -> tuple[Any, Any, Any, tuple[Any, ...]]:
    """Elbow branch ``sign`` (+1 epositive) of an arm plane's carry -> (θ2 in [-π, π), θ3,
    |sin θ5|, carry)."""
    c3, s3abs, psi, a00, a01, a02, a10, a12 = arm
    _, _, a2, d4, _, _, _ = g
    s3 = sign * s3abs
    t3 = xp.atan2(s3, c3)
    t2 = psi - xp.atan2(d4 * s3, a2 + d4 * c3)
    t23 = t2 + t3
    s23, c23 = xp.sin(t23), xp.cos(t23)
    r2 = T[2]
    # Wrist: M = (Rz(θ1)·Ry(θ23))ᵀ·R = Rz(θ4)·Ry(θ5)·Rz(θ6); row 1 of M is row 1 of A.
    m00, m02 = c23 * a00 - s23 * r2[0], c23 * a02 - s23 * r2[2]
    m20, m21, m22 = s23 * a00 + c23 * r2[0], s23 * a01 + c23 * r2[1], s23 * a02 + c23 * r2[2]
    s5abs = xp.hypot(m02, a12)
    carry = (s5abs, xp.atan2(s5abs, m22), m00, m02, a10, a12, m20, m21, m22)
    return (t2 + math.pi) % (2.0 * math.pi) - math.pi, t3, s5abs, carry  # θ2 in [-π, π)


def _wrist(elbow: tuple[Any, ...], sign: Any, pref4: Any, xp: _Ops) -> tuple[Any, Any, Any]:
    """Wrist branch ``sign`` (+1 wpositive) of an elbow's carry -> (θ4, θ5, θ6). Where axes
    4 and 6 align only θ4 ± θ6 is defined: θ4 takes ``pref4`` (radians)."""
    s5abs, t5, m00, m02, m10, m12, m20, m21, m22 = elbow
    t4 = xp.atan2(sign * m12, sign * m02)
    t6 = xp.atan2(sign * m21, -sign * m20)
    degenerate = s5abs < _DEGENERATE
    if xp.any(degenerate):
        up = m22 > 0.0
        total = xp.where(
            up,
            xp.atan2(m10, m00),  # θ4 + θ6
            -xp.atan2(-m10, -m00),  # θ6 - θ4 (θ5 = ±π)
        )
        t6 = xp.where(degenerate, xp.where(up, total - pref4, total + pref4), t6)
        t4 = xp.where(degenerate, pref4, t4)
    return t4, sign * t5, t6


_ZERO6 = (0.0,) * 6
#: A turn this close to 180° from the target is left to the full pick (ties, round-off).
_OWN_MARGIN = 180.0 - 1e-6
_PACK6 = struct.Struct("=6d").pack
#: Degrees per radian: x * _DEG is math.degrees(x) and np.degrees(x), bit for bit.
_DEG = 180.0 / math.pi
_FREE = ConfigRequest()


#: One IK branch of one pose: joints (degrees, None when unreachable or outside the limits),
#: reachable (limits ignored), singular flags (wrist, elbow, shoulder; None without joints).
#: A plain tuple: eight are built per ik() call.
_Branch = tuple[list[float] | None, bool, tuple[bool, bool, bool] | None]


#: Two turns of a joint tie when they lie 180° either side of the target; numpy's (SIMD)
#: atan2 and libm's differ in the last bit, so the tie goes to the turn above the target
#: by this margin instead of to whichever rounding makes nearer.
_TIE_DEG = 1e-9


def _base_turn(q: Any, rnd: Any = round) -> Any:
    """q wrapped into (-180, 180]; a float with ``round``, an array with ``np.round``."""
    base = q - 360.0 * rnd(q / 360.0)
    return base + 360.0 * (base <= -180.0)


def _turn_cost(cand: Any, target: Any) -> Any:
    """How far a turn candidate is from the target, ties at 180° going to the one above it;
    floats and arrays alike (one rule for both IK paths)."""
    return abs(cand - target - _TIE_DEG)


def _pick_turn_one(q: float, bounds: tuple[float, float, bool], target: float) -> float | None:
    """Scalar :meth:`IkMixin._pick_turn`: q + 360k (k in 0, -1, 1) inside ``bounds``
    (lo, hi, only the base turn fits) with the least :func:`_turn_cost`, else None."""
    lo, hi, single = bounds
    if single:
        if lo <= q <= hi:
            return q  # inside (-180, 180): its own base turn
        base = q if -180.0 < q < 180.0 else _base_turn(q)
        return base if lo <= base <= hi else None
    # atan2's angles mostly are their own base turn: skip the rounding then
    base = q if -180.0 < q < 180.0 else _base_turn(q)
    best = base if lo <= base <= hi else None
    for cand in (base - 360.0, base + 360.0):
        if lo <= cand <= hi and (
            best is None or _turn_cost(cand, target) < _turn_cost(best, target)
        ):
            best = cand
    return best


def _one_transform(T: Any) -> list[list[float]]:
    """One flange2base (4, 4) as rows of Python floats, checked as ``check_transform`` does
    (the batch check costs more than the single IK itself)."""
    # a plain float64 (4, 4) (dtype compared by identity: == costs a conversion) is checked
    # here, anything else by check_transform
    if type(T) is np.ndarray and T.dtype is _F64 and T.shape == (4, 4):
        rows: list[list[float]] = T.tolist()
        _check_rigid_rows(rows)
        return rows
    arr = check_transform(T, name="flange2base")
    if arr.ndim != 2:
        raise KinematicsError("ik: expected one (4, 4) flange2base; use ik_batch for N")
    return arr.tolist()  # type: ignore[no-any-return]


_F64 = np.dtype(np.float64)
_LAST_ROW = [0.0, 0.0, 0.0, 1.0]  # compared first: the exact row is the common case


def _check_rigid_rows(rows: list[list[float]]) -> None:
    """``check_transform``'s tests on one (4, 4) of Python floats, same messages."""
    name = "flange2base"
    r0, r1, r2, r3 = rows
    # a NaN or an infinity makes the sum one; only an overflow needs the look at each entry
    if not math.isfinite(sum(r0) + sum(r1) + sum(r2) + sum(r3)) and not all(
        math.isfinite(v) for row in rows for v in row
    ):
        raise KinematicsError(f"{name}: contains NaN or infinity")
    tol = RIGID_TOL
    if r3 != _LAST_ROW and (
        abs(r3[0]) > tol or abs(r3[1]) > tol or abs(r3[2]) > tol or abs(r3[3] - 1.0) > tol
    ):
        raise KinematicsError(f"{name}: last row must be (0, 0, 0, 1)")
    a, b, c, _ = r0
    d, e, f, _ = r1
    g, h, i_, _ = r2
    # RᵀR - I, the six distinct entries
    gram = (
        a * a + d * d + g * g - 1.0,
        b * b + e * e + h * h - 1.0,
        c * c + f * f + i_ * i_ - 1.0,
        a * b + d * e + g * h,
        a * c + d * f + g * i_,
        b * c + e * f + h * i_,
    )
    if (
        max(gram) > tol
        or min(gram) < -tol
        or (a * (e * i_ - f * h) - b * (d * i_ - f * g) + c * (d * h - e * g) < 0.0)
    ):
        raise KinematicsError(f"{name}: rotation part is not orthonormal with det +1")


class IkMixin(ConfigMixin):
    """All IK solutions of one pose, or all 8 branches of N poses."""

    def ik_batch(self, flange2base_T: Any, near: Any = None) -> IkBatch:
        """All 8 IK branches for N poses (N, 4, 4) -> ``IkBatch`` (axis 1 follows ``CONFIGS``).

        Each joint is reported in the turn (±360°) inside its limits that is closest to
        ``near`` (N, 6) or (6,) degrees, or to zero without it. Vectorised, no loop over N.
        """
        T = check_transform(flange2base_T, name="flange2base")
        if T.ndim != 3:
            raise KinematicsError(f"flange2base: expected shape (N, 4, 4), got {T.shape}")
        return self._ik_batch(T, near)

    def _ik_batch(self, T: FloatArray, near: Any) -> IkBatch:
        ref = None
        if near is not None:
            nr = np.asarray(near, dtype=np.float64)
            if nr.shape == (6,):
                nr = np.broadcast_to(nr, (T.shape[0], 6))
            ref = batch6(nr, "near")
            if ref.shape[0] != T.shape[0]:
                raise KinematicsError("near: must be (6,) or one row per pose")
        theta, reach, sing = self._ik_core(T, ref)
        q = np.degrees(theta) - self._offsets
        q = self._pick_turn(q, ref)
        inside = np.all(np.isfinite(q), axis=-1)
        valid = reach & inside
        q[~valid] = np.nan
        return IkBatch(joints_deg=q, valid=valid, reachable=reach, singular=sing)

    def _pick_turn(self, q: FloatArray, ref: FloatArray | None) -> FloatArray:
        """Per joint, the value q + 360k (k in -1, 0, 1) inside the limits with the least
        :func:`_turn_cost` to ref."""
        cand = _base_turn(q, np.round)[..., None] + np.array([0.0, -360.0, 360.0])  # (N, 8, 6, 3)
        lo = self._limits[:, 0, None] - LIMIT_SLACK_DEG
        hi = self._limits[:, 1, None] + LIMIT_SLACK_DEG
        target = np.zeros(6) if ref is None else ref[:, None, :]
        dist = _turn_cost(cand, np.asarray(target)[..., None])
        dist = np.where((cand >= lo) & (cand <= hi), dist, np.inf)
        k = np.argmin(dist, axis=-1)
        best = np.take_along_axis(cand, k[..., None], axis=-1)[..., 0]
        ok = np.take_along_axis(dist, k[..., None], axis=-1)[..., 0] < np.inf
        return np.where(ok, best, np.nan)

    def _ik_core(
        self, T: FloatArray, ref: FloatArray | None
    ) -> tuple[FloatArray, BoolArray, BoolArray]:
        """Model angles θ (N, 8, 6) rad, reachable (N, 8), singular flags (N, 8, 3)."""
        n = T.shape[0]
        g, xp = self._ik_geometry, _NUMPY
        Tv = T.transpose(1, 2, 0)  # Tv[row][col] is (N,)
        pref1, pref4 = None, 0.0
        if ref is not None:
            pref1 = np.radians(ref[:, 0] + self._offsets[0])
            pref4 = np.radians(ref[:, 3] + self._offsets[3])
        centre = _wrist_centre(g, Tv, xp)
        t1, reach, sing_sh, sh = _shoulder(g, centre, _SIGNS[0], pref1, xp)  # (2, N)
        s3abs, arm = _arm_plane(Tv, sh, xp)
        t2, t3, s5abs, el = _elbow(g, Tv, arm, _SIGNS[1], xp)  # (2, 2, N)
        t4, t5, t6 = _wrist(el, _SIGNS[2], pref4, xp)  # (2, 2, 2, N)
        # axes (wrist, elbow, shoulder, pose) -> (pose, shoulder, elbow, wrist): CONFIGS order
        order = (4, 3, 2, 1, 0)
        theta = np.empty((6, 2, 2, 2, n))
        for i, t in enumerate((t1, t2, t3, t4, t5, t6)):
            theta[i] = t
        flags = np.empty((4, 2, 2, 2, n), dtype=bool)  # singular (wrist, elbow, shoulder), reach
        for i, f in enumerate((s5abs < SINGULAR_TOL, s3abs < SINGULAR_TOL, sing_sh, reach)):
            flags[i] = f
        per_branch = flags.transpose(order).reshape(n, 8, 4)
        return theta.transpose(order).reshape(n, 8, 6), per_branch[..., 3], per_branch[..., :3]

    def ik(
        self,
        flange2base_T: Any,
        config: str | Config | ConfigRequest | None = None,
        near: Any = None,
        *,
        raise_on_singularity: bool = False,
    ) -> list[IkSolution]:
        """All IK solutions (up to 8) of one flange2base (4, 4) inside the joint limits.

        ``config`` keeps only matching solutions (e.g. 'righty,epositive'; 'ssame' etc. refer
        to ``near``). ``near`` (6,) degrees: joints report the turn closest to it and the
        solutions come sorted by distance to it (else in ``CONFIGS`` order). Solutions at a
        singularity list it in ``singularities`` (or raise SingularityError when asked).
        Raises UnreachableError, or JointLimitError when only limit-violating ones exist.
        """
        rows = _one_transform(flange2base_T)
        ref = None if near is None else vector6(near, "near")
        request = None if config is None else ConfigRequest.parse(config)
        if request is not None and request == _FREE:
            request = None
        same_as = None if ref is None or request is None else self.config_of(ref)
        kept: list[tuple[list[float], Config, tuple[str, ...]]] = []
        any_reachable = any_config = False
        for cfg, (q, reachable, singular) in zip(CONFIGS, self._ik_one(rows, ref), strict=True):
            if not reachable:
                continue
            any_reachable = True
            if request is not None and not request.matches(cfg, same_as):
                continue
            any_config = True
            if q is None:
                continue
            names: tuple[str, ...] = ()
            # branches coincide only at a singularity (flags come with the joints)
            if singular is not None and True in singular:
                if any(max(abs(u - v) for u, v in zip(q, k[0], strict=True)) <= 1e-9 for k in kept):
                    continue  # the same joints twice
                names = tuple(nm for nm, f in zip(SINGULARITY_NAMES, singular, strict=True) if f)
                if raise_on_singularity:
                    raise SingularityError(
                        f"{self.name}: pose is at a {names[0]} singularity", kind=names[0]
                    )
            kept.append((q, cfg, names))
        if not any_reachable:
            raise UnreachableError(self._why_unreachable(rows))
        if not kept:
            what = "" if request is None else " with the requested configuration"
            if not any_config:
                raise UnreachableError(f"{self.name}: no solution{what}")
            raise JointLimitError(f"{self.name}: every solution{what} violates a joint limit")
        if ref is not None and len(kept) > 1:
            r0, r1, r2, r3, r4, r5 = ref
            kept.sort(
                key=lambda k: (k[0][0] - r0) ** 2 + (k[0][1] - r1) ** 2 + (k[0][2] - r2) ** 2
                + (k[0][3] - r3) ** 2 + (k[0][4] - r4) ** 2 + (k[0][5] - r5) ** 2
            )  # fmt: skip
        # read-only arrays over bytes: cheaper than np.array of a list plus the flag; the
        # tuples built as the named tuple's own __new__ does, without its Python frame
        new, frombuffer = tuple.__new__, np.frombuffer
        return [new(IkSolution, (frombuffer(_PACK6(*q)), cfg, names)) for q, cfg, names in kept]

    def _ik_one(self, T: list[list[float]], ref: list[float] | None) -> list[_Branch]:
        """The 8 branches of one pose (``CONFIGS`` order), in Python floats: the batch's
        closed form over ``math``, looping over the branches (numpy's per-call overhead on
        (1, 8) arrays costs ten times the arithmetic; ToolMoveJ, jogging and the console
        pay it per pose). Each step runs only while the joints so far are inside the limits."""
        g, xp = self._ik_geometry, _MATH
        off1, off2, off3, off4, off5, off6 = self.joint_offsets_deg
        b1, b2, b3, b4, b5, b6 = self._turn_bounds
        target = ref if ref is not None else _ZERO6
        r1, r2, r3, r4, r5, r6 = target
        (l1, h1), (l2, h2), (l3, h3), (l4, h4), (l5, h5), (l6, h6) = self._own_turn(target)
        pick, deg = _pick_turn_one, _DEG
        pref1 = None if ref is None else math.radians(r1 + off1)
        pref4 = 0.0 if ref is None else math.radians(r4 + off4)
        centre = _wrist_centre(g, T, xp)
        out: list[_Branch] = []
        # Each joint: v if it lies where it is its own pick (_own_turn), else the full pick.
        for s in (1.0, -1.0):
            t1, reach, sing_sh, sh = _shoulder(g, centre, s, pref1, xp)
            # joint 1 is shared by the four branches of this shoulder: its turn picked once
            v = t1 * deg - off1
            q1 = (v if l1 < v < h1 else pick(v, b1, r1)) if reach else None
            if q1 is None:
                out += ((None, reach, None),) * 4
                continue
            s3abs, arm = _arm_plane(T, sh, xp)
            for e in (1.0, -1.0):
                t2, t3, s5abs, el = _elbow(g, T, arm, e, xp)
                # joints 2-3 are shared by both wrist branches: their turns picked once
                v = t2 * deg - off2
                q2 = v if l2 < v < h2 else pick(v, b2, r2)
                v = t3 * deg - off3
                q3 = v if l3 < v < h3 else pick(v, b3, r3)
                if q2 is None or q3 is None:
                    out += ((None, reach, None), (None, reach, None))
                    continue
                sing = (s5abs < SINGULAR_TOL, s3abs < SINGULAR_TOL, sing_sh)
                for w in (1.0, -1.0):
                    t4, t5, t6 = _wrist(el, w, pref4, xp)
                    v = t4 * deg - off4
                    q4 = v if l4 < v < h4 else pick(v, b4, r4)
                    v = t5 * deg - off5
                    q5 = v if l5 < v < h5 else pick(v, b5, r5)
                    v = t6 * deg - off6
                    q6 = v if l6 < v < h6 else pick(v, b6, r6)
                    if q4 is None or q5 is None or q6 is None:
                        out.append((None, reach, None))
                    else:
                        out.append(([q1, q2, q3, q4, q5, q6], reach, sing))
        return out

    @cached_property
    def _ik_geometry(self) -> _Geometry:
        a1, d = self.shoulder_offset_mm, self.lateral_offset_mm
        return _Geometry(
            a1,
            d,
            self.upper_arm_mm,
            self.forearm_mm,
            self.wrist_to_flange_mm,
            1e-9 * (self.reach_mm + abs(a1) + abs(d)),
            SINGULAR_TOL * self.reach_mm,
        )

    @cached_property
    def _turn_bounds(self) -> tuple[tuple[float, float, bool], ...]:
        """Per joint: the limits widened by the slack as Python floats, and whether only the
        turn in (-180, 180] can lie inside them (the scalar IK's turn pick)."""
        lim = self._limits.tolist()
        out = []
        for lo, hi in lim:
            lo, hi = lo - LIMIT_SLACK_DEG, hi + LIMIT_SLACK_DEG
            out.append((lo, hi, lo > -180.0 and hi < 180.0))
        return tuple(out)

    def _own_turn(self, target: Sequence[float]) -> Sequence[tuple[float, float]]:
        """Per joint: an open interval (degrees) where a value is its own turn pick (what
        :func:`_pick_turn_one` returns): inside the limits and (-180, 180), every other turn
        outside the limits (a single-turn joint) or over 180° from ``target`` (6,)."""
        if target is _ZERO6:
            return self._own_turn_at_zero
        out = list(self._own_turn_at_zero)
        for j, lo, hi in self._multi_turn:
            t = target[j]
            out[j] = (max(lo, t - _OWN_MARGIN), min(hi, t + _OWN_MARGIN))
        return out

    @cached_property
    def _multi_turn(self) -> tuple[tuple[int, float, float], ...]:
        """The joints whose limits hold more than one turn: index, limits cut to (-180, 180)."""
        return tuple(
            (j, max(lo, -180.0), min(hi, 180.0))
            for j, (lo, hi, single) in enumerate(self._turn_bounds)
            if not single
        )

    @cached_property
    def _own_turn_at_zero(self) -> tuple[tuple[float, float], ...]:
        out = [(lo, hi) for lo, hi, _ in self._turn_bounds]
        for j, lo, hi in self._multi_turn:
            out[j] = (max(lo, -_OWN_MARGIN), min(hi, _OWN_MARGIN))
        return tuple(out)

    def _why_unreachable(self, T: list[list[float]]) -> str:
        g = self._ik_geometry
        root, _, wz, _, rho2 = _wrist_centre(g, T, _MATH)
        rho, d = math.sqrt(rho2), abs(g.d)
        if rho < d:
            return (
                f"{self.name}: unreachable, wrist centre {rho:.3f} mm from axis 1 "
                f"(< lateral offset {d:g} mm)"
            )
        dist = min(math.hypot(root - g.a1, wz), math.hypot(-root - g.a1, wz))
        return (
            f"{self.name}: unreachable, wrist centre {dist:.3f} mm from axis 2, "
            f"reach is [{abs(g.a2 - g.d4):g}, {g.a2 + g.d4:g}] mm"
        )
