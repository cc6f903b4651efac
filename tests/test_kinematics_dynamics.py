"""The elastic-joint model against closed-form and exact solutions, and its RX90B figures."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kinematics import get_model
from kinematics.dynamics import (
    RX90B,
    ElasticArm,
    axis_matrices,
    first_resonance_hz,
    link_inertia,
    rest_state,
    simulate,
)

READY = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])
PERIOD = 0.004


def _expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a Taylor series (an independent exact
    solution of the linear ODE, no integrator involved)."""
    s = max(0, math.ceil(math.log2(max(np.abs(M).sum(axis=1).max(), 1e-300))) + 1)
    A = M / 2.0**s
    E, term = np.eye(len(M)), np.eye(len(M))
    for k in range(1, 30):
        term = term @ A / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def test_free_elastic_joint_rings_as_the_closed_form() -> None:
    """Servo off, no friction, the gearbox wound up by δ0: the deflection is the damped
    oscillation δ0·e^(−ζωt)(cos ωd t + ζω/ωd sin ωd t) with ω² = k(1/Jm + 1/Jl),
    2ζω = d(1/Jm + 1/Jl), and the momentum Jm θm' + Jl θl' stays zero."""
    p = replace(RX90B, servo_hz=(0.0,) * 6, friction=(0.0,) * 6)
    jl = link_inertia(get_model("RX90B"), READY, p)
    x0 = rest_state(np.zeros(6))
    delta0 = 1e-3
    x0[0] = delta0
    n = 200
    motor, link = simulate(p, jl, np.zeros((n + 1, 6)), period=PERIOD, initial=x0)
    jm, k, d = (np.array(v) for v in (p.motor_inertia, p.stiffness, p.damping))
    inv = 1.0 / jm + 1.0 / jl
    w = np.sqrt(k * inv)
    zeta = d * inv / (2.0 * w)
    wd = w * np.sqrt(1.0 - zeta**2)
    t = PERIOD * np.arange(1, n + 1)[:, None]
    expect = delta0 * np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta * w / wd * np.sin(wd * t))
    # RK4 at 0.5 ms: within 5e-5 of the amplitude over 0.8 s even on the 41 Hz axis 6
    np.testing.assert_allclose(motor - link, expect, atol=5e-5 * delta0)
    # the centre of mass does not move: Jm θm + Jl θl = Jm δ0
    np.testing.assert_allclose(jm * motor + jl * link, np.broadcast_to(jm * delta0, motor.shape))


def test_servoed_elastic_joint_step_matches_the_exact_solution() -> None:
    """The closed loop (servo on the motor encoder) following a setpoint step ramped over
    one cycle, against e^(At) of the augmented linear system: within 1e-5 of the step; the link
    overshoots the motor and both settle on the setpoint (the integral removes friction)."""
    jl = link_inertia(get_model("RX90B"), READY, RX90B)
    A, B = axis_matrices(RX90B, jl)
    step = 0.01  # rad
    n = 750  # 3 s
    r = np.full((n + 1, 6), step)
    r[0] = 0.0
    motor, link = simulate(RX90B, jl, r, period=PERIOD)
    for i in range(6):
        # augmented state (x, r, r'): r' constant step/T in the first cycle, then 0
        M = np.zeros((7, 7))
        M[:5, :5] = A[i]
        M[:5, 5:] = B[i]
        M[5, 6] = 1.0
        z = np.zeros(7)
        z[6] = step / PERIOD
        z = _expm(M * PERIOD) @ z
        z[6] = 0.0
        E = _expm(M * PERIOD)
        exact = [z.copy()]
        for _ in range(n - 1):
            z = E @ z
            exact.append(z.copy())
        ex = np.array(exact)
        np.testing.assert_allclose(motor[:, i], ex[:, 0], atol=1e-5 * step)
        np.testing.assert_allclose(link[:, i], ex[:, 2], atol=1e-5 * step)
    assert np.all(link.max(axis=0)[:3] > motor.max(axis=0)[:3])
    np.testing.assert_allclose(link[-1], step, atol=1e-6)
    np.testing.assert_allclose(motor[-1], step, atol=1e-6)


def test_rx90b_resonances_are_those_of_the_arm_class() -> None:
    """At the cell's ready pose the first resonances of axes 1-3 lie in 10-20 Hz, and the
    closed loops are stable at every pose along the joint range."""
    model = get_model("RX90B")
    jl = link_inertia(model, READY, RX90B)
    f = first_resonance_hz(RX90B, jl)
    assert np.all((f[:3] >= 10.0) & (f[:3] <= 20.0))
    rng = np.random.default_rng(1)
    lim = model.limits
    for q in rng.uniform(lim[:, 0], lim[:, 1], (50, 6)):
        A, _ = axis_matrices(RX90B, link_inertia(model, q, RX90B))
        assert np.all(np.linalg.eigvals(A).real < 0.0)


def test_link_inertia_follows_the_configuration_and_payload() -> None:
    """Axis 1 carries more with the arm stretched out than folded up; a heavier payload
    weighs on every axis."""
    model = get_model("RX90B")
    stretched = link_inertia(model, np.array([0.0, 90.0, 0.0, 0.0, 0.0, 0.0]), RX90B)
    upright = link_inertia(model, np.zeros(6), RX90B)
    assert stretched[0] > 5.0 * upright[0]
    heavy = link_inertia(model, READY, RX90B.with_payload(10.0))
    light = link_inertia(model, READY, RX90B)
    assert np.all(heavy[:5] > light[:5])
    with pytest.raises(ValueError, match="payload"):
        RX90B.with_payload(-1.0)


def test_elastic_arm_runs_the_same_equations_cycle_by_cycle() -> None:
    """ElasticArm (the emulator's) over a joint move equals :func:`simulate` with the
    inertia held; it stands at rest at the start and again once the move has settled."""
    model = get_model("RX90B")
    arm = ElasticArm(model, RX90B, READY, PERIOD)
    assert arm.at_rest()
    target = READY + np.array([5.0, -3.0, 4.0, 10.0, -8.0, 20.0])
    sp = READY + (target - READY) * np.clip(np.arange(1, 301) / 100.0, 0.0, 1.0)[:, None]
    link = []
    for q in sp:
        arm.cycle(q)
        link.append(arm.link_deg)
        if len(link) == 50:
            assert not arm.at_rest()
    for _ in range(1500):
        arm.cycle(target)
    assert arm.at_rest()
    np.testing.assert_allclose(arm.link_deg, target, atol=ElasticArm.REST_DEG)
    # overshoot beyond the target while it settles, on the axes with the large inertias
    link_a = np.array(link)
    assert np.any(np.abs(link_a[:, 0] - READY[0]) > abs(target[0] - READY[0]))
