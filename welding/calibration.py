"""Tool calibration (paper section III-C, 24-Laser's SensorCalib and LaserCalib): find the
sensor tool ^N_S T and the laser tool ^N_L T from point-to-point moves, by least squares.

Both are solved the same way (:func:`least_squares`): Gauss-Newton on the tool as a small
change of the nominal tool, ``tool = nominal · [R(w) | v]`` with ``v`` (mm) and the rotation
vector ``w`` (rad) in the nominal tool frame, plus the unknowns of the feature the poses look
at. The uncertainty of each component comes from the Jacobian at the solution (covariance
σ² (JᵀJ)⁻¹, σ from the residual); a result is refused when the pose set does not determine
every component (JᵀJ ill-conditioned) or when a component's 1σ exceeds :class:`Limits`.

Sensor tool (:func:`solve_sensor_tool`, :class:`SensorToolCalibration`): the sensor measures
the seam point ^S_G T of a straight seam (a butt joint of plates); from every flange pose
^B_N T_k the point ^B_N T_k · ^N_S T · ^S_G T_k must lie on the same straight line in B (the
laser plane cuts the seam at another place from each pose, so "the same point" is "on the
same line"). Unknowns: the tool (6) and the line (4). Why the poses of :func:`sensor_plan`:

- one orientation cannot work: with the same R_k for every pose a change of the tool's
  position shifts every base point by the same R·δ, which the line absorbs. Rotations about
  two axes at least make R_k·δ differ between poses; the plan tilts about all three.
- the tool's rotation is seen only through the lever of the measured point in the sensor
  frame (a point at the sensor origin does not move when the frame turns about it), so the
  plan puts the seam at different places in the field of view (±5 mm across, ±3 mm deep).
- a rotation about y_S or z_S moves the point along x_S, which is along the seam (invisible)
  unless x_S leaves the seam direction: the plan turns the sensor about z_S (±25°) and tilts
  it out of the plate about y_S (±20°).
- a first pass with half the spread (the tool may be 5 mm / 3° off, the seam must stay in the
  field of view) gives an estimate; the second pass commands its poses with that estimate.

Laser tool (:func:`solve_laser_tool`, :class:`LaserToolCalibration`): a spot detector fixed
in the cell (a camera under a diffusing plate, its frame ^B_D T known) measures the centre
(x, y) of the laser spot on the plate and the spot's 1/e² radius. The beam is a Gaussian
beam with waist radius w0 at the focal point and Rayleigh length zR (known properties of the
optics, not of the mounting): radius(s) = w0·sqrt(1 + (s/zR)²) at the distance s from the
focus along the beam. The centres give the beam axis (a line through the focus), the radii
the focus's place along the axis (|s|; the plan keeps every s on one side of the focus, so
the sign is known). The laser tool's rotation about its own beam is not a property of the
laser (a round beam): it keeps the nominal value, and ``error_vs_true`` of the laser tool is
the angle between the beam axes. Unknowns: the tool (5: position and the beam's two tilts).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from kinematics.transforms import (
    location_to_transform,
    matrix_from_rotvec,
    rotvec_from_matrix,
    transform_to_location,
)
from kinematics.types import IDENTITY_LOC, FloatArray, Loc
from spec.wire import SensorStatus

__all__ = [
    "CalibrationError",
    "EmulatedSpotDetector",
    "GaussianBeam",
    "LaserObservation",
    "LaserToolCalibration",
    "Limits",
    "SensorObservation",
    "SensorToolCalibration",
    "SpotMeasurement",
    "ToolEstimate",
    "error_vs_true",
    "laser_plan",
    "least_squares",
    "sensor_plan",
    "solve_laser_tool",
    "solve_sensor_tool",
    "spot_on_plate",
]

COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")
#: What to do when the sensor tool's run does not see enough of the seam.
OVER_THE_SEAM = "move the sensor back over the straight seam and start again"


class CalibrationError(RuntimeError):
    """The calibration cannot give a result it can stand behind (message says why).
    ``hint``: what the operator can do about it, also at the end of the message (the CLI
    prints the message, the console shows the hint on its own line)."""

    def __init__(self, message: str, hint: str = "") -> None:
        super().__init__(f"{message}: {hint}" if hint else message)
        self.hint = hint


@dataclass(frozen=True)
class Limits:
    """When a result is refused: a component's 1σ above ``position_mm`` / ``rotation_deg``
    (a third of the 0.05 mm / 0.05° target, so the target holds at 3σ), or the pose set
    degenerate (condition number of the column-scaled Jacobian above ``condition``)."""

    position_mm: float = 0.0167
    rotation_deg: float = 0.0167
    condition: float = 1e6


# --- least squares ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Solution:
    x: FloatArray
    jacobian: FloatArray  # (m, n) at x
    residuals: FloatArray  # (m,)

    @property
    def sigma(self) -> float:
        """Noise estimate from the residual (units of the residuals)."""
        m, n = self.jacobian.shape
        return float(np.sqrt(self.residuals @ self.residuals / max(m - n, 1)))

    def condition(self) -> float:
        """Condition number of the Jacobian with its columns scaled to unit length."""
        norms = np.linalg.norm(self.jacobian, axis=0)
        if (norms == 0).any():
            return math.inf
        s = np.linalg.svd(self.jacobian / norms, compute_uv=False)
        return math.inf if s[-1] <= 0 else float(s[0] / s[-1])

    def covariance(self) -> FloatArray:
        out: FloatArray = np.asarray(
            np.linalg.pinv(self.jacobian.T @ self.jacobian), dtype=np.float64
        )
        out *= self.sigma**2
        return out


def least_squares(
    residuals: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    *,
    steps: FloatArray | None = None,
    iterations: int = 30,
    tolerance: float = 1e-12,
) -> Solution:
    """Gauss-Newton (Levenberg-damped) on ``residuals(x) -> (m,)`` from ``x0`` (n,), with a
    central-difference Jacobian (``steps`` per parameter, default 1e-6)."""
    x = np.array(x0, dtype=np.float64)
    h = np.full(len(x), 1e-6) if steps is None else np.asarray(steps, dtype=np.float64)

    def jac(x: FloatArray) -> FloatArray:
        cols = []
        for i in range(len(x)):
            d = np.zeros_like(x)
            d[i] = h[i]
            cols.append((residuals(x + d) - residuals(x - d)) / (2 * h[i]))
        return np.stack(cols, axis=1)

    r = residuals(x)
    cost = float(r @ r)
    damping = 1e-6
    for _ in range(iterations):
        J = jac(x)
        g = J.T @ r
        A = J.T @ J
        while True:
            step = np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-12), -g)
            r_new = residuals(x + step)
            c_new = float(r_new @ r_new)
            if c_new <= cost or damping > 1e6:
                break
            damping *= 10.0
        if not c_new <= cost:  # no step helps (or NaN): x is the solution
            break
        x, r, done = x + step, r_new, cost - c_new <= tolerance * max(cost, 1e-30)
        cost = c_new
        damping = max(damping / 10.0, 1e-9)
        if done:
            break
    return Solution(x, jac(x), r)


def _tool(nominal: FloatArray, p: FloatArray) -> FloatArray:
    """nominal (4, 4) · [R(w) | v] for p = (v mm, w rad)."""
    delta = np.eye(4)
    delta[:3, :3] = matrix_from_rotvec(p[3:6])
    delta[:3, 3] = p[:3]
    out: FloatArray = nominal @ delta
    return out


def _loc(T: FloatArray) -> Loc:
    v = [float(x) for x in transform_to_location(T)]
    return (v[0], v[1], v[2], v[3], v[4], v[5])


def _perpendicular_basis(d: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors perpendicular to the unit vector ``d`` and to each other."""
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


# --- results ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ToolEstimate:
    """A calibrated tool: ``tool`` (VAL3 location, mm, deg); ``sigma`` the 1σ of each
    component (x, y, z mm and rx, ry, rz deg as small rotations about the tool's axes; NaN
    for a component the procedure does not find); the residuals (mm) of the fit."""

    kind: str
    nominal: Loc
    tool: Loc
    sigma: tuple[float, ...]
    residuals_mm: tuple[float, ...]
    noise_mm: float
    condition: float
    poses: int
    measurements: int
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def residual_rms_mm(self) -> float:
        r = np.asarray(self.residuals_mm)
        return float(np.sqrt(np.mean(r * r))) if len(r) else math.nan

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "nominal": list(self.nominal),
            "tool": [round(v, 6) for v in self.tool],
            "uncertainty": {
                c: (None if math.isnan(s) else s)
                for c, s in zip(COMPONENTS, self.sigma, strict=True)
            },
            "uncertainty_units": "1 sigma; x, y, z mm; rx, ry, rz deg about the tool axes",
            "residual_rms_mm": self.residual_rms_mm,
            "residual_max_mm": float(np.max(np.abs(self.residuals_mm))),
            "residuals_mm": [round(v, 6) for v in self.residuals_mm],
            "noise_estimate_mm": self.noise_mm,
            "condition": self.condition,
            "poses": self.poses,
            "measurements": self.measurements,
            **self.details,
        }


def error_vs_true(estimate: Loc, true: Loc, *, beam_only: bool = False) -> dict[str, float]:
    """``position_mm``: distance between the origins; ``orientation_deg``: the angle of the
    rotation between the two frames, or between their z axes with ``beam_only`` (a laser)."""
    a, b = location_to_transform(estimate), location_to_transform(true)
    pos = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    if beam_only:
        c = float(np.clip(a[:3, 2] @ b[:3, 2], -1.0, 1.0))
        ang = math.degrees(math.acos(c))
    else:
        ang = math.degrees(float(np.linalg.norm(rotvec_from_matrix(a[:3, :3].T @ b[:3, :3]))))
    return {"position_mm": pos, "orientation_deg": ang}


def _check(sol: Solution, n_tool: int, names: Sequence[str], limits: Limits) -> list[float]:
    """1σ of the first ``n_tool`` parameters (mm, deg); CalibrationError when refused."""
    cond = sol.condition()
    if not cond < limits.condition:
        # the weakest direction of the problem, named by its largest tool component
        norms = np.linalg.norm(sol.jacobian, axis=0)
        norms[norms == 0] = 1.0
        _, _, vt = np.linalg.svd(sol.jacobian / norms)
        weak = names[int(np.argmax(np.abs(vt[-1][:n_tool])))]
        raise CalibrationError(
            f"degenerate pose set (condition {cond:.3g}): the poses do not determine the"
            f" tool's {weak}; use poses with different orientations"
        )
    cov = sol.covariance()
    sig = np.sqrt(np.diag(cov)[:n_tool])
    out = []
    for name, s in zip(names, sig, strict=False):
        rot = name.startswith("r")
        value = math.degrees(s) if rot else float(s)
        limit = limits.rotation_deg if rot else limits.position_mm
        if not value <= limit:
            unit = "deg" if rot else "mm"
            raise CalibrationError(
                f"the tool's {name} is uncertain by {value:.4f} {unit} (1 sigma, limit "
                f"{limit:g} {unit}): more poses, more spread, or less noise"
            )
        out.append(value)
    return out


# --- sensor tool -----------------------------------------------------------------------------


@dataclass(frozen=True)
class SensorObservation:
    """A flange pose ^B_N T (4, 4) mm and the seam point it saw, (3,) mm in S."""

    flange2base: FloatArray
    point: FloatArray


def _sensor_residuals(
    obs: Sequence[SensorObservation], nominal: FloatArray, c0: FloatArray, d0: FloatArray
) -> Callable[[FloatArray], FloatArray]:
    F = np.stack([o.flange2base for o in obs])
    s = np.stack([o.point for o in obs])
    e1, e2 = _perpendicular_basis(d0)

    def fun(x: FloatArray) -> FloatArray:
        T = _tool(nominal, x)
        local = s @ T[:3, :3].T + T[:3, 3]
        p = np.einsum("kij,kj->ki", F[:, :3, :3], local) + F[:, :3, 3]
        d = d0 + x[8] * e1 + x[9] * e2
        d = d / np.linalg.norm(d)
        q = p - (c0 + x[6] * e1 + x[7] * e2)
        q = q - np.outer(q @ d, d)
        u1 = e1 - (e1 @ d) * d
        u1 /= np.linalg.norm(u1)
        u2 = np.cross(d, u1)
        out: FloatArray = np.stack([q @ u1, q @ u2], axis=1).reshape(-1)
        return out

    return fun


def solve_sensor_tool(
    obs: Sequence[SensorObservation],
    nominal: Loc,
    *,
    direction: Sequence[float] | FloatArray | None = None,
    limits: Limits = Limits(),
) -> ToolEstimate:
    """^N_S T from seam points of one straight seam seen from several flange poses (see the
    module docstring). ``direction``: the seam's direction in B roughly (default: the main
    direction of the points under the nominal tool)."""
    if len(obs) < 6:
        raise CalibrationError(
            f"{len(obs)} observations: at least 6 are needed", OVER_THE_SEAM + " (its middle)"
        )
    T0 = location_to_transform(nominal)
    p = np.array([(o.flange2base @ T0 @ np.append(o.point, 1.0))[:3] for o in obs])
    c0 = p.mean(axis=0)
    if direction is None:
        d0 = np.linalg.svd(p - c0)[2][0]
    else:
        d0 = np.asarray(direction, dtype=np.float64)
        d0 = d0 / np.linalg.norm(d0)
    fun = _sensor_residuals(obs, T0, c0, d0)
    sol = least_squares(fun, np.zeros(10))
    sig = _check(sol, 6, COMPONENTS, limits)
    r = sol.residuals.reshape(-1, 2)
    e1, e2 = _perpendicular_basis(d0)
    d = d0 + sol.x[8] * e1 + sol.x[9] * e2
    line = {
        "point": (c0 + sol.x[6] * e1 + sol.x[7] * e2).tolist(),
        "direction": (d / np.linalg.norm(d)).tolist(),
    }
    return ToolEstimate(
        kind="sensor",
        nominal=nominal,
        tool=_loc(_tool(T0, sol.x)),
        sigma=tuple(sig),
        residuals_mm=tuple(float(v) for v in np.hypot(r[:, 0], r[:, 1])),
        noise_mm=sol.sigma,
        condition=sol.condition(),
        poses=len(obs),
        measurements=len(obs),
        details={"seam_line": line},
    )


#: one pose of a plan: turn about z_S, tilt about y_S, roll about x_S (deg), the station along
#: the seam (mm) and where the seam should appear in the laser plane, y_S and z_S (mm)
PlanPose = tuple[float, float, float, float, float, float]


def sensor_plan(
    n: int = 30,
    spread: float = 1.0,
    angles: tuple[float, float, float] = (45.0, 30.0, 15.0),
    place: tuple[float, float] = (7.0, 5.0),
) -> list[PlanPose]:
    """``n`` poses (see the module docstring): the corners of a two-level design in the three
    angles, each with the seam at another place of the field of view; ``spread`` scales the
    angles and the places (0.5 for a first pass)."""
    out: list[PlanPose] = []
    py, pz = place
    places = ((py, pz), (-py, -pz), (py, -pz), (-py, pz), (0.0, 0.0))
    for i in range(n):
        signs = ((i >> 0) & 1, (i >> 1) & 1, (i >> 2) & 1)
        a = [spread * ang * (1 if b else -1) for ang, b in zip(angles, signs, strict=True)]
        if i % 8 == 7:
            a = [0.0, 0.0, 0.0]  # some straight poses: the plain view of the seam
        y, z = places[i % len(places)]
        station = 4.0 * ((i % 7) - 3)
        out.append((a[0], a[1], a[2], station, spread * y, spread * z))
    return out


class SeamSensor(Protocol):
    """What the calibration needs of a sensor (a :class:`~sensorsocket.client.SensorClient`)."""

    def acquire(self) -> int: ...

    def get_data(self) -> Any: ...


class Robot(Protocol):
    """What the calibration needs of a robot (a :class:`~robotsocket.client.RobotClient`)."""

    def here(self, tool: Sequence[float] = ..., frame: Sequence[float] = ...) -> Loc: ...

    def tool_move_j(
        self, loc: Sequence[float], tool: Sequence[float] = ..., frame: Sequence[float] = ...
    ) -> int: ...

    def wait_end_move(self, timeout: float = ...) -> bool: ...


def _rot(axis: int, deg: float) -> FloatArray:
    r = np.zeros(3)
    r[axis] = math.radians(deg)
    out: FloatArray = matrix_from_rotvec(r)
    return out


@dataclass
class SensorToolCalibration:
    """The sensor tool procedure (module docstring): start with the sensor over a straight
    seam; ``poses`` point-to-point poses (``first_pass`` of them with half the spread and the
    nominal tool, the rest with the first pass's estimate), ``repeats`` measurements averaged
    at each; then back to the start pose."""

    robot: Robot
    sensor: SeamSensor
    nominal: Loc
    poses: int = 30
    first_pass: int = 8
    repeats: int = 16
    limits: Limits = field(default_factory=Limits)
    move_timeout_s: float = 60.0
    skipped: int = field(default=0, init=False)

    def measure(self) -> FloatArray | None:
        """The seam point (3,) mm in S, averaged over ``repeats`` acquisitions; None when
        fewer than half of them found the seam."""
        pts = []
        for _ in range(self.repeats):
            index = self.sensor.acquire()
            data = self.sensor.get_data()
            if data.index != index:
                raise CalibrationError(f"GetData returned measurement {data.index}, not {index}")
            if data.status is SensorStatus.LASER_OFF:  # not a pose off the seam [SS-5.13]
                where = getattr(self.sensor, "address", "HOST:PORT")
                raise CalibrationError(data.status.problem(where))
            if data.found and data.seam is not None:
                pts.append(data.seam[:3])
        if 2 * len(pts) < self.repeats:
            return None
        out: FloatArray = np.mean(np.array(pts, dtype=np.float64), axis=0)
        return out

    def _go(self, sensor2base: FloatArray, tool: Loc) -> None:
        self.robot.tool_move_j(_loc(sensor2base), tool, IDENTITY_LOC)
        if not self.robot.wait_end_move(self.move_timeout_s):
            raise CalibrationError(f"a move did not end within {self.move_timeout_s:g} s")

    def _observe(
        self, plan: list[PlanPose], tool: Loc, flange0: FloatArray, seam: FloatArray, d: FloatArray
    ) -> list[SensorObservation]:
        """Go to each pose of ``plan`` relative to the start orientation (sensor frame of
        ``tool`` on ``flange0``), the seam ``seam`` (3,) in B along ``d``, and measure."""
        r0 = (flange0 @ location_to_transform(tool))[:3, :3]
        out = []
        for yaw, pitch, roll, station, y, z in plan:
            R = r0 @ _rot(2, yaw) @ _rot(1, pitch) @ _rot(0, roll)
            pose = np.eye(4)
            pose[:3, :3] = R
            pose[:3, 3] = seam + station * d - R @ np.array([0.0, y, z])
            self._go(pose, tool)
            point = self.measure()
            if point is None:
                self.skipped += 1
                continue
            out.append(
                SensorObservation(location_to_transform(self.robot.here(IDENTITY_LOC)), point)
            )
        return out

    def run(self) -> ToolEstimate:
        self.skipped = 0
        start = self.robot.here(IDENTITY_LOC)
        flange0 = location_to_transform(start)
        s0 = self.measure()
        if s0 is None:
            raise CalibrationError(
                "the sensor does not see the seam at the start pose", OVER_THE_SEAM
            )
        sensor0 = flange0 @ location_to_transform(self.nominal)
        seam0 = (sensor0 @ np.append(s0, 1.0))[:3]
        d0 = sensor0[:3, 0]
        obs = [SensorObservation(flange0, s0)]
        try:
            n1 = min(self.first_pass, self.poses - 1)
            obs += self._observe(sensor_plan(n1, 0.5), self.nominal, flange0, seam0, d0)
            rough = solve_sensor_tool(
                obs, self.nominal, direction=d0, limits=Limits(1.0, 1.0, self.limits.condition)
            )
            line = rough.details["seam_line"]
            c, d = np.array(line["point"]), np.array(line["direction"])
            if d @ d0 < 0:
                d = -d
            # the start's seam point on the fitted line, as the stations' origin
            seam1 = c + ((seam0 - c) @ d) * d
            plan = sensor_plan(self.poses - 1 - n1)
            obs += self._observe(plan, rough.tool, flange0, seam1, d)
        finally:
            self.robot.tool_move_j(start, IDENTITY_LOC, IDENTITY_LOC)
            self.robot.wait_end_move(self.move_timeout_s)
        est = solve_sensor_tool(obs, self.nominal, direction=d0, limits=self.limits)
        details = {**est.details, "repeats": self.repeats, "poses_without_seam": self.skipped}
        return dataclasses.replace(
            est,
            poses=len(obs) + self.skipped,
            measurements=len(obs) * self.repeats,
            details=details,
        )


# --- laser tool ------------------------------------------------------------------------------


@dataclass(frozen=True)
class GaussianBeam:
    """The focused beam (mm): waist radius ``w0`` (1/e²) at the focus, Rayleigh length
    ``z_r``; ``radius(s)`` at the distance ``s`` from the focus along the beam."""

    w0: float = 0.3
    z_r: float = 2.0

    def radius(self, s: FloatArray | float) -> FloatArray:
        out: FloatArray = self.w0 * np.sqrt(1.0 + (np.asarray(s, dtype=np.float64) / self.z_r) ** 2)
        return out


@dataclass(frozen=True)
class SpotMeasurement:
    """The spot detector's reading: the spot centre (x, y) on its plate, in the plate frame D
    (mm), and the beam's 1/e² radius there (mm)."""

    x: float
    y: float
    radius: float


@dataclass(frozen=True)
class LaserObservation:
    flange2base: FloatArray
    spot: SpotMeasurement


class SpotDetector(Protocol):
    """A spot detector fixed in the cell: ``plate2base`` ^B_D T (4, 4) mm (the plate is
    z_D = 0), its ``beam``, the 1σ of its readings, and a reading of the spot now."""

    plate2base: FloatArray
    beam: GaussianBeam
    sigma_centre_mm: float
    sigma_radius_mm: float

    def measure(self) -> SpotMeasurement: ...


def spot_on_plate(laser2base: FloatArray, plate2base: FloatArray) -> tuple[FloatArray, float]:
    """Where the beam (z axis of ``laser2base``, from its origin, the focus) meets the plate
    (z = 0 of ``plate2base``): (x, y) in the plate frame and the distance s from the focus."""
    n, o = plate2base[:3, 2], plate2base[:3, 3]
    f, b = laser2base[:3, 3], laser2base[:3, 2]
    s = float(n @ (o - f) / (n @ b))
    p = plate2base[:3, :3].T @ (f + s * b - o)
    out: FloatArray = p[:2]
    return out, s


def _laser_residuals(
    obs: Sequence[LaserObservation], nominal: FloatArray, det: SpotDetector
) -> Callable[[FloatArray], FloatArray]:
    F = np.stack([o.flange2base for o in obs])
    meas = np.array([(o.spot.x, o.spot.y, o.spot.radius) for o in obs])
    n, o = det.plate2base[:3, 2], det.plate2base[:3, 3]
    scale = np.array([det.sigma_centre_mm, det.sigma_centre_mm, det.sigma_radius_mm])

    def fun(x: FloatArray) -> FloatArray:
        T = _tool(nominal, np.append(x, 0.0))  # the roll about the beam stays nominal
        f = np.einsum("kij,j->ki", F[:, :3, :3], T[:3, 3]) + F[:, :3, 3]
        b = F[:, :3, :3] @ T[:3, 2]
        s = ((o - f) @ n) / (b @ n)
        p = (f + s[:, None] * b - o) @ det.plate2base[:3, :3]
        model = np.stack([p[:, 0], p[:, 1], det.beam.radius(s)], axis=1)
        out: FloatArray = ((model - meas) / scale).reshape(-1)
        return out

    return fun


def solve_laser_tool(
    obs: Sequence[LaserObservation],
    nominal: Loc,
    detector: SpotDetector,
    *,
    limits: Limits = Limits(),
) -> ToolEstimate:
    """^N_L T (focus and beam axis; the roll about the beam stays nominal) from the spot
    detector's readings at several flange poses (see the module docstring)."""
    if len(obs) < 4:
        raise CalibrationError(f"{len(obs)} observations: at least 4 are needed")
    T0 = location_to_transform(nominal)
    sol = least_squares(_laser_residuals(obs, T0, detector), np.zeros(5))
    sig = _check(sol, 5, COMPONENTS[:5], limits)
    r = sol.residuals.reshape(-1, 3) * np.array(
        [detector.sigma_centre_mm, detector.sigma_centre_mm, detector.sigma_radius_mm]
    )
    return ToolEstimate(
        kind="laser",
        nominal=nominal,
        tool=_loc(_tool(T0, np.append(sol.x, 0.0))),
        sigma=(*sig, math.nan),
        residuals_mm=tuple(float(v) for v in np.linalg.norm(r, axis=1)),
        noise_mm=sol.sigma * detector.sigma_centre_mm,
        condition=sol.condition(),
        poses=len(obs),
        measurements=len(obs),
        details={"roll_about_beam": "nominal (not a property of a round beam)"},
    )


def laser_plan(n: int = 30) -> list[PlanPose]:
    """``n`` poses for the laser tool: (turn about the beam, tilt about y_L, tilt about x_L
    (deg), the plate's distance from the nominal focus s (mm, always past the focus, so the
    radius tells s without the sign's ambiguity), where the spot should land on the plate
    x, y (mm)). Tilts about two axes make the focus's offset show in the spot centres;
    distances from 3 to 12 mm (1.5 to 6 Rayleigh lengths) make the radius tell s."""
    out: list[PlanPose] = []
    places = ((3.0, 3.0), (-3.0, -3.0), (3.0, -3.0), (-3.0, 3.0), (0.0, 0.0))
    for i in range(n):
        signs = [1.0 if (i >> k) & 1 else -1.0 for k in range(3)]
        yaw, pitch, roll = 45.0 * signs[0], 20.0 * signs[1], 20.0 * signs[2]
        if i % 8 == 7:
            yaw = pitch = roll = 0.0
        x, y = places[i % len(places)]
        out.append((yaw, pitch, roll, 3.0 + 3.0 * (i % 4), x, y))
    return out


@dataclass
class LaserToolCalibration:
    """The laser tool procedure: ``poses`` poses of :func:`laser_plan` over the spot
    detector, commanded with the nominal tool, ``repeats`` readings averaged at each."""

    robot: Robot
    detector: SpotDetector
    nominal: Loc
    poses: int = 30
    repeats: int = 4
    limits: Limits = field(default_factory=Limits)
    move_timeout_s: float = 60.0

    def run(self) -> ToolEstimate:
        start = self.robot.here(IDENTITY_LOC)
        plate = self.detector.plate2base
        r0 = plate[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # beam into the plate
        obs = []
        try:
            for yaw, pitch, roll, s, x, y in laser_plan(self.poses):
                R = r0 @ _rot(2, yaw) @ _rot(1, pitch) @ _rot(0, roll)
                spot = plate[:3, :3] @ np.array([x, y, 0.0]) + plate[:3, 3]
                # the nominal focus s before the plate along the (tilted) beam
                b = R[:, 2]
                depth = s / abs(float(b @ plate[:3, 2]))
                pose = np.eye(4)
                pose[:3, :3] = R
                pose[:3, 3] = spot - depth * b
                self.robot.tool_move_j(_loc(pose), self.nominal, IDENTITY_LOC)
                if not self.robot.wait_end_move(self.move_timeout_s):
                    raise CalibrationError(f"a move did not end within {self.move_timeout_s:g} s")
                m = [self.detector.measure() for _ in range(self.repeats)]
                avg = SpotMeasurement(
                    float(np.mean([v.x for v in m])),
                    float(np.mean([v.y for v in m])),
                    float(np.mean([v.radius for v in m])),
                )
                flange = location_to_transform(self.robot.here(IDENTITY_LOC))
                obs.append(LaserObservation(flange, avg))
        finally:
            self.robot.tool_move_j(start, IDENTITY_LOC, IDENTITY_LOC)
            self.robot.wait_end_move(self.move_timeout_s)
        det = _Averaged(self.detector, self.repeats)
        est = solve_laser_tool(obs, self.nominal, det, limits=self.limits)
        details = {
            **est.details,
            "repeats": self.repeats,
            "beam": {"w0_mm": det.beam.w0, "rayleigh_mm": det.beam.z_r},
            "detector_sigma_mm": {
                "centre": self.detector.sigma_centre_mm,
                "radius": self.detector.sigma_radius_mm,
            },
        }
        return dataclasses.replace(est, measurements=len(obs) * self.repeats, details=details)


@dataclass
class _Averaged:
    """The detector as its ``repeats``-reading averages see it (1σ / √repeats)."""

    inner: SpotDetector
    repeats: int

    def __post_init__(self) -> None:
        self.plate2base = self.inner.plate2base
        self.beam = self.inner.beam
        k = math.sqrt(self.repeats)
        self.sigma_centre_mm = self.inner.sigma_centre_mm / k
        self.sigma_radius_mm = self.inner.sigma_radius_mm / k

    def measure(self) -> SpotMeasurement:
        return self.inner.measure()


class EmulatedSpotDetector:
    """The emulated cell's spot detector: a plate 100 mm beside the laser focus of the ready
    pose, 8 mm past it along the beam, facing the laser; it sees the spot where the cell's
    *true* laser tool puts it, with Gaussian noise (``sigma_centre_mm`` on each centre
    coordinate, ``sigma_radius_mm`` on the radius: a camera behind a diffusing plate, spot
    centroid and second moment of a ~1 mm spot over ~100 pixels)."""

    def __init__(
        self,
        cell: Any,
        rng: np.random.Generator,
        *,
        beam: GaussianBeam = GaussianBeam(),
        sigma_centre_mm: float = 0.005,
        sigma_radius_mm: float = 0.005,
    ) -> None:
        self.cell = cell
        self.beam = beam
        self.sigma_centre_mm = sigma_centre_mm
        self.sigma_radius_mm = sigma_radius_mm
        self._rng = rng
        laser = cell.ready_flange2base() @ location_to_transform(cell.laser_tool)
        plate = np.eye(4)
        plate[:3, :3] = laser[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # z_D against the beam
        plate[:3, 3] = laser[:3, 3] + 8.0 * laser[:3, 2] + np.array([0.0, -100.0, 0.0])
        self.plate2base = plate

    def measure(self) -> SpotMeasurement:
        # the arm's true pose: its latest setpoint (the reading is taken at rest)
        flange = self.cell.flange2base_now()
        xy, s = spot_on_plate(flange @ self.cell.laser2flange, self.plate2base)
        nx, ny, nr = self._rng.normal(0.0, 1.0, 3)
        return SpotMeasurement(
            float(xy[0] + self.sigma_centre_mm * nx),
            float(xy[1] + self.sigma_centre_mm * ny),
            float(self.beam.radius(s) + self.sigma_radius_mm * nr),
        )
