"""Camera emulator throughput: detector and renderer frames per second.

Baselines measured in the same run: the detector against reading the same frames' bytes
once (numpy sum over a uint64 view: the memory-read floor of any detector), the seam stage
(detect minus stripe, µs per frame) against the stripe stage, the renderer against drawing
one frame of fresh Gaussian noise (what a naive renderer pays before it draws any stripe).
detect() and stripe() have absolute targets (frames/s): they are timed at the machine's full
speed (:mod:`bench.pace`) and carry the speed they were measured at.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from bench.common import Result, result, time_per_call
from bench.pace import time_at_full_speed
from sensorsocket.camera import StripeRenderer
from sensorsocket.detector import DetectorConfig, SeamDetector
from sensorsocket.scene import Joint, Scene, fixed_pose

N_FRAMES = 32
T = TypeVar("T")


def _frames(scene: Scene, rng: np.random.Generator) -> list[NDArray[np.uint8]]:
    renderer = StripeRenderer(scene, rng=rng)
    out = []
    for _ in range(N_FRAMES):
        pose = scene.sensor_over_seam(
            0.0, seam_y_mm=rng.uniform(-3, 3), seam_z_mm=rng.uniform(-2, 2)
        )
        out.append(renderer.render(0, np.zeros(512), fixed_pose(pose))[0])
    return out


def _cycle(fn: Callable[[T], object], items: Sequence[T]) -> Callable[[], object]:
    """A call that applies fn to the next item, round robin (defeats result caching)."""
    state = {"i": 0}

    def call() -> object:
        i = state["i"]
        state["i"] = (i + 1) % len(items)
        return fn(items[i])

    return call


def run() -> list[Result]:
    rng = np.random.default_rng(2024)
    results: list[Result] = []
    for joint in (Joint.butt(0.4), Joint.fillet(), Joint.lap(1.0)):
        scene = Scene(joint)
        frames = _frames(scene, rng)
        det = SeamDetector(config=DetectorConfig(joint=joint.kind))
        words = [f.view(np.uint64) for f in frames]
        t_read = time_per_call(_cycle(np.sum, words))
        detect = time_at_full_speed(_cycle(det.detect, frames))
        stripe = time_at_full_speed(_cycle(det.stripe, frames))
        t_det, t_stripe = detect.seconds, stripe.seconds
        name = joint.kind.value
        for fn, timing in (("detect", detect), ("stripe", stripe)):
            results.append(
                result(
                    f"sensor.{fn}.{name}",
                    1 / timing.seconds,
                    "frames/s",
                    "memory read",
                    1 / t_read,
                    machine_speed=timing.speed,
                )
            )
        # the seam stage alone (profile, outliers, feature): detect minus its stripe stage
        results.append(
            result(
                f"sensor.seam_stage.{name}",
                max(t_det - t_stripe, 0.0) * 1e6,
                "us/frame",
                "stripe stage",
                t_stripe * 1e6,
            )
        )
    scene = Scene(Joint.butt(0.4))
    renderer = StripeRenderer(scene, rng=rng)
    pose = fixed_pose(scene.sensor_over_seam(0.0, seam_y_mm=1.0))
    times = np.arange(512) * 3.5e-3 / 512
    t_render = time_per_call(lambda: renderer.render(0, times, pose))
    t_noise = time_per_call(lambda: rng.standard_normal((512, 256), dtype=np.float32))
    results.append(
        result("sensor.render.butt", 1 / t_render, "frames/s", "fresh frame noise", 1 / t_noise)
    )
    return results
