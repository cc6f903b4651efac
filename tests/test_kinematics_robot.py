"""Stäubli model data: the bundled models, encoder offsets as data, bad model files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinematics import (
    KinematicsError,
    RobotModel,
    UnknownModelError,
    get_model,
    list_models,
    load_model,
)

MODELS = ["RX90B", "RX130B", "RX160", "TX90"]


def test_models_are_listed_with_limits() -> None:
    assert set(MODELS) <= set(list_models())
    m = get_model("tx90")  # case-insensitive
    assert m.limits.shape == (6, 2)
    assert m.joint_limits_deg[1] == (-130.0, 147.5)


def test_encoder_offset_is_data(tmp_path: Path) -> None:
    data = get_model("RX90B").to_dict()
    data["name"] = "RX90B-cal"
    data["joint_offsets_deg"] = [0, 0.5, 0, 0, 0, 0]
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(data))
    m = load_model(path)
    ref = get_model("RX90B")
    q = [10, 20, 30, 40, 50, 60]
    np.testing.assert_allclose(m.flange2base(q), ref.flange2base([10, 20.5, 30, 40, 50, 60]))
    sols = m.ik(m.flange2base(q), near=q)
    np.testing.assert_allclose(sols[0].joints_deg, q, atol=1e-9)
    assert get_model(str(path)).name == "RX90B-cal"


def test_bad_model_data() -> None:
    with pytest.raises(UnknownModelError):
        get_model("KR16")
    data = get_model().to_dict()
    data["joint_limits_deg"] = data["joint_limits_deg"][:5]
    with pytest.raises(KinematicsError):
        RobotModel.from_dict(data)
    with pytest.raises(KinematicsError):
        RobotModel.from_dict({"name": "x"})
