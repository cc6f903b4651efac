"""Analytic IK of the Stäubli arms: axes 4, 5, 6 meet in the wrist centre, so the IK is
closed-form with up to 8 solutions (the configurations of :data:`kinematics.config.CONFIGS`),
for one pose or vectorised over N poses."""

from __future__ import annotations

import math
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
from kinematics.transforms import RIGID_TOL, Array, check_transform

#: Below this, the closed form degenerates and the free joint takes the preferred value.
_DEGENERATE = 1e-12


@dataclass(frozen=True, eq=False)
class IkSolution:
    """One IK solution: VAL3 joints (6,) in degrees, its configuration, any singularities."""

    joints_deg: Array
    config: Config
    singularities: tuple[str, ...] = ()

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

    joints_deg: Array
    valid: BoolArray
    reachable: BoolArray
    singular: BoolArray


def _wrap_pi(a: Array) -> Array:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi)


_ZERO6 = (0.0,) * 6
_FREE = ConfigRequest()


class _Branch(NamedTuple):
    """One IK branch of one pose: joints (degrees, None when unreachable or outside the
    limits), reachable (limits ignored), singular flags (wrist, elbow, shoulder). A tuple:
    eight are built per ik() call."""

    joints_deg: list[float] | None
    reachable: bool
    singular: tuple[bool, bool, bool]


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
    base = _base_turn(q)
    lo, hi, single = bounds
    if single:
        return base if lo <= base <= hi else None
    best = None
    for cand in (base, base - 360.0, base + 360.0):
        if lo <= cand <= hi and (
            best is None or _turn_cost(cand, target) < _turn_cost(best, target)
        ):
            best = cand
    return best


def _one_transform(T: Any) -> list[list[float]]:
    """One flange2base (4, 4) as rows of Python floats, checked as ``check_transform`` does
    (the batch check costs more than the single IK itself)."""
    arr = check_transform(T, name="flange2base") if not _plain_4x4(T) else T
    if arr.ndim != 2:
        raise KinematicsError("ik: expected one (4, 4) flange2base; use ik_batch for N")
    rows: list[list[float]] = arr.tolist()
    if arr is T:
        _check_rigid_rows(rows)
    return rows


def _plain_4x4(T: Any) -> bool:
    return isinstance(T, np.ndarray) and T.dtype == np.float64 and T.shape == (4, 4)


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
    if abs(r3[0]) > tol or abs(r3[1]) > tol or abs(r3[2]) > tol or abs(r3[3] - 1.0) > tol:
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

    def _ik_batch(self, T: Array, near: Any) -> IkBatch:
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

    def _pick_turn(self, q: Array, ref: Array | None) -> Array:
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

    def _ik_core(self, T: Array, ref: Array | None) -> tuple[Array, BoolArray, BoolArray]:
        """Model angles θ (N, 8, 6) rad, reachable (N, 8), singular flags (N, 8, 3)."""
        n = T.shape[0]
        a1, d = self.shoulder_offset_mm, self.lateral_offset_mm
        a2, d4, d6 = self.upper_arm_mm, self.forearm_mm, self.wrist_to_flange_mm
        R = T[:, :3, :3]
        w = T[:, :3, 3] - d6 * R[:, :, 2]
        wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
        rho2 = wx * wx + wy * wy
        disc = rho2 - d * d
        len_tol = 1e-9 * (self.reach_mm + abs(a1) + abs(d))
        reach_sh = disc >= -2.0 * len_tol * max(abs(d), 1.0)
        root = np.sqrt(np.maximum(disc, 0.0))
        r = np.stack([root, -root], axis=1)  # (N, 2): righty, lefty
        phi = np.arctan2(wy, wx)[:, None]
        t1 = phi - np.arctan2(d, r)
        if ref is not None:
            # Wrist centre on axis 1 (no lateral offset): θ1 is free, keep the current one.
            free1 = (rho2 < len_tol**2)[:, None]
            t1 = np.where(free1, np.radians(ref[:, 0] + self._offsets[0])[:, None], t1)
        xp = r - a1
        zp = np.broadcast_to(wz[:, None], xp.shape)
        c3 = (xp * xp + zp * zp - a2 * a2 - d4 * d4) / (2.0 * a2 * d4)
        reach_el = np.abs(c3) <= 1.0 + 1e-12
        c3 = np.clip(c3, -1.0, 1.0)
        s3abs = np.sqrt(1.0 - c3 * c3)
        s3 = np.stack([s3abs, -s3abs], axis=2)  # (N, 2, 2): epositive, enegative
        c3b = np.broadcast_to(c3[:, :, None], s3.shape)
        t3 = np.arctan2(s3, c3b)
        t2 = np.arctan2(xp, zp)[:, :, None] - np.arctan2(d4 * s3, a2 + d4 * c3b)
        t23 = t2 + t3
        # Wrist: M = (Rz(θ1)·Ry(θ23))ᵀ·R = Rz(θ4)·Ry(θ5)·Rz(θ6).
        s1, c1 = np.sin(t1)[:, :, None, None], np.cos(t1)[:, :, None, None]
        R4 = R[:, None, None, :, :]
        A0 = c1 * R4[..., 0, :] + s1 * R4[..., 1, :]
        A1 = -s1 * R4[..., 0, :] + c1 * R4[..., 1, :]
        A2 = np.broadcast_to(R4[..., 2, :], A0.shape)
        s23, c23 = np.sin(t23)[..., None], np.cos(t23)[..., None]
        M0 = c23 * A0 - s23 * A2
        M2 = s23 * A0 + c23 * A2
        m00, m02, m10, m12 = M0[..., 0], M0[..., 2], A1[..., 0], A1[..., 2]
        m20, m21, m22 = M2[..., 0], M2[..., 1], M2[..., 2]
        s5abs = np.hypot(m02, m12)  # (N, 2, 2)
        t5 = np.stack([np.arctan2(s5abs, m22), -np.arctan2(s5abs, m22)], axis=3)
        t4 = np.stack([np.arctan2(m12, m02), np.arctan2(-m12, -m02)], axis=3)
        t6 = np.stack([np.arctan2(m21, -m20), np.arctan2(-m21, m20)], axis=3)
        degenerate = np.broadcast_to((s5abs < _DEGENERATE)[..., None], t4.shape)
        if np.any(degenerate):
            # Axes 4 and 6 aligned: only θ4 ± θ6 is defined; keep θ4 (current or 0).
            pref4 = (
                np.zeros((n, 1, 1, 1))
                if ref is None
                else np.radians(ref[:, 3] + self._offsets[3])[:, None, None, None]
            )
            pref4 = np.broadcast_to(pref4, t4.shape)
            up = np.broadcast_to((m22 > 0.0)[..., None], t4.shape)
            total = np.where(
                up,
                np.arctan2(m10, m00)[..., None],  # θ4 + θ6
                -np.arctan2(-m10, -m00)[..., None],  # θ6 - θ4 (θ5 = ±π)
            )
            t6 = np.where(degenerate, np.where(up, total - pref4, total + pref4), t6)
            t4 = np.where(degenerate, pref4, t4)
        shape = (n, 2, 2, 2)
        theta = np.empty((*shape, 6))
        theta[..., 0] = np.broadcast_to(t1[:, :, None, None], shape)
        theta[..., 1] = np.broadcast_to(_wrap_pi(t2)[..., None], shape)
        theta[..., 2] = np.broadcast_to(t3[..., None], shape)
        theta[..., 3] = t4
        theta[..., 4] = t5
        theta[..., 5] = t6
        reach = np.broadcast_to((reach_sh[:, None] & reach_el)[:, :, None, None], shape)
        sing = np.empty((*shape, 3), dtype=bool)
        sing[..., 0] = np.broadcast_to((s5abs < SINGULAR_TOL)[..., None], shape)
        sing[..., 1] = np.broadcast_to((s3abs < SINGULAR_TOL)[:, :, None, None], shape)
        sing[..., 2] = np.broadcast_to(
            (np.abs(r) < SINGULAR_TOL * self.reach_mm)[:, :, None, None], shape
        )
        return theta.reshape(n, 8, 6), reach.reshape(n, 8).copy(), sing.reshape(n, 8, 3)

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
        request = _FREE if config is None else ConfigRequest.parse(config)
        free = request == _FREE
        same_as = None if ref is None or free else self.config_of(ref)
        branches = self._ik_one(rows, ref)
        if not any(b.reachable for b in branches):
            raise UnreachableError(self._why_unreachable(np.array(rows)))
        kept: list[tuple[list[float], Config, tuple[str, ...]]] = []
        any_config = False
        for cfg, (q, reachable, singular) in zip(CONFIGS, branches, strict=True):
            if not reachable or not (free or request.matches(cfg, same_as)):
                continue
            any_config = True
            if q is None:
                continue
            names: tuple[str, ...] = ()
            if singular[0] or singular[1] or singular[2]:  # branches coincide only there
                if any(max(abs(u - v) for u, v in zip(q, k[0], strict=True)) <= 1e-9 for k in kept):
                    continue  # the same joints twice
                names = tuple(nm for nm, f in zip(SINGULARITY_NAMES, singular, strict=True) if f)
                if raise_on_singularity:
                    raise SingularityError(
                        f"{self.name}: pose is at a {names[0]} singularity", kind=names[0]
                    )
            kept.append((q, cfg, names))
        if not kept:
            what = "" if free else " with the requested configuration"
            if not any_config:
                raise UnreachableError(f"{self.name}: no solution{what}")
            raise JointLimitError(f"{self.name}: every solution{what} violates a joint limit")
        if ref is not None:
            r0, r1, r2, r3, r4, r5 = ref
            kept.sort(
                key=lambda k: (k[0][0] - r0) ** 2 + (k[0][1] - r1) ** 2 + (k[0][2] - r2) ** 2
                + (k[0][3] - r3) ** 2 + (k[0][4] - r4) ** 2 + (k[0][5] - r5) ** 2
            )  # fmt: skip
        # one read-only array, a row per solution: one numpy call, not one per solution
        joints = np.array([q for q, _, _ in kept])
        joints.flags.writeable = False
        return [IkSolution(j, cfg, names) for j, (_, cfg, names) in zip(joints, kept, strict=True)]

    def _ik_one(self, T: list[list[float]], ref: list[float] | None) -> list[_Branch]:
        """The 8 branches of one pose (``CONFIGS`` order), in Python floats.

        The scalar twin of :meth:`_ik_core` + :meth:`_pick_turn`: the same formulas step for
        step (tests check it against the batch), because numpy's per-call overhead on (1, 8)
        arrays costs ten times the arithmetic; ToolMoveJ, jogging and the console pay it per
        pose.
        """
        a1, d = self.shoulder_offset_mm, self.lateral_offset_mm
        a2, d4, d6 = self.upper_arm_mm, self.forearm_mm, self.wrist_to_flange_mm
        off = self.joint_offsets_deg
        r0, r1, r2 = T[0], T[1], T[2]
        wx, wy, wz = r0[3] - d6 * r0[2], r1[3] - d6 * r1[2], r2[3] - d6 * r2[2]
        rho2 = wx * wx + wy * wy
        disc = rho2 - d * d
        reach_mm = a2 + d4
        len_tol = 1e-9 * (reach_mm + abs(a1) + abs(d))
        reach_sh = disc >= -2.0 * len_tol * max(abs(d), 1.0)
        shoulder_tol = SINGULAR_TOL * reach_mm
        root = math.sqrt(max(disc, 0.0))
        phi = math.atan2(wy, wx)
        free1 = ref is not None and rho2 < len_tol**2
        lo_hi = self._turn_bounds
        pick = _pick_turn_one
        target = ref if ref is not None else _ZERO6
        out: list[_Branch] = []
        for r in (root, -root):
            t1 = (
                math.radians(ref[0] + off[0])
                if free1 and ref is not None
                else phi - math.atan2(d, r)
            )
            xp = r - a1
            zp = wz
            c3 = (xp * xp + zp * zp - a2 * a2 - d4 * d4) / (2.0 * a2 * d4)
            reach = reach_sh and abs(c3) <= 1.0 + 1e-12
            c3 = min(max(c3, -1.0), 1.0)
            s3abs = math.sqrt(1.0 - c3 * c3)
            s1, c1 = math.sin(t1), math.cos(t1)
            # A = Rz(θ1)ᵀ·R, rows 0, 1, 2
            a00 = c1 * r0[0] + s1 * r1[0]
            a01 = c1 * r0[1] + s1 * r1[1]
            a02 = c1 * r0[2] + s1 * r1[2]
            m10, m12 = -s1 * r0[0] + c1 * r1[0], -s1 * r0[2] + c1 * r1[2]
            a20, a21, a22 = r2[0], r2[1], r2[2]
            shoulder_sing = abs(r) < shoulder_tol
            # joint 1 is shared by the four branches of this shoulder: its turn picked once
            q1 = pick(math.degrees(t1) - off[0], lo_hi[0], target[0]) if reach else None
            for s3 in (s3abs, -s3abs):
                t3 = math.atan2(s3, c3)
                t2 = math.atan2(xp, zp) - math.atan2(d4 * s3, a2 + d4 * c3)
                t23 = t2 + t3
                s23, c23 = math.sin(t23), math.cos(t23)
                m02 = c23 * a02 - s23 * a22
                m22 = s23 * a02 + c23 * a22
                s5abs = math.hypot(m02, m12)
                sing = (s5abs < SINGULAR_TOL, s3abs < SINGULAR_TOL, shoulder_sing)
                # joints 2-3 are shared by both wrist branches: their turns picked once
                q2 = q3 = None
                if q1 is not None:
                    t2w = (t2 + math.pi) % (2.0 * math.pi) - math.pi
                    q2 = pick(math.degrees(t2w) - off[1], lo_hi[1], target[1])
                    if q2 is not None:
                        q3 = pick(math.degrees(t3) - off[2], lo_hi[2], target[2])
                if q1 is None or q2 is None or q3 is None:
                    out += (_Branch(None, reach, sing), _Branch(None, reach, sing))
                    continue
                m00 = c23 * a00 - s23 * a20
                m20 = s23 * a00 + c23 * a20
                m21 = s23 * a01 + c23 * a21
                t5p = math.atan2(s5abs, m22)
                wraps = ((t5p, math.atan2(m12, m02), math.atan2(m21, -m20)),
                         (-t5p, math.atan2(-m12, -m02), math.atan2(-m21, m20)))  # fmt: skip
                if s5abs < _DEGENERATE:
                    # Axes 4 and 6 aligned: only θ4 ± θ6 is defined; keep θ4 (current or 0).
                    pref4 = 0.0 if ref is None else math.radians(ref[3] + off[3])
                    if m22 > 0.0:
                        t6 = math.atan2(m10, m00) - pref4  # θ4 + θ6
                    else:
                        t6 = -math.atan2(-m10, -m00) + pref4  # θ6 - θ4 (θ5 = ±π)
                    wraps = ((t5p, pref4, t6), (-t5p, pref4, t6))
                for t5, t4, t6 in wraps:
                    q: list[float] | None = None
                    q4 = pick(math.degrees(t4) - off[3], lo_hi[3], target[3])
                    q5 = pick(math.degrees(t5) - off[4], lo_hi[4], target[4])
                    q6 = pick(math.degrees(t6) - off[5], lo_hi[5], target[5])
                    if q4 is not None and q5 is not None and q6 is not None:
                        q = [q1, q2, q3, q4, q5, q6]
                    out.append(_Branch(q, reach, sing))
        return out

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

    def _why_unreachable(self, T: Array) -> str:
        w = T[:3, 3] - self.wrist_to_flange_mm * T[:3, 2]
        rho = math.hypot(w[0], w[1])
        d = abs(self.lateral_offset_mm)
        if rho < d:
            return (
                f"{self.name}: unreachable, wrist centre {rho:.3f} mm from axis 1 "
                f"(< lateral offset {d:g} mm)"
            )
        a2, d4 = self.upper_arm_mm, self.forearm_mm
        r = math.sqrt(max(rho * rho - d * d, 0.0))
        dist = min(math.hypot(r - self.shoulder_offset_mm, w[2]),
                   math.hypot(-r - self.shoulder_offset_mm, w[2]))  # fmt: skip
        return (
            f"{self.name}: unreachable, wrist centre {dist:.3f} mm from axis 2, "
            f"reach is [{abs(a2 - d4):g}, {a2 + d4:g}] mm"
        )
