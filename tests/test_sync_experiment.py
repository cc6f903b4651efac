"""The ΔT experiment's pure parts and its command line (no cell needed except --emulate)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sync.__main__ import main
from sync.delay import simulate_sine_experiment
from sync.experiment import ExperimentData, ExperimentSettings, analyse, sine_path, write_json


def test_sine_path_starts_and_ends_at_rest_on_the_4ms_grid() -> None:
    s = ExperimentSettings(frequency_hz=1.5, amplitude_mm=2.0, duration_s=4.0, rest_s=0.2)
    t, y = sine_path(s)
    assert t[0] == 0.0 and np.allclose(np.diff(t), 0.004)
    assert t[-1] >= s.total_s - 1e-9
    assert y[0] == 0.0 and abs(y[-1]) < 1e-12 and np.max(np.abs(y)) <= 2.0 + 1e-12
    mid = (t > 0.2 + s.ramp) & (t < 0.2 + 4.0 - s.ramp)
    np.testing.assert_allclose(y[mid], 2.0 * np.sin(2 * np.pi * 1.5 * (t[mid] - 0.2)))
    v = np.diff(y) / 0.004
    assert abs(v[0]) < 1e-9 and np.max(np.abs(np.diff(v))) / 0.004 < 2 * 2.0 * (3 * np.pi) ** 2


def test_analyse_finds_the_delay_of_synthetic_data() -> None:
    syn = simulate_sine_experiment(np.random.default_rng(4), duration_s=10.0, delay_s=4.9e-3)
    data = ExperimentData(syn.t_robot, syn.y_robot, syn.t_trigger, syn.y_sensor, 0.0, "RX90B")
    r = analyse(data, ExperimentSettings())
    assert abs(r.estimate.delta_t_s - syn.expected_delta_t_s) < 0.06e-3
    j = r.to_json()
    assert {"delta_t_ms", "residual_max_um", "residual_rms_um", "mse_curve"} <= set(j)
    assert len(j["mse_curve"]["delta_t_ms"]) == len(j["mse_curve"]["mse_um2"]) == 101


def test_write_json_is_atomic_and_valid(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "r.json"
    write_json(path, {"a": 1.5, "nan": math.nan})
    assert json.loads(path.read_text())["a"] == 1.5
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]  # no temporary left


def test_cli_curvature_and_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["curvature", "--amplitude", "2", "--frequency", "5", "--speed", "250"]) == 0
    assert "31.66 mm" in capsys.readouterr().out
    assert main(["delay"]) == 2  # neither an endpoint nor --emulate
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error" in err
    done = subprocess.run(
        [sys.executable, "-m", "sync", "delay", "--robot", "nohost"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and "HOST:PORT" in done.stderr and "Traceback" not in done.stderr


def test_cli_emulate_writes_json_with_the_truth(tmp_path: Path) -> None:
    out = tmp_path / "d.json"
    argv = ["delay", "--emulate", "-q", "--duration", "2", "--json", str(out)]
    assert main([*argv, "--encoder-latency-ms", "3.8"]) == 0
    j = json.loads(out.read_text())
    assert j["true_delta_t_ms"] == pytest.approx(5.9)
    assert abs(j["delta_t_ms"] - 5.9) < 0.15
