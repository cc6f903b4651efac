"""``python -m kinematics``: fk, ik, models, negative values and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from kinematics import get_model, location_to_transform
from kinematics.cli import main


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, object, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, (json.loads(out) if out.strip() else None), err


def test_fk_straight_up(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(["fk", "--joints", "0,0,0,0,0,0"], capsys)
    assert code == 0
    assert out == {"x": 0.0, "y": 0.0, "z": 985.0, "rx": 0.0, "ry": 0.0, "rz": 0.0}


@pytest.mark.parametrize(
    "argv",
    [
        ["fk", "--joints=-30,45,0,0,90,0"],
        ["fk", "--joints", "-30,45,0,0,90,0"],
        ["fk", "--model", "RX90B", "--joints=-30, 45, 0, 0, 90, 0"],
    ],
)
def test_fk_negative_values(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(argv, capsys)
    assert code == 0
    assert isinstance(out, dict)
    T = get_model().flange2base([-30, 45, 0, 0, 90, 0])
    np.testing.assert_allclose([out["x"], out["y"], out["z"]], T[:3, 3], atol=1e-8)
    assert out["y"] < 0  # J1 = -30 turns clockwise seen from above


def test_fk_with_tool_and_frame(capsys: pytest.CaptureFixture[str]) -> None:
    # Flange pointing down at (450, 0, 365); a 100 mm tool along flange z reaches z = 265;
    # seen from a frame 200 mm above the base origin, z = 65.
    argv = ["fk", "--joints", "0,0,90,0,90,0", "--tool", "0,0,100,0,0,0"]
    code, out, _ = run([*argv, "--frame", "0,0,200,0,0,0"], capsys)
    assert code == 0 and isinstance(out, dict)
    assert (out["x"], out["y"], out["z"]) == (450.0, 0.0, 65.0)


def test_ik_round_trip_with_tool_and_frame(capsys: pytest.CaptureFixture[str]) -> None:
    q = [-20.0, 30.0, 70.0, 15.0, 50.0, -40.0]
    tool, frame = "10,-5,120,0,30,0", "300,-100,50,0,0,45"
    code, loc, _ = run(
        ["fk", "--joints", ",".join(map(str, q)), "--tool", tool, "--frame", frame], capsys
    )
    assert code == 0 and isinstance(loc, dict)
    text = ",".join(str(loc[k]) for k in ("x", "y", "z", "rx", "ry", "rz"))
    code, out, _ = run(
        [
            "ik",
            "--location",
            text,
            "--tool",
            tool,
            "--frame",
            frame,
            "--near",
            "-20,30,70,15,50,-40",
        ],
        capsys,
    )
    assert code == 0 and isinstance(out, dict)
    first = out["solutions"][0]
    np.testing.assert_allclose(first["joints"], q, atol=1e-6)  # printed to 1e-9 mm/deg
    assert first["config"] == {"shoulder": "righty", "elbow": "epositive", "wrist": "wpositive"}
    code, only, _ = run(
        ["ik", "--location", text, "--tool", tool, "--frame", frame, "--config", "enegative"],
        capsys,
    )
    assert code == 0 and isinstance(only, dict)
    assert all(s["config"]["elbow"] == "enegative" for s in only["solutions"])


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["ik", "--location", "5000,0,0,0,0,0"], "unreachable"),
        (["fk", "--model", "KR16", "--joints", "0,0,0,0,0,0"], "unknown robot model"),
        (["fk", "--joints", "0,0,0"], "6 comma-separated"),
        (["fk", "--joints", "0,0,0,0,nan,0"], "NaN"),
        (["fk", "--joints", "a,b,c,d,e,f"], "not a number"),
        (["fk"], "required"),
        (["ik", "--location", "500,0,300,0,180,0", "--config", "up"], "unknown value"),
    ],
)
def test_errors_are_one_line_exit_2(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(argv, capsys)
    assert code == 2 and out is None
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_models_lists_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(["models", "--json"], capsys)
    assert code == 0 and isinstance(out, list)
    by_name = {m["name"]: m for m in out}
    assert by_name["RX160"]["shoulder_offset_mm"] == 150.0
    assert by_name["RX90B"]["joint_limits_deg"][0] == [-160.0, 160.0]


def test_models_table_one_row_per_model(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["models"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = {line.split()[0]: line.split() for line in lines[1:-1]}
    assert lines[0].split()[0] == "model" and "--json" in lines[-1]
    assert rows["RX160"][1] == "150" and rows["RX90B"][-6] == "-160..160"


def test_module_entry_point() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "kinematics", "ik", "--location=500,0,300,0,180,0"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    sols = json.loads(proc.stdout)["solutions"]
    T = location_to_transform([500, 0, 300, 0, 180, 0])
    for s in sols:
        np.testing.assert_allclose(get_model().flange2base(s["joints"]), T, atol=1e-6)
