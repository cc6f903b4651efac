"""Stäubli 6R arms: the model data and its registry.

:class:`RobotModel` is one arm (lengths, joint limits, encoder offsets; data in
``kinematics/models/*.json``) with the pieces that work on it: the DGM, paper eq. 3
(:mod:`kinematics.dgm`), the analytic IK (:mod:`kinematics.ik`), the Jacobian
(:mod:`kinematics.jacobian`), configurations and singularities (:mod:`kinematics.config`).
See ``kinematics/CONVENTIONS.md`` for units, frames, joint zero and directions.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from kinematics.arm import LIMIT_SLACK_DEG, BoolArray, vector6
from kinematics.errors import JointLimitError, KinematicsError, UnknownModelError
from kinematics.ik import IkMixin
from kinematics.jacobian import JacobianMixin
from kinematics.types import FloatArray

MODELS_DIR = Path(__file__).with_name("models")
DEFAULT_MODEL = "RX90B"


@dataclass(frozen=True)
class RobotModel(IkMixin, JacobianMixin):
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
    _limits: FloatArray = field(init=False, repr=False, compare=False)
    _offsets: FloatArray = field(init=False, repr=False, compare=False)
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
    def limits(self) -> FloatArray:
        """Joint limits (6, 2) in degrees, [lower, upper] (read-only array)."""
        return self._limits

    # --- limits -----------------------------------------------------------------------------

    def within_limits(self, q_deg: Any) -> bool | BoolArray:
        """True where all joints of (6,) or (N, 6) lie inside the limits."""
        arr = np.asarray(q_deg, dtype=np.float64)
        inside = (arr >= self._limits[:, 0] - LIMIT_SLACK_DEG) & (
            arr <= self._limits[:, 1] + LIMIT_SLACK_DEG
        )
        res = np.all(inside, axis=-1)
        return bool(res) if res.ndim == 0 else res

    def check_joints(self, q_deg: Any) -> FloatArray:
        """Validate joints (6,): finite and inside the limits, else JointLimitError."""
        q = np.array(vector6(q_deg))
        for i in range(6):
            lo, hi = self.joint_limits_deg[i]
            if not lo - LIMIT_SLACK_DEG <= q[i] <= hi + LIMIT_SLACK_DEG:
                raise JointLimitError(
                    f"{self.name}: J{i + 1} = {q[i]:.6g} deg outside [{lo:g}, {hi:g}]"
                )
        return q


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
