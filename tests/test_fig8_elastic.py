"""Fig. 8 on the elastic arm: what the ΔT fit reads, and why it falls rather than rises.

The sweep's y^R comes from the joint log (the MOTOR side, delayed by the encoder latency), its
y^S from the camera (the LINK side, the truth). Eq. 4-7 find the ΔT at which the joint log
shows what the camera saw, so a link that lags its motor by δ(f) shows up as ΔT − δ(f). A
passive gearbox can only make the link lag: the link follows the motor through
(k + jωd) / (k − Jl ω² + jωd), whose phase is negative at every ω > 0. These tests pin that
reading on the simulated clock (deterministic), so a model change that breaks it is seen.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cell.cell import READY_JOINTS, EmulatedCell
from kinematics.dynamics import RX90B, link_inertia
from kinematics.robot import get_model
from kinematics.types import FloatArray
from sync.experiment import ExperimentSettings, run_delay_experiment


def _sine_phase(t: FloatArray, y: FloatArray, f: float) -> tuple[float, float]:
    """(amplitude, phase rad) of the least-squares a·sin(ωt + φ) + c."""
    w = 2.0 * math.pi * f * t
    basis = np.column_stack([np.sin(w), np.cos(w), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return math.hypot(a, b), math.atan2(b, a)


def _run(dynamics: str, f: float) -> tuple[float, float, float]:
    """(ΔT fitted s, link-behind-motor lag s, link/motor amplitude ratio) of the sensor
    origin's lateral motion for the 2 mm sine at ``f`` Hz, 4 s, seed 0."""
    cell = EmulatedCell(clock="sim", seed=0, dynamics=dynamics)
    robot = cell.robot
    rows: list[tuple[float, FloatArray, FloatArray]] = []

    def record(t: float, q_sp: FloatArray, q_m: FloatArray) -> None:
        arm = robot._arm  # the undelayed motor side (q_m is it 2.8 ms late)
        motor = q_sp.copy() if arm is None else arm.motor_deg.copy()
        rows.append((t, motor, robot.true_joints().copy()))

    robot.cycle_hooks.append(record)
    s = ExperimentSettings(frequency_hz=f, duration_s=4.0)
    with cell:
        r = run_delay_experiment(cell.robot_address, cell.sensor_address, s, require_interior=False)
    t = np.array([row[0] for row in rows])
    full = (t >= r.data.t_start + s.rest_s + s.ramp + 0.2) & (
        t <= r.data.t_start + s.rest_s + s.duration_s - s.ramp - 0.2
    )
    fit = []
    for side in (1, 2):
        q = np.array([row[side] for row in rows])
        pose = robot.model.flange2base_batch(q) @ cell.nominal_sensor2flange
        y = (pose[:, :3, 3] - pose[0, :3, 3]) @ pose[0, :3, 1]
        fit.append(_sine_phase(t[full], y[full], f))
    (a_m, p_m), (a_l, p_l) = fit
    lag = ((p_m - p_l + math.pi) % (2.0 * math.pi) - math.pi) / (2.0 * math.pi * f)
    return r.estimate.delta_t_s, lag, a_l / a_m


def test_a_passive_gearbox_makes_the_link_lag_at_every_frequency() -> None:
    jl = link_inertia(get_model("RX90B"), np.array(READY_JOINTS), RX90B)
    k, d = np.array(RX90B.stiffness), np.array(RX90B.damping)
    for w in 2.0 * math.pi * np.geomspace(0.1, 200.0, 400):
        h = (k + 1j * w * d) / (k - jl * w * w + 1j * w * d)
        assert np.all(np.angle(h) < 0.0)


@pytest.mark.slow
def test_fig8_elastic_falls_by_the_links_lag_behind_the_motor() -> None:
    rigid = {f: _run("off", f) for f in (2.0, 10.0)}
    elastic = {f: _run("elastic", f) for f in (2.0, 10.0)}
    # the rigid arm: no lag, ΔT at the cell's 4.9 ms
    for f in (2.0, 10.0):
        assert rigid[f][1] == pytest.approx(0.0, abs=1e-9)
        assert rigid[f][0] == pytest.approx(4.9e-3, abs=0.05e-3)
    # flat at 2 Hz (the link within 0.05 ms of the motor) ...
    assert abs(elastic[2.0][0] - rigid[2.0][0]) < 0.05e-3
    # ... falling at 10 Hz, by the link's lag behind the motor (and not by its overshoot:
    # the link moves more than the motor, yet the fit reads only the phase)
    dt10, lag10, ratio10 = elastic[10.0]
    assert lag10 > 0.5e-3 and ratio10 > 1.5
    assert rigid[10.0][0] - dt10 > 0.5e-3
    for f in (2.0, 10.0):
        dt, lag, _ = elastic[f]
        assert dt == pytest.approx(rigid[f][0] - lag, abs=0.03e-3)
