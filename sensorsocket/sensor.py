"""The sensor facade: settings, clock, the latest measurement and frame (no I/O).

:class:`Sensor` owns a :class:`~sensorsocket.emulator.CameraEmulator` (timing model, stripe
renderer, seam detector and its settings), the sensor clock and the latest reading. The TCP
service and the UDP trigger handler both call :meth:`Sensor.acquire`; it is thread-safe.

Time is an input: ``clock`` is any callable returning seconds (``time.monotonic`` in real
time, a :class:`SimClock` in simulated time). ``acquire(t_arrival)`` renders and detects at
once and stamps the *modelled* timestamps (poll, start jitter, column-wise exposure,
processing) on the sensor clock; in simulated time the caller advances the clock.

The sensor's pose is an injectable :data:`~sensorsocket.scene.PoseProvider`: fixed over the
seam, scripted (:func:`motion_pose`), or the emulated work cell's true robot motion.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.transforms import transform_to_location
from kinematics.types import FloatArray
from sensorsocket.detector import SeamStatus
from sensorsocket.emulator import CameraEmulator, Frame, SettingsError
from sensorsocket.scene import Joint, PoseProvider, Scene, SeamPath, fixed_pose, scripted_pose
from sensorsocket.timing import TimingModel
from spec.wire import SensorStatus

U8Array = NDArray[np.uint8]
Clock = Callable[[], float]

NAN_LOCATION = (math.nan,) * 6


class SensorError(ValueError):
    """A setting outside its range or an impossible request (maps to OUT_OF_RANGE)."""


class SimClock:
    """A simulated sensor clock (seconds): call it to read, ``set``/``advance`` to move it."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()

    def __call__(self) -> float:
        return self._t

    def set(self, t: float) -> None:
        """Move the clock to ``t`` (s); it never goes back."""
        with self._lock:
            self._t = max(self._t, float(t))

    def advance(self, dt: float) -> None:
        """Move the clock forward by ``dt`` >= 0 (s)."""
        if not dt >= 0:
            raise ValueError(f"dt must be >= 0 s, got {dt}")
        with self._lock:
            self._t += float(dt)


@dataclass(frozen=True)
class SensorSettings:
    """Acquisition settings: laser, exposure of one column (s), readout window (columns)."""

    laser: bool
    exposure_s: float
    first_column: int
    columns: int


@dataclass(slots=True)  # not frozen: a frozen __init__ of 14 fields costs ~1 us per frame
class Reading:
    """One measurement: the acquisition, the frame and what the detector found.

    ``frame`` is (512 columns, 256 rows) uint8 in readout order (``frame.T`` is the image),
    columns outside the readout window zero. ``seam2sensor`` (4, 4) mm and ``seam``
    (x, y, z mm, rx, ry, rz deg) are NaN unless status is FOUND. ``points`` (N, 3) mm are the
    stripe points in S. ``truth_seam2sensor`` (4, 4) is the scene's true seam frame at the
    time of the seam column (middle of the exposure when not found), NaN where the laser
    plane misses the seam; ``None`` unless the sensor was built with ``keep_truth=True``
    (computing it costs as much as detecting the seam, and only tests need it). Treat a
    reading as read-only: the sensor hands the same one to every caller.
    """

    index: int
    status: SensorStatus
    seam2sensor: FloatArray = field(repr=False)
    seam: tuple[float, float, float, float, float, float]
    quality: float
    t_trigger: float  # robot clock, NaN for a software acquisition
    t_arrival: float
    t_exposure_start: float
    t_exposure_end: float
    t_done: float
    frame: U8Array = field(repr=False)
    points: FloatArray = field(repr=False)
    truth_seam2sensor: FloatArray | None = field(repr=False, default=None)
    detector_status: str = ""


def motion_pose(scene: Scene, motion: str, *, t0: float = 0.0) -> PoseProvider:
    """A pose provider from a short spec (mm, Hz, mm/s): ``fixed``, ``sine:AMP:FREQ``
    (perpendicular to the seam, as the paper's ΔT experiment) or ``scan:SPEED`` (along x_W).

    The sensor starts over the seam at x_W = 0; ``t0`` is the clock time of that start (s).
    """
    start = scene.sensor_over_seam(0.0)
    kind, _, rest = motion.partition(":")
    try:
        values = [float(v) for v in rest.split(":")] if rest else []
    except ValueError:
        raise SensorError(f"bad motion {motion!r}: numbers expected after the kind") from None
    if not all(math.isfinite(v) for v in values):
        raise SensorError(f"bad motion {motion!r}: numbers must be finite")
    if kind == "fixed" and not values:
        return fixed_pose(start)
    if kind == "sine" and len(values) == 2 and abs(values[0]) <= 10 and 0 <= values[1] <= 100:
        return scripted_pose(
            start, sine_amplitude_mm=values[0], sine_frequency_hz=values[1], t0_s=t0
        )
    if kind == "scan" and len(values) == 1 and abs(values[0]) <= 2000:
        axis = scene.workpiece2base[:3, 0]
        return scripted_pose(start, velocity_mm_s=values[0] * axis, t0_s=t0)
    raise SensorError(
        f"bad motion {motion!r}: use fixed, sine:AMP_MM:FREQ_HZ (|AMP| <= 10, 0..100 Hz) "
        "or scan:SPEED_MM_S (|SPEED| <= 2000)"
    )


def make_scene(joint: str = "butt", seam: str = "straight") -> Scene:
    """The standard scenes of the CLI: joint butt|fillet|lap, seam straight|sine (Fig. 10)."""
    joints = {"butt": Joint.butt(), "fillet": Joint.fillet(), "lap": Joint.lap()}
    paths = {"straight": SeamPath.straight(), "sine": SeamPath.paper_sine()}
    if joint not in joints:
        raise SensorError(f"unknown joint {joint!r}: use butt, fillet or lap")
    if seam not in paths:
        raise SensorError(f"unknown seam {seam!r}: use straight or sine")
    return Scene(joints[joint], paths[seam])


class Sensor:
    """Seam-tracking sensor: a :class:`CameraEmulator` plus a clock, the software trigger
    counter and the latest reading. ``after_acquire`` is called with every reading (e.g. to
    step a simulated clock to ``t_done``). ``keep_truth`` fills
    :attr:`Reading.truth_seam2sensor` (the scene's true seam pose) in every reading."""

    def __init__(
        self,
        emulator: CameraEmulator,
        *,
        clock: Clock,
        after_acquire: Callable[[Reading], None] | None = None,
        keep_truth: bool = False,
    ) -> None:
        self.emulator = emulator
        self.clock = clock
        self.after_acquire = after_acquire
        self.keep_truth = keep_truth
        self._lock = threading.RLock()
        self._latest: Reading | None = None
        self._busy_until = -math.inf
        self.frames = 0
        self._software_index = 0

    # --- settings ---------------------------------------------------------------------------

    @property
    def scene(self) -> Scene:
        return self.emulator.scene

    @property
    def width(self) -> int:
        return self.emulator.camera.columns

    @property
    def height(self) -> int:
        return self.emulator.camera.rows

    @property
    def settings(self) -> SensorSettings:
        s = self.emulator.settings
        return SensorSettings(self.emulator.laser_on, s.exposure_s, s.first_column, s.n_columns)

    def acquisition_time(self) -> float:
        """Readout time of the current window (s): 3.5 ms for 512 columns, proportional to
        the number of columns [SS-5.7]."""
        return self.emulator.acquisition_time()

    def set_laser(self, on: bool) -> None:
        with self._lock:
            self.emulator.set_laser(bool(on))

    def set_exposure(self, exposure_s: float) -> None:
        """Exposure time of one column (s) [SS-5.6]."""
        with self._lock:
            try:
                self.emulator.configure(exposure_s=exposure_s)
            except SettingsError as exc:
                raise SensorError(str(exc)) from None

    def set_readout_window(self, first_column: int, columns: int) -> float:
        """Read only columns first..first+columns-1; returns the acquisition time (s)
        [SS-5.6]."""
        with self._lock:
            try:
                self.emulator.configure(first_column=first_column, n_columns=columns)
            except SettingsError as exc:
                raise SensorError(str(exc)) from None
            return self.acquisition_time()

    # --- acquisition ------------------------------------------------------------------------

    @property
    def latest(self) -> Reading | None:
        return self._latest

    def busy(self, t_arrival: float) -> bool:
        """True when a trigger at ``t_arrival`` would wait more than one acquisition time for
        the chip (earlier exposures still run): the sensor answers OVERRUN [SY-2.8]."""
        return self._busy_until - t_arrival > self.acquisition_time()

    def next_software_index(self) -> int:
        with self._lock:
            index = self._software_index
            self._software_index += 1
            return index

    def acquire(
        self,
        t_arrival: float | None = None,
        *,
        index: int | None = None,
        t_trigger: float = math.nan,
    ) -> Reading:
        """Acquire and process one frame triggered at ``t_arrival`` (s, default: now).

        ``index``: the trigger index (default: the next software acquisition number).
        """
        with self._lock:
            t = self.clock() if t_arrival is None else float(t_arrival)
            if index is None:
                index = self.next_software_index()
            frame = self.emulator.acquire(t)
            self._busy_until = max(self._busy_until, frame.acquisition.t_exposure_end)
            reading = self._reading(index, t_trigger, frame)
            self._latest = reading
            self.frames += 1
        if self.after_acquire is not None:
            self.after_acquire(reading)
        return reading

    def _reading(self, index: int, t_trigger: float, frame: Frame) -> Reading:
        m = self.emulator.measure(frame)
        acq = frame.acquisition
        if not frame.laser_on:
            status = SensorStatus.LASER_OFF  # [SS-5.8] laser off: no seam
        elif m.found:
            status = SensorStatus.FOUND
        elif m.status is SeamStatus.BAD_IMAGE:
            status = SensorStatus.ERROR
        else:
            status = SensorStatus.NOT_FOUND
        if status is SensorStatus.FOUND:
            g2s = np.asarray(m.seam2sensor, dtype=np.float64)
            loc = transform_to_location(g2s)  # the scalar form: one matrix, ~6 µs
            seam = (
                float(loc[0]), float(loc[1]), float(loc[2]),
                float(loc[3]), float(loc[4]), float(loc[5]),
            )  # fmt: skip
            quality = m.quality
        else:
            g2s = np.full((4, 4), np.nan)
            seam = NAN_LOCATION
            quality = 0.0
        truth = None
        if self.keep_truth:
            t_truth = (
                m.t_seam
                if status is SensorStatus.FOUND and math.isfinite(m.t_seam)
                else (0.5 * (acq.t_exposure_start + acq.t_exposure_end))
            )
            truth = self.scene.seam2sensor(self.emulator.sensor2base(np.array([t_truth])))[0]
        image = frame.image
        image.setflags(write=False)
        return Reading(
            index=index,
            status=status,
            seam2sensor=g2s,
            seam=seam,
            quality=float(quality),
            t_trigger=float(t_trigger),
            t_arrival=acq.t_arrival,
            t_exposure_start=acq.t_exposure_start,
            t_exposure_end=acq.t_exposure_end,
            t_done=acq.t_done,
            frame=image,
            points=np.asarray(m.points, dtype=np.float64).reshape(-1, 3),
            truth_seam2sensor=truth,
            detector_status=str(m.status),
        )


def build_sensor(
    *,
    joint: str = "butt",
    seam: str = "straight",
    motion: str = "fixed",
    seed: int = 0,
    clock: Clock,
    timing: TimingModel | None = None,
    after_acquire: Callable[[Reading], None] | None = None,
    keep_truth: bool = False,
) -> Sensor:
    """A standalone sensor over a standard scene (see :func:`make_scene`, :func:`motion_pose`);
    ``keep_truth`` as for :class:`Sensor`."""
    scene = make_scene(joint, seam)
    rng = np.random.default_rng(seed)
    pose = motion_pose(scene, motion, t0=clock())
    timing = timing if timing is not None else TimingModel(rng=rng)
    emulator = CameraEmulator(scene, pose, timing, rng=rng)
    return Sensor(emulator, clock=clock, after_acquire=after_acquire, keep_truth=keep_truth)


__all__ = [
    "Clock",
    "Reading",
    "Sensor",
    "SensorError",
    "SensorSettings",
    "SimClock",
    "build_sensor",
    "make_scene",
    "motion_pose",
]
