"""Kinematics: transforms, VAL3 location conventions, Stäubli DGM, IK and Jacobian.

See ``kinematics/CONVENTIONS.md`` for units, frames, joint zero and directions.
"""

from __future__ import annotations

from kinematics.config import CONFIGS, Config, ConfigRequest
from kinematics.errors import (
    JointLimitError,
    KinematicsError,
    SingularityError,
    UnknownModelError,
    UnreachableError,
)
from kinematics.ik import IkBatch, IkSolution
from kinematics.robot import DEFAULT_MODEL, RobotModel, get_model, list_models, load_model
from kinematics.transforms import (
    check_transform,
    concat,
    interpolate,
    invert,
    location_to_transform,
    locations_to_transforms,
    transform_to_location,
    transforms_to_locations,
)

__all__ = [
    "CONFIGS",
    "DEFAULT_MODEL",
    "Config",
    "ConfigRequest",
    "IkBatch",
    "IkSolution",
    "JointLimitError",
    "KinematicsError",
    "RobotModel",
    "SingularityError",
    "UnknownModelError",
    "UnreachableError",
    "check_transform",
    "concat",
    "get_model",
    "interpolate",
    "invert",
    "list_models",
    "load_model",
    "location_to_transform",
    "locations_to_transforms",
    "transform_to_location",
    "transforms_to_locations",
]
