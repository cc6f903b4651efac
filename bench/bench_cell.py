"""Benchmarks of the emulated cell: the simulated 10 s ΔT experiment end to end.

Figures, each with a baseline from the same run:

- wall time of the whole simulated experiment (cell, sockets, rendering, detection,
  matching, estimation), against the simulated duration (real time would take that long);
- the per-frame cost of the chain, against the camera emulator alone (render + detect);
- the estimator on the recorded data, against the bare estimator on synthetic data of the
  same size, and a numpy pass (upsampling both signals) over the same samples.
"""

from __future__ import annotations

import time

import numpy as np

from bench.common import Result, result, time_per_call
from cell.cell import EmulatedCell
from sync.delay import estimate_delay, simulate_sine_experiment, upsample
from sync.experiment import ExperimentSettings, analyse, run_delay_experiment


def run() -> list[Result]:
    settings = ExperimentSettings(duration_s=10.0)
    with EmulatedCell(clock="sim", seed=1) as cell:
        t0 = time.perf_counter()
        res = run_delay_experiment(cell.robot_address, cell.sensor_address, settings)
        wall = time.perf_counter() - t0
        frames = cell.sensor.frames
        sensor = cell.sensor
        t_acq = [1000.0]

        def acquire() -> None:
            t_acq[0] += 0.004
            sensor.acquire(t_acq[0])

        per_frame_camera = time_per_call(acquire, min_time=0.3, repeat=3)
    data = res.data
    est_time = time_per_call(lambda: analyse(data, settings), min_time=0.3, repeat=3)
    syn = simulate_sine_experiment(np.random.default_rng(0), duration_s=10.4)
    bare = time_per_call(
        lambda: estimate_delay(syn.t_robot, syn.y_robot, syn.t_trigger, syn.y_sensor),
        min_time=0.3,
        repeat=3,
    )

    def numpy_pass() -> None:
        upsample(data.t_robot, data.y_robot)
        upsample(data.t_trigger, data.y_sensor)

    npass = time_per_call(numpy_pass, min_time=0.3, repeat=3)
    return [
        result(
            "ΔT experiment 10 s, simulated cell, wall (sync.experiment.run_delay_experiment)",
            wall,
            "s",
            "simulated duration",
            settings.total_s,
        ),
        result(
            "cell chain per frame: trigger, render, detect, match (same run)",
            wall / max(frames, 1) * 1e3,
            "ms",
            "camera acquire+detect alone",
            per_frame_camera * 1e3,
        ),
        result(
            "ΔT analysis of the cell's data (sync.experiment.analyse)",
            est_time * 1e3,
            "ms",
            "bare estimator, synthetic",
            bare * 1e3,
        ),
        result(
            "ΔT analysis of the cell's data (sync.experiment.analyse) ",
            est_time * 1e3,
            "ms",
            "numpy upsample pass",
            npass * 1e3,
        ),
    ]
