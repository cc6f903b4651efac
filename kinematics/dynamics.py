"""Elastic-joint dynamics of a Stäubli arm (numpy, pure): why a real tool lags and overshoots.

Per axis i, on the joint side (angles in rad; the motor angle divided by the gear ratio,
inertias reflected through the gear ratio squared):

    Jm θm'' = τ − k (θm − θl) − d (θm' − θl') − b θm'        motor + gearbox input
    Jl(q) θl'' = k (θm − θl) + d (θm' − θl')                 link side
    τ = Kp (r − θm) + Kd (r' − θm') + Ki ∫(r − θm)            servo on the MOTOR encoder

``r`` is the controller's setpoint, ramped linearly across each 4 ms cycle (the drive
interpolates between setpoints), ``r'`` its velocity (the velocity feedforward ``Kd·r'``).
The servo sees only θm, as a CS8 drive sees only its motor encoder; the tool goes where θl
puts it. ``Jl(q)`` is the inertia of everything beyond the joint about its axis at the
current configuration (lumped masses, :func:`link_inertia`), so along a path the dynamics
change, as Hakvoort's RX90 model does. Left out, on purpose: the coupling between axes
(cross inertia, Coriolis) and gravity (a static sag): the first would need the full
rigid-body model, the second only moves where the arm stands still.

The parameters (:data:`RX90B`) are estimates, not identified values: Stäubli publishes the
RX90B's mass (about 111 kg), reach (985 mm) and payload (6 kg nominal, 12 kg max) but no
stiffness, motor inertia or servo tuning. Each value is chosen so the arm behaves like the
arm class does in the literature: first resonances between 10 and 20 Hz on the main axes
(Hakvoort et al. on the same RX90; most 6-axis arms of this size), reflected motor inertia
of the order of the link inertia, servo bandwidths a little below the first resonance.

Integration: fixed-step RK4 at ``substeps`` per cycle (default 8: 0.5 ms), vectorised over
the axes and over any leading batch dimensions (:func:`simulate` runs many inputs at once,
which is how the ILC's lifted model is built).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from kinematics.types import FloatArray

__all__ = [
    "DYNAMICS",
    "RX90B",
    "ElasticArm",
    "ElasticParams",
    "axis_matrices",
    "dynamics_named",
    "first_resonance_hz",
    "link_inertia",
    "rest_state",
    "simulate",
]

Six = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class ElasticParams:
    """One arm's elastic-joint parameters, per axis (joint side). SI units."""

    #: reflected motor + gearbox input inertia (kg m²)
    motor_inertia: Six
    #: gearbox stiffness (N m/rad)
    stiffness: Six
    #: gearbox damping (N m s/rad)
    damping: Six
    #: viscous friction on the motor side (N m s/rad): what the servo's integral removes
    friction: Six
    #: own inertia of each moving part about its axis, beyond the lumped masses (kg m²)
    own_inertia: Six
    #: closed-loop servo bandwidth (Hz) and damping ratio per axis, tuned for servo_inertia
    servo_hz: Six
    servo_zeta: float
    #: integral corner as a fraction of the bandwidth
    servo_integral: float
    #: the total (motor + link) inertia each servo was tuned for (kg m²): the drive's tuning
    #: is fixed, it does not follow the payload or the pose
    servo_inertia: Six
    #: lumped masses (kg): upper arm (at its middle), forearm (at its middle), wrist (at
    #: the wrist centre), payload at ``payload_offset_mm`` along the flange's z axis
    upper_arm_kg: float
    forearm_kg: float
    wrist_kg: float
    payload_kg: float
    payload_offset_mm: float

    def with_payload(self, kg: float) -> ElasticParams:
        """The same arm with another payload (kg, >= 0)."""
        if not (math.isfinite(kg) and 0.0 <= kg <= 100.0):
            raise ValueError(f"payload must be in [0, 100] kg, got {kg}")
        return replace(self, payload_kg=kg)

    def gains(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(Kp N m/rad, Kd N m s/rad, Ki N m/(rad s)) per axis (6,): a PD with velocity
        feedforward placing the rigid loop's poles at ``servo_hz`` with ``servo_zeta``,
        plus an integral at ``servo_integral`` of the bandwidth."""
        w = 2.0 * math.pi * np.array(self.servo_hz)
        jt = np.array(self.servo_inertia)
        kp = jt * w * w
        kd = 2.0 * self.servo_zeta * jt * w
        ki = kp * w * self.servo_integral
        return kp, kd, ki


#: Estimated RX90B parameters (see the module docstring for what is published and what is
#: not). At the cell's ready pose (0, 30, 100, 0, 50, 0) with the 5 kg laser and sensor head:
#: two-mass resonances (servo off, :func:`first_resonance_hz`) 19.5-19.6 Hz on axes 1-3 and
#: 21-41 Hz on the wrist; the link against a locked motor, sqrt(k/Jl), 14 Hz on axes 1-3
#: (so the link swings 15 % more than the motor at 5 Hz: the paper's own arm did better,
#: about 2 % by its 40 µm residual at 5 Hz and 2 mm, which would need ~35 Hz; the 10-20 Hz
#: class figure is kept). The reflected motor inertia is about the link inertia (gear
#: ratios of 100 or more). Gearbox damping 5 % of critical, d = 2·0.05·sqrt(k·JmJl/(Jm+Jl))
#: (lightly damped, as cycloidal and harmonic gearboxes are). Servos: 10 Hz on axes 1-3,
#: 9-10 Hz on the wrist, damping ratio 0.8, tuned for the ready pose's inertia; with the
#: servo closed the dominant mode of axes 1-3 is about 13 Hz at a damping ratio of 0.36, and
#: a 5 Hz setpoint sine is followed with an error of about half its amplitude (velocity
#: feedforward only: what an ILC has to learn). The masses add up with the base and the
#: motors to the published 111 kg.
RX90B = ElasticParams(
    motor_inertia=(7.0, 8.0, 3.6, 0.25, 0.25, 0.08),
    stiffness=(5.0e4, 6.0e4, 2.7e4, 2.0e3, 2.0e3, 6.0e2),
    damping=(40.9, 48.6, 21.9, 1.4, 1.5, 0.2),
    friction=(2.0, 2.0, 1.0, 0.2, 0.2, 0.05),
    own_inertia=(1.0, 0.6, 0.25, 0.05, 0.05, 0.01),
    servo_hz=(10.0, 10.0, 10.0, 9.0, 9.0, 10.0),
    servo_zeta=0.8,
    servo_integral=0.2,
    servo_inertia=(13.4, 15.8, 7.1, 0.4, 0.47, 0.09),
    upper_arm_kg=22.0,
    forearm_kg=14.0,
    wrist_kg=4.0,
    payload_kg=5.0,
    payload_offset_mm=100.0,
)


#: The emulator's dynamics by name: ``off`` (a rigid arm, exactly at its setpoints) or
#: ``elastic`` (:class:`ElasticArm` with the model's parameters).
DYNAMICS = ("off", "elastic")
_PARAMS = {"RX90B": RX90B}


def dynamics_named(name: str, model: str) -> ElasticParams | None:
    """The parameters of dynamics ``name`` (:data:`DYNAMICS`) for robot ``model``; None for
    ``off``. ValueError for an unknown name or a model without elastic parameters."""
    if name not in DYNAMICS:
        raise ValueError(f"dynamics must be one of {', '.join(DYNAMICS)}, got {name!r}")
    if name == "off":
        return None
    if model not in _PARAMS:
        raise ValueError(
            f"no elastic-joint parameters for the {model}: --dynamics elastic has them for "
            + ", ".join(_PARAMS)
        )
    return _PARAMS[model]


def link_inertia(model: Any, q_deg: FloatArray, params: ElasticParams) -> FloatArray:
    """Inertia (6,) kg m² of everything beyond each joint about its axis at joints (6,) deg:
    the lumped masses at their distances from the axis (``model.joint_axes``), plus each
    part's own inertia. ``model`` is a :class:`~kinematics.robot.RobotModel`."""
    axes, points, F = model.joint_axes(q_deg)
    elbow = points[2]
    wrist = points[3]
    payload = F[:3, 3] + F[:3, 2] * params.payload_offset_mm
    bodies = (
        (0.5 * (points[1] + elbow), params.upper_arm_kg, 2),  # moved by axes 1-2
        (0.5 * (elbow + wrist), params.forearm_kg, 3),  # axes 1-3
        (wrist, params.wrist_kg, 3),
        (payload, params.payload_kg, 6),  # every axis
    )
    out = np.array(params.own_inertia, dtype=np.float64)
    for p, m, last in bodies:
        r = np.cross(axes[:last], (p - points[:last]) * 1e-3)  # m: distance to each axis
        out[:last] += m * np.einsum("ij,ij->i", r, r)
    return out


def axis_matrices(params: ElasticParams, jl: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Continuous state space of the six closed loops at link inertias ``jl`` (6,): ``A``
    (6, 5, 5) and ``B`` (6, 5, 2) for the state (θm, θm', θl, θl', ∫e) and the input
    (r, r'). For analysis and tests; :func:`simulate` integrates the same equations."""
    kp, kd, ki = params.gains()
    jm = np.array(params.motor_inertia)
    k, d, b = (np.array(v) for v in (params.stiffness, params.damping, params.friction))
    A = np.zeros((6, 5, 5))
    B = np.zeros((6, 5, 2))
    A[:, 0, 1] = 1.0
    A[:, 1, 0] = (-kp - k) / jm
    A[:, 1, 1] = (-kd - d - b) / jm
    A[:, 1, 2] = k / jm
    A[:, 1, 3] = d / jm
    A[:, 1, 4] = ki / jm
    A[:, 2, 3] = 1.0
    A[:, 3, 0] = k / jl
    A[:, 3, 1] = d / jl
    A[:, 3, 2] = -k / jl
    A[:, 3, 3] = -d / jl
    A[:, 4, 0] = -1.0
    B[:, 1, 0] = kp / jm
    B[:, 1, 1] = kd / jm
    B[:, 4, 0] = 1.0
    return A, B


def first_resonance_hz(params: ElasticParams, jl: FloatArray) -> FloatArray:
    """Undamped two-mass resonance (6,) Hz of each axis at link inertias ``jl`` (6,) with
    the servo off: sqrt(k (1/Jm + 1/Jl)) / 2π (the servo shifts it a little)."""
    jm = np.array(params.motor_inertia)
    k = np.array(params.stiffness)
    out: FloatArray = np.sqrt(k * (1.0 / jm + 1.0 / jl)) / (2.0 * math.pi)
    return out


class _Coefficients:
    """The per-axis constants of the equations, as arrays (6,)."""

    def __init__(self, params: ElasticParams) -> None:
        self.kp, self.kd, self.ki = params.gains()
        self.jm = np.array(params.motor_inertia, dtype=np.float64)
        self.k = np.array(params.stiffness, dtype=np.float64)
        self.d = np.array(params.damping, dtype=np.float64)
        self.b = np.array(params.friction, dtype=np.float64)

    def deriv(self, x: FloatArray, r: FloatArray, rd: FloatArray, jl: FloatArray) -> FloatArray:
        """dx/dt of states x (..., 5, 6) at setpoint r, r' (..., 6), link inertia jl."""
        th_m, w_m, th_l, w_l, z = (x[..., i, :] for i in range(5))
        e = r - th_m
        tau = self.kp * e + self.kd * (rd - w_m) + self.ki * z
        spring = self.k * (th_m - th_l) + self.d * (w_m - w_l)
        return np.stack([w_m, (tau - spring - self.b * w_m) / self.jm, w_l, spring / jl, e], -2)

    def cycle(
        self, x: FloatArray, r0: FloatArray, r1: FloatArray, jl: FloatArray, period: float, n: int
    ) -> FloatArray:
        """States after one cycle of ``period`` s in ``n`` RK4 substeps, the setpoint ramped
        from r0 to r1 (..., 6) rad."""
        h = period / n
        rd = (r1 - r0) / period
        for i in range(n):
            ra = r0 + rd * (i * h)
            rm = ra + rd * (0.5 * h)
            rb = ra + rd * h
            k1 = self.deriv(x, ra, rd, jl)
            k2 = self.deriv(x + 0.5 * h * k1, rm, rd, jl)
            k3 = self.deriv(x + 0.5 * h * k2, rm, rd, jl)
            k4 = self.deriv(x + h * k3, rb, rd, jl)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return x


def rest_state(q_rad: FloatArray) -> FloatArray:
    """The state (..., 5, 6) of an arm standing at ``q_rad`` (..., 6): motor = link = q."""
    q = np.asarray(q_rad, dtype=np.float64)
    x = np.zeros((*q.shape[:-1], 5, 6))
    x[..., 0, :] = q
    x[..., 2, :] = q
    return x


def simulate(
    params: ElasticParams,
    jl: FloatArray,
    setpoints_rad: FloatArray,
    *,
    period: float,
    substeps: int = 8,
    initial: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Run the arm over setpoints (..., N + 1, 6) rad, starting at rest at the first one
    (or in the state ``initial`` (..., 5, 6): θm, θm', θl, θl', ∫e), with link inertias
    ``jl`` (N, 6) per cycle (or (6,) throughout; or broadcastable to (..., N, 6): one arm
    of its own inertias per leading index). Returns (motor, link) (..., N, 6) rad at the end
    of each of the N cycles."""
    r = np.asarray(setpoints_rad, dtype=np.float64)
    n = r.shape[-2] - 1
    jl_all = np.asarray(jl, dtype=np.float64)
    jl_all = np.broadcast_to(jl_all, (*jl_all.shape[:-2], n, 6))
    c = _Coefficients(params)
    x = rest_state(r[..., 0, :]) if initial is None else np.array(initial, dtype=np.float64)
    motor = np.empty((*r.shape[:-2], n, 6))
    link = np.empty_like(motor)
    for k in range(n):
        x = c.cycle(x, r[..., k, :], r[..., k + 1, :], jl_all[..., k, :], period, substeps)
        motor[..., k, :] = x[..., 0, :]
        link[..., k, :] = x[..., 2, :]
    return motor, link


class ElasticArm:
    """The six elastic axes of ``model`` (a :class:`~kinematics.robot.RobotModel`) standing
    at ``q0_deg`` (6,); :meth:`cycle` advances one controller cycle of ``period`` s."""

    #: at rest: link within this of the setpoint (deg; ~1 µm at the RX90's reach) ...
    REST_DEG = 1e-4
    #: ... and no axis faster than this (deg/s)
    REST_DEG_S = 1e-3

    def __init__(
        self,
        model: Any,
        params: ElasticParams,
        q0_deg: FloatArray,
        period: float,
        substeps: int = 8,
    ) -> None:
        if substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        self.model = model
        self.params = params
        self.period = period
        self.substeps = substeps
        self._c = _Coefficients(params)
        q0 = np.radians(np.asarray(q0_deg, dtype=np.float64))
        self._x = rest_state(q0)
        self._r = q0.copy()
        self.motor_deg = np.degrees(q0)
        self.link_deg = self.motor_deg.copy()

    def cycle(self, setpoint_deg: FloatArray) -> None:
        """One cycle towards ``setpoint_deg`` (6,) (ramped from the previous setpoint);
        :attr:`motor_deg` and :attr:`link_deg` (6,) are the new sides (new arrays)."""
        r1 = np.radians(np.asarray(setpoint_deg, dtype=np.float64))
        jl = link_inertia(self.model, self.link_deg, self.params)
        self._x = self._c.cycle(self._x, self._r, r1, jl, self.period, self.substeps)
        self._r = r1
        self.motor_deg = np.degrees(self._x[0])
        self.link_deg = np.degrees(self._x[2])

    def at_rest(self) -> bool:
        """The link stands at the setpoint (within :attr:`REST_DEG`, :attr:`REST_DEG_S`)."""
        x = np.degrees(self._x)
        return bool(
            np.all(np.abs(x[2] - np.degrees(self._r)) < self.REST_DEG)
            and np.all(np.abs(x[1]) < self.REST_DEG_S)
            and np.all(np.abs(x[3]) < self.REST_DEG_S)
        )
