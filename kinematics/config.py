"""VAL3 arm configurations and singularities.

VAL3 configuration: shoulder 'righty' when the wrist centre lies on the forward side of axis 1
(r >= 0 along the arm's x after J1), 'lefty' behind it; elbow 'epositive' when J3 >= 0;
wrist 'wpositive' when J5 >= 0. Singular: the wrist when axes 4 and 6 align (sin θ5 = 0), the
elbow when the arm is stretched or folded (sin θ3 = 0), the shoulder when the wrist centre
is on the plane through axis 1 normal to the arm's x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from kinematics.arm import ArmGeometry, vector6
from kinematics.errors import KinematicsError

#: A configuration is reported singular when |sin J5|, |sin J3| or r / (a2 + d4) is below this.
SINGULAR_TOL = 1e-6

SINGULARITY_NAMES = ("wrist", "elbow", "shoulder")

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


class ConfigMixin(ArmGeometry):
    """The configuration of joints and the singularities they are at."""

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
        q = vector6(q_deg)
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
        r, s3, s5 = self._geometry(vector6(q_deg))
        flags = (abs(s5) < tol, abs(s3) < tol, abs(r) < tol * self.reach_mm)
        return tuple(n for n, f in zip(SINGULARITY_NAMES, flags, strict=True) if f)
