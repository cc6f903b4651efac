"""Errors raised at the public edges of the kinematics package.

All are ``ValueError`` subclasses, so a caller that only knows "bad input" can catch one type.
"""

from __future__ import annotations


class KinematicsError(ValueError):
    """Base class: bad shape, NaN, non-rigid transform, bad argument."""


class UnknownModelError(KinematicsError):
    """No robot model of that name (see ``kinematics.robot.list_models()``)."""


class UnreachableError(KinematicsError):
    """The pose cannot be reached by the arm's geometry (out of reach or too close to axis 1)."""


class JointLimitError(KinematicsError):
    """Joints outside the model's limits, or every IK solution violates a limit."""


class SingularityError(KinematicsError):
    """The configuration is at a singularity; ``kind`` is 'wrist', 'elbow' or 'shoulder'."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind
