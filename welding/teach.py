"""Seam teaching (method 1 of the paper, section III-C): point to point along a seam.

Manual teaching records where the robot is (:func:`record_here`). 3D seam teaching with the
sensor follows an unknown seam: measure at the current pose, then repeat

1. predict the next seam point and its tangent from the points found so far (a quadratic in
   the arc length through the last three, a line through two, the sensor's x axis for the
   first probe step);
2. move the sensor there, its x axis along the predicted tangent and its z axis kept
   looking into the material, the seam point at the sensor origin (the nominal stand-off);
3. wait until the arm has settled (WaitEndMove), trigger the sensor (Acquire), GetData;
4. ^B_G T = ^B_S T · ^S_G T, with ^B_S T = DGM(q)·^N_S T read from the robot (Here with the
   sensor tool), so any conforming robot does the kinematics;

until the seam leaves the field of view, the taught length or the point count is reached.
When the seam is lost the step is halved down to ``min_step_mm`` (the seam ended or turned
close ahead); then a 90° turn either way is tried, and when the seam is found there the
corner is put in as the intersection of the two legs (a computed point, marked as such).

Everything goes through :class:`RobotClient` and :class:`SensorClient`, so it runs against
any conforming robot and sensor; both clients must hold control, the arm powered.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np

from kinematics.transforms import invert, location_to_transform, transform_to_location
from kinematics.types import IDENTITY_LOC, FloatArray, Loc
from robotsocket.client import MotionDesc, RobotClient
from sensorsocket.client import SensorClient
from spec.wire import SensorStatus
from welding.job import Arc, Line, Location, Path, Segment
from welding.tools import Tables

__all__ = [
    "SeamTeacher",
    "TaughtPoint",
    "TeachError",
    "TeachResult",
    "record_here",
    "seam_path",
]

#: Three taught points become an arc when the middle one is this far (mm) off the line
#: through the others: well above the teaching's few-µm noise, so straight stretches of a
#: taught seam stay lines instead of arcs of kilometre radius.
ARC_MIN_SAG_MM = 0.01


class TeachError(RuntimeError):
    """Teaching cannot start or go on (no seam in view, a move that did not end)."""


@dataclass(frozen=True)
class TaughtPoint:
    """A seam point: ``seam2base`` ^B_G T (4, 4) mm with x along the seam's tangent and z
    into the material; ``t`` robot time (s) of the measurement (NaN for a computed corner)."""

    seam2base: FloatArray
    t: float
    quality: float
    corner: bool = False

    @property
    def position(self) -> FloatArray:
        out: FloatArray = self.seam2base[:3, 3]
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "location": [round(float(v), 6) for v in transform_to_location(self.seam2base)],
            "t": None if math.isnan(self.t) else self.t,
            "quality": self.quality,
            "corner": self.corner,
        }


@dataclass
class TeachResult:
    points: list[TaughtPoint]
    stop_reason: str
    robot_seconds: float
    wall_seconds: float
    measurements: int

    @property
    def seconds_per_point(self) -> float:
        """Robot-clock seconds per taught point (moves, settling, acquisition, and the
        measurements of a corner search)."""
        return self.robot_seconds / max(1, len(self.points))

    @property
    def length_mm(self) -> float:
        p = np.array([q.position for q in self.points])
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def _unit(v: FloatArray) -> FloatArray:
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise TeachError("degenerate direction (two taught points coincide)")
    out: FloatArray = v / n
    return out


def _frame(p: FloatArray, tangent: FloatArray, z_hint: FloatArray) -> FloatArray:
    """A pose (4, 4): origin ``p``, x along ``tangent``, z as close to ``z_hint`` as x allows."""
    x = _unit(tangent)
    z = _unit(z_hint - float(z_hint @ x) * x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, p
    return T


def _predict(
    points: list[FloatArray], step: float, tangent: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Next point and tangent ``step`` mm on along the points of the current leg."""
    if len(points) == 1:
        return points[0] + step * tangent, tangent
    if len(points) == 2:
        t = _unit(points[1] - points[0])
        return points[1] + step * t, t
    p = np.array(points[-3:])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    s1 = s[-1] + step
    # quadratic Lagrange basis at s1 and its derivative
    w = np.array([
        (s1 - s[1]) * (s1 - s[2]) / ((s[0] - s[1]) * (s[0] - s[2])),
        (s1 - s[0]) * (s1 - s[2]) / ((s[1] - s[0]) * (s[1] - s[2])),
        (s1 - s[0]) * (s1 - s[1]) / ((s[2] - s[0]) * (s[2] - s[1])),
    ])  # fmt: skip
    dw = np.array([
        (2 * s1 - s[1] - s[2]) / ((s[0] - s[1]) * (s[0] - s[2])),
        (2 * s1 - s[0] - s[2]) / ((s[1] - s[0]) * (s[1] - s[2])),
        (2 * s1 - s[0] - s[1]) / ((s[2] - s[0]) * (s[2] - s[1])),
    ])  # fmt: skip
    return w @ p, _unit(dw @ p)


def _closest_between_lines(
    a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray
) -> FloatArray:
    """Midpoint of the shortest segment between the line a0-a1 and the line b0-b1."""
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    a, b, c, d, e = u @ u, u @ v, v @ v, u @ w, v @ w
    den = a * c - b * b
    if abs(den) < 1e-12 * a * c:
        raise TeachError("the legs of the corner are parallel")
    sa, sb = (b * e - c * d) / den, (a * e - b * d) / den
    out: FloatArray = 0.5 * ((a0 + sa * u) + (b0 + sb * v))
    return out


@dataclass
class SeamTeacher:
    """Teaches the seam under the sensor (see the module docstring).

    ``sensor_tool`` ^N_S T (mm, deg); ``step_mm`` between points; ``speed_mm_s`` of the
    sensor between them; ``clock`` for the wall time of the run."""

    robot: RobotClient
    sensor: SensorClient
    sensor_tool: Loc
    step_mm: float = 5.0
    max_points: int = 40
    max_length_mm: float = 200.0
    min_step_mm: float = 0.5
    speed_mm_s: float = 50.0
    move_timeout_s: float = 30.0
    corners: bool = True
    clock: Callable[[], float] = time.monotonic
    #: Told each measurement's ^B_G T (None: no seam seen) as it is made; what it raises
    #: (a TeachError: "cancelled by the operator") ends the teaching there.
    on_measure: Callable[[FloatArray | None], None] | None = None
    measurements: int = field(default=0, init=False)

    def measure(self) -> tuple[FloatArray, float, float] | None:
        """(^B_G T (4, 4), robot time, quality) of a fresh measurement here, None when the
        sensor does not see the seam."""
        self.measurements += 1
        data = self.sensor.measure()
        if data.status is SensorStatus.LASER_OFF:  # not the end of the seam [SS-5.13]
            raise TeachError(self.sensor.problem(data))
        if not data.found or data.seam is None:
            if self.on_measure is not None:
                self.on_measure(None)
            return None
        sensor2base = location_to_transform(self.robot.here(self.sensor_tool))
        seam2base: FloatArray = sensor2base @ location_to_transform(data.seam)
        if self.on_measure is not None:
            self.on_measure(seam2base)
        return seam2base, data.t_exposure_start, data.quality

    def _go(self, pose: FloatArray) -> None:
        loc = transform_to_location(pose)
        self.robot.tool_move_l(tuple(float(v) for v in loc), self.sensor_tool, IDENTITY_LOC)
        if not self.robot.wait_end_move(self.move_timeout_s):
            raise TeachError(f"the move did not end within {self.move_timeout_s:g} s")

    def _try(
        self, p: FloatArray, tangent: FloatArray, z_hint: FloatArray
    ) -> tuple[FloatArray, float, float] | None:
        self._go(_frame(p, tangent, z_hint))
        return self.measure()

    def teach(self) -> TeachResult:
        wall0, t0 = self.clock(), self.robot.get_time()
        self.measurements = 0
        desc = self.robot.motion_desc()
        self.robot.set_motion_desc(
            MotionDesc(
                desc.joint_speed, desc.joint_accel, desc.joint_decel,
                self.speed_mm_s, desc.tool_rot_speed, 0.0,
            )
        )  # fmt: skip
        try:
            points, reason = self._run()
        finally:
            self.robot.set_motion_desc(desc)
        return TeachResult(
            points, reason, self.robot.get_time() - t0, self.clock() - wall0, self.measurements
        )

    def _run(self) -> tuple[list[TaughtPoint], str]:
        first = self.measure()
        if first is None:
            raise TeachError("the sensor does not see a seam at the start pose")
        here = location_to_transform(self.robot.here(self.sensor_tool))
        z_hint, tangent = here[:3, 2].copy(), here[:3, 0].copy()
        out = [TaughtPoint(first[0], first[1], first[2])]
        leg = [first[0][:3, 3]]
        step = min(self.step_mm, 2.0)  # a short first probe: the seam may cross x_S at an angle
        while True:
            if len(out) >= self.max_points:
                return out, "point count reached"
            length = sum(float(np.linalg.norm(b.position - a.position)) for a, b in pairwise(out))
            if length + step > self.max_length_mm + 1e-9:
                return out, "length reached"
            p, tangent = _predict(leg, step, tangent)
            got = self._try(p, tangent, z_hint)
            if got is not None:
                out.append(TaughtPoint(got[0], got[1], got[2]))
                leg.append(got[0][:3, 3])
                if len(leg) >= 2:
                    tangent = _unit(leg[-1] - leg[-2])
                step = self.step_mm
                continue
            if step / 2 >= self.min_step_mm:
                step /= 2  # the seam ended or turned between the last point and here
                continue
            turned = self._turn(out, leg, tangent, z_hint) if self.corners else None
            if turned is None:
                return out, "seam left the field of view"
            leg = turned
            tangent = _unit(leg[-1] - leg[-2]) if len(leg) >= 2 else tangent
            step = self.step_mm

    def _turn(
        self, out: list[TaughtPoint], leg: list[FloatArray], tangent: FloatArray, z_hint: FloatArray
    ) -> list[FloatArray] | None:
        """Look for the seam 90° to either side of the last point; on success append the
        corner (computed) and the points found on the new leg, return the new leg."""
        if len(leg) < 2:
            return None
        last = leg[-1]
        normal = _unit(z_hint)
        for sign in (1.0, -1.0):
            d = sign * np.cross(normal, tangent)
            got = self._try(last + self.step_mm * d, d, z_hint)
            if got is None:
                continue
            q0 = got[0][:3, 3]
            second = self._try(q0 + self.step_mm * d, d, z_hint)
            if second is None:
                continue
            q1 = second[0][:3, 3]
            corner = _closest_between_lines(leg[-2], leg[-1], q0, q1)
            x_in = _unit(corner - leg[-1])
            T = _frame(corner, x_in, z_hint)
            out.append(TaughtPoint(T, math.nan, 1.0, corner=True))
            out.append(TaughtPoint(got[0], got[1], got[2]))
            out.append(TaughtPoint(second[0], second[1], second[2]))
            return [corner, q0, q1]
        return None


def _tangents(points: list[TaughtPoint]) -> list[FloatArray]:
    """Tangent at each point from its neighbours on the same leg (corners split legs)."""
    p = [q.position for q in points]
    out = []
    for i in range(len(p)):
        before = i > 0 and not points[i].corner
        after = i + 1 < len(p) and not points[i + 1].corner
        if points[i].corner:
            before, after = i > 0, False
        a = p[i - 1] if before else p[i]
        b = p[i + 1] if after else p[i]
        if a is b:
            b = p[i + 1] if i + 1 < len(p) else p[i]
            a = p[i - 1] if i > 0 else p[i]
        out.append(_unit(b - a))
    return out


def seam_path(
    result: TeachResult,
    name: str,
    *,
    tool: str,
    frame: str,
    tables: Tables,
    velocity: float = 20.0,
    **process: Any,
) -> Path:
    """The taught seam as a welding path of ``tool`` in ``frame``: the tool on each seam
    point, x along the seam, z into the material; arcs through curved stretches (three
    points that are not on one line and no corner between), lines elsewhere."""
    pts = result.points
    if len(pts) < 2:
        raise TeachError("a path needs at least two taught points")
    base2frame = invert(location_to_transform(tables.frame(frame).location))
    tables.tool(tool)  # refuse an unknown tool now
    locs: list[Location] = []
    for q, t in zip(pts, _tangents(pts), strict=True):
        T = base2frame @ _frame(q.position, t, q.seam2base[:3, 2])
        v = [round(float(x), 6) for x in transform_to_location(T)]
        locs.append(Location(v[0], v[1], v[2], v[3], v[4], v[5], tool, frame))
    segments: list[Segment] = []
    i = 1
    while i < len(locs):
        if i + 1 < len(locs) and not pts[i].corner and not pts[i + 1].corner:
            a, m, b = (pts[k].position for k in (i - 1, i, i + 1))
            chord = max(float(np.linalg.norm(b - a)), 1e-12)
            sag = float(np.linalg.norm(np.cross(m - a, b - a))) / chord
            if sag > ARC_MIN_SAG_MM:
                segments.append(Arc(locs[i], locs[i + 1]))
                i += 2
                continue
        segments.append(Line(locs[i]))
        i += 1
    return Path(name, locs[0], tuple(segments), velocity=velocity, **process)


def record_here(robot: RobotClient, tables: Tables, tool: str, frame: str) -> Location:
    """Manual teaching: where ``tool`` is now, in ``frame`` (names from ``tables``)."""
    v = robot.here(tables.tool(tool).location, tables.frame(frame).location)
    r = [round(float(x), 6) for x in v]
    return Location(r[0], r[1], r[2], r[3], r[4], r[5], tool, frame)
