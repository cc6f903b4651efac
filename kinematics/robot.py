"""Stäubli 6R arms: the DGM (paper eq. 3), analytic IK, Jacobian and singularities.

Geometry of every model (data in ``kinematics/models/*.json``), VAL3 joints all zero, arm
straight up; see ``kinematics/CONVENTIONS.md`` for the directions a pendant shows:

    flange2base = Rz(θ1)·Tx(a1)·Ty(d)·Ry(θ2)·Tz(a2)·Ry(θ3)·Tz(d4)·Rz(θ4)·Ry(θ5)·Rz(θ6)·Tz(d6)

with θi = qi + joint_offset_i (VAL3 joints q in degrees, encoder offsets as data), a1 the
shoulder offset (axis 1 to axis 2, along the arm's forward x), d the lateral offset (along
axis 2; the forearm plane sits d to the arm's left, +y at J1 = 0), a2 the upper arm (axis 2
to axis 3), d4 the forearm (axis 3 to the wrist centre) and d6 the wrist centre to the flange
face. Axes 2, 3 and 5 turn about +y, axes 1, 4 and 6 about +z of the moving frame, so a
positive J2, J3 or J5 tips the next link toward +x ("forward"). Axes 4, 5, 6 meet in the
wrist centre: the IK is closed-form with up to 8 solutions.

VAL3 configuration: shoulder 'righty' when the wrist centre lies on the forward side of axis 1
(r >= 0 along the arm's x after J1), 'lefty' behind it; elbow 'epositive' when J3 >= 0;
wrist 'wpositive' when J5 >= 0.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from kinematics.errors import (
    JointLimitError,
    KinematicsError,
    SingularityError,
    UnknownModelError,
    UnreachableError,
)
from kinematics.transforms import check_transform

Array = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MODELS_DIR = Path(__file__).with_name("models")
DEFAULT_MODEL = "RX90B"

#: A configuration is reported singular when |sin J5|, |sin J3| or r / (a2 + d4) is below this.
SINGULAR_TOL = 1e-6
#: Joint values this far outside a limit (degrees) still count as inside (round-off).
LIMIT_SLACK_DEG = 1e-9
#: Below this, the closed form degenerates and the free joint takes the preferred value.
_DEGENERATE = 1e-12
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


Shoulder = Literal["righty", "lefty"]
Elbow = Literal["epositive", "enegative"]
Wrist = Literal["wpositive", "wnegative"]


@dataclass(frozen=True)
class Config:
    """A VAL3 arm configuration (the ``config`` of a location)."""

    shoulder: Shoulder
    elbow: Elbow
    wrist: Wrist

    def as_dict(self) -> dict[str, str]:
        return {"shoulder": self.shoulder, "elbow": self.elbow, "wrist": self.wrist}


#: The 8 configurations in the order of the batch IK's solution axis.
CONFIGS: tuple[Config, ...] = tuple(
    Config(s, e, w)
    for s in ("righty", "lefty")
    for e in ("epositive", "enegative")
    for w in ("wpositive", "wnegative")
)


@dataclass(frozen=True)
class ConfigRequest:
    """A requested configuration; None means free (VAL3 sfree/efree/wfree), 'same' as near."""

    shoulder: str | None = None
    elbow: str | None = None
    wrist: str | None = None

    @classmethod
    def parse(cls, text: str | Config | ConfigRequest | None) -> ConfigRequest:
        """Parse 'righty,epositive,wpositive' (any subset, any order; sfree/ssame etc.)."""
        if text is None:
            return cls()
        if isinstance(text, ConfigRequest):
            return text
        if isinstance(text, Config):
            return cls(text.shoulder, text.elbow, text.wrist)
        values: dict[str, str | None] = {}
        for raw in text.replace(";", ",").split(","):
            tok = raw.strip().lower()
            if not tok:
                continue
            key = _CONFIG_TOKENS.get(tok)
            if key is None:
                raise KinematicsError(
                    f"config: unknown value {raw.strip()!r} (use righty/lefty/ssame/sfree, "
                    "epositive/enegative/esame/efree, wpositive/wnegative/wsame/wfree)"
                )
            if key in values:
                raise KinematicsError(f"config: {key} given twice")
            values[key] = None if tok.endswith("free") else tok
        return cls(**values)

    def matches(self, config: Config, same_as: Config | None) -> bool:
        for key in ("shoulder", "elbow", "wrist"):
            want = getattr(self, key)
            if want is None:
                continue
            if want.endswith("same"):
                if same_as is None:
                    raise KinematicsError(f"config: {want} needs the current joints (near)")
                want = getattr(same_as, key)
            if getattr(config, key) != want:
                return False
        return True


_CONFIG_TOKENS = {
    **dict.fromkeys(("righty", "lefty", "ssame", "sfree"), "shoulder"),
    **dict.fromkeys(("epositive", "enegative", "esame", "efree"), "elbow"),
    **dict.fromkeys(("wpositive", "wnegative", "wsame", "wfree"), "wrist"),
}


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


SINGULARITY_NAMES = ("wrist", "elbow", "shoulder")


def _vector6(q: Any, name: str = "joints") -> list[float]:
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


def _batch6(q: Any, name: str = "joints") -> Array:
    try:
        arr = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise KinematicsError(f"{name}: expected an (N, 6) array of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise KinematicsError(f"{name}: expected shape (N, 6), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise KinematicsError(f"{name}: contains NaN or infinity")
    return arr


def _wrap_pi(a: Array) -> Array:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi)


@dataclass(frozen=True)
class RobotModel:
    """A Stäubli 6R arm with a spherical wrist. Lengths in mm, angles in degrees.

    ``joint_limits_deg`` is (6, 2) [lower, upper] in VAL3 joints; ``joint_offsets_deg`` (6,)
    is added to the VAL3 joints before the geometry (encoder offset correction).
    """

    name: str
    upper_arm_mm: float
    forearm_mm: float
    wrist_to_flange_mm: float
    joint_limits_deg: tuple[tuple[float, float], ...]
    shoulder_offset_mm: float = 0.0
    lateral_offset_mm: float = 0.0
    floor_to_axis2_mm: float = 0.0
    joint_offsets_deg: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    description: str = ""
    _limits: Array = field(init=False, repr=False, compare=False)
    _offsets: Array = field(init=False, repr=False, compare=False)
    #: The DGM's lengths in the order ``_flange_rows`` takes them.
    _lengths: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        lim = np.asarray(self.joint_limits_deg, dtype=np.float64)
        off = np.asarray(self.joint_offsets_deg, dtype=np.float64)
        if lim.shape != (6, 2) or not np.all(np.isfinite(lim)) or np.any(lim[:, 0] >= lim[:, 1]):
            raise KinematicsError(f"model {self.name}: joint_limits_deg must be 6 [lower, upper]")
        if off.shape != (6,) or not np.all(np.isfinite(off)):
            raise KinematicsError(f"model {self.name}: joint_offsets_deg must be 6 numbers")
        for key in ("upper_arm_mm", "forearm_mm"):
            if not float(getattr(self, key)) > 0.0:
                raise KinematicsError(f"model {self.name}: {key} must be > 0")
        for key in ("wrist_to_flange_mm", "shoulder_offset_mm", "lateral_offset_mm"):
            if not math.isfinite(float(getattr(self, key))):
                raise KinematicsError(f"model {self.name}: {key} must be finite")
        lim.flags.writeable = False
        off.flags.writeable = False
        object.__setattr__(self, "_limits", lim)
        object.__setattr__(self, "_offsets", off)
        lengths = (
            self.shoulder_offset_mm,
            self.lateral_offset_mm,
            self.upper_arm_mm,
            self.forearm_mm,
            self.wrist_to_flange_mm,
        )
        object.__setattr__(self, "_lengths", lengths)

    # --- data -------------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobotModel:
        """Build a model from its JSON form (see ``kinematics/models/RX90B.json``)."""
        try:
            return cls(
                name=str(data["name"]),
                upper_arm_mm=float(data["upper_arm_mm"]),
                forearm_mm=float(data["forearm_mm"]),
                wrist_to_flange_mm=float(data["wrist_to_flange_mm"]),
                joint_limits_deg=tuple(
                    (float(lo), float(hi)) for lo, hi in data["joint_limits_deg"]
                ),
                shoulder_offset_mm=float(data.get("shoulder_offset_mm", 0.0)),
                lateral_offset_mm=float(data.get("lateral_offset_mm", 0.0)),
                floor_to_axis2_mm=float(data.get("floor_to_axis2_mm", 0.0)),
                joint_offsets_deg=tuple(float(v) for v in data.get("joint_offsets_deg", [0.0] * 6)),
                description=str(data.get("description", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, KinematicsError):
                raise
            raise KinematicsError(f"model data: missing or bad field ({exc})") from None

    def to_dict(self) -> dict[str, Any]:
        """The JSON form of the model."""
        return {
            "name": self.name,
            "description": self.description,
            "floor_to_axis2_mm": self.floor_to_axis2_mm,
            "shoulder_offset_mm": self.shoulder_offset_mm,
            "lateral_offset_mm": self.lateral_offset_mm,
            "upper_arm_mm": self.upper_arm_mm,
            "forearm_mm": self.forearm_mm,
            "wrist_to_flange_mm": self.wrist_to_flange_mm,
            "joint_limits_deg": [list(p) for p in self.joint_limits_deg],
            "joint_offsets_deg": list(self.joint_offsets_deg),
        }

    @property
    def limits(self) -> Array:
        """Joint limits (6, 2) in degrees, [lower, upper] (read-only array)."""
        return self._limits

    @property
    def reach_mm(self) -> float:
        """Distance from axis 2 to the wrist centre with the arm stretched (a2 + d4)."""
        return self.upper_arm_mm + self.forearm_mm

    # --- limits -----------------------------------------------------------------------------

    def within_limits(self, q_deg: Any) -> bool | BoolArray:
        """True where all joints of (6,) or (N, 6) lie inside the limits."""
        arr = np.asarray(q_deg, dtype=np.float64)
        inside = (arr >= self._limits[:, 0] - LIMIT_SLACK_DEG) & (
            arr <= self._limits[:, 1] + LIMIT_SLACK_DEG
        )
        res = np.all(inside, axis=-1)
        return bool(res) if res.ndim == 0 else res

    def check_joints(self, q_deg: Any) -> Array:
        """Validate joints (6,): finite and inside the limits, else JointLimitError."""
        q = np.array(_vector6(q_deg))
        for i in range(6):
            lo, hi = self.joint_limits_deg[i]
            if not lo - LIMIT_SLACK_DEG <= q[i] <= hi + LIMIT_SLACK_DEG:
                raise JointLimitError(
                    f"{self.name}: J{i + 1} = {q[i]:.6g} deg outside [{lo:g}, {hi:g}]"
                )
        return q

    # --- DGM --------------------------------------------------------------------------------

    def flange2base(self, q_deg: Any) -> Array:
        """DGM (paper eq. 3): VAL3 joints (6,) deg -> flange2base (4, 4), or (N, 6) -> (N, 4, 4).

        Joint limits are not checked here (see ``check_joints``).
        """
        if isinstance(q_deg, np.ndarray) and q_deg.ndim == 2:
            return self.flange2base_batch(q_deg)
        q1, q2, q3, q4, q5, q6 = _vector6(q_deg)
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

    def flange2base_batch(self, q_deg: Any) -> Array:
        """Vectorised DGM: VAL3 joints (N, 6) deg -> flange2base (N, 4, 4)."""
        q = _batch6(q_deg)
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

    # --- configuration and singularities ---------------------------------------------------

    def _geometry(self, q_deg: Sequence[float]) -> tuple[float, float, float]:
        """(r, sin θ3, sin θ5): wrist centre ahead of axis 1 (mm), elbow and wrist measures."""
        t = [math.radians(v + o) for v, o in zip(q_deg, self.joint_offsets_deg, strict=True)]
        r = (
            self.shoulder_offset_mm
            + self.upper_arm_mm * math.sin(t[1])
            + self.forearm_mm * math.sin(t[1] + t[2])
        )
        return r, math.sin(t[2]), math.sin(t[4])

    def config_of(self, q_deg: Any) -> Config:
        """The VAL3 configuration of joints (6,) in degrees."""
        q = _vector6(q_deg)
        r, _, _ = self._geometry(q)
        o = self.joint_offsets_deg
        return Config(
            "righty" if r >= 0.0 else "lefty",
            "epositive" if q[2] + o[2] >= 0.0 else "enegative",
            "wpositive" if q[4] + o[4] >= 0.0 else "wnegative",
        )

    def singularities(self, q_deg: Any, tol: float = SINGULAR_TOL) -> tuple[str, ...]:
        """Names of the singularities ('wrist', 'elbow', 'shoulder') that joints (6,) are at.

        wrist: |sin θ5| < tol (axes 4 and 6 aligned); elbow: |sin θ3| < tol (arm stretched or
        folded); shoulder: wrist centre within tol·(a2 + d4) of the plane through axis 1
        normal to the arm's x (on axis 1 when there is no lateral offset).
        """
        r, s3, s5 = self._geometry(_vector6(q_deg))
        flags = (abs(s5) < tol, abs(s3) < tol, abs(r) < tol * self.reach_mm)
        return tuple(n for n, f in zip(SINGULARITY_NAMES, flags, strict=True) if f)

    # --- Jacobian ---------------------------------------------------------------------------

    def jacobian(
        self, q_deg: Any, frame: Literal["base", "tool"] = "base", tool: Any = None
    ) -> Array:
        """Geometric Jacobian (6, 6) at joints (6,) deg: rows (vx, vy, vz) mm/rad and
        (wx, wy, wz) rad/rad, columns per joint (per radian).

        The velocity is that of the tool centre point (flange centre without ``tool``, a
        tool2flange (4, 4) otherwise), expressed in the base frame or in the tool frame.
        """
        if frame not in ("base", "tool"):
            raise KinematicsError(f"jacobian: frame must be 'base' or 'tool', got {frame!r}")
        q = _vector6(q_deg)
        F = self.flange2base(q)
        T = F if tool is None else F @ check_transform(tool, name="tool")
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

    # --- IK ---------------------------------------------------------------------------------

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
            ref = _batch6(nr, "near")
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
        """Per joint, the value q + 360k (k in -1, 0, 1) inside the limits closest to ref."""
        base = q - 360.0 * np.round(q / 360.0)
        base = np.where(base <= -180.0, base + 360.0, base)  # (-180, 180]
        cand = base[..., None] + np.array([0.0, -360.0, 360.0])  # (N, 8, 6, 3); ties keep base
        lo = self._limits[:, 0, None] - LIMIT_SLACK_DEG
        hi = self._limits[:, 1, None] + LIMIT_SLACK_DEG
        target = np.zeros(6) if ref is None else ref[:, None, :]
        dist = np.abs(cand - np.asarray(target)[..., None])
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
        T = check_transform(flange2base_T, name="flange2base")
        if T.ndim != 2:
            raise KinematicsError("ik: expected one (4, 4) flange2base; use ik_batch for N")
        ref = None if near is None else np.array(_vector6(near, "near"))
        request = ConfigRequest.parse(config)
        same_as = None if ref is None else self.config_of(ref)
        batch = self._ik_batch(T[None], ref)
        if not np.any(batch.reachable[0]):
            raise UnreachableError(self._why_unreachable(T))
        sols: list[IkSolution] = []
        any_config = False
        for k, cfg in enumerate(CONFIGS):
            if not batch.reachable[0, k] or not request.matches(cfg, same_as):
                continue
            any_config = True
            if not batch.valid[0, k]:
                continue
            q = batch.joints_deg[0, k].copy()
            q.flags.writeable = False
            if any(float(np.max(np.abs(q - s.joints_deg))) <= 1e-9 for s in sols):
                continue  # the same joints twice, at a singularity
            names = tuple(
                nm for nm, f in zip(SINGULARITY_NAMES, batch.singular[0, k], strict=True) if f
            )
            if names and raise_on_singularity:
                raise SingularityError(
                    f"{self.name}: pose is at a {names[0]} singularity", kind=names[0]
                )
            sols.append(IkSolution(q, cfg, names))
        if not sols:
            what = "" if request == ConfigRequest() else " with the requested configuration"
            if not any_config:
                raise UnreachableError(f"{self.name}: no solution{what}")
            raise JointLimitError(f"{self.name}: every solution{what} violates a joint limit")
        if ref is not None:
            sols.sort(key=lambda s: float(np.linalg.norm(s.joints_deg - ref)))
        return sols

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


# --- model registry ------------------------------------------------------------------------


def load_model(path: str | Path) -> RobotModel:
    """Load a model from a JSON file (same fields as ``kinematics/models/RX90B.json``)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise KinematicsError(f"model file {p}: {exc}") from None
    if not isinstance(data, dict):
        raise KinematicsError(f"model file {p}: expected a JSON object")
    return RobotModel.from_dict(data)


def list_models() -> list[str]:
    """Names of the bundled models (files in ``kinematics/models/``)."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.json"))


@cache
def _bundled(name: str) -> RobotModel:
    return load_model(MODELS_DIR / f"{name}.json")


def get_model(name: str = DEFAULT_MODEL) -> RobotModel:
    """A bundled model by name (case-insensitive), or a model JSON file by path."""
    if name.endswith(".json"):
        return load_model(name)
    for known in list_models():
        if known.lower() == name.lower():
            return _bundled(known)
    raise UnknownModelError(f"unknown robot model {name!r}; known: {', '.join(list_models())}")
