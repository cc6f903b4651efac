"""Iterative learning control (the 24-Laser's ILC DLL, paper ref. [10]), pure: the lifted
model of the arm, the zero-phase Q-filter, the learning update, Norrlöf's convergence check
and the learned table's file.

Lifted form (Hakvoort et al., on the same RX90): one pass of N cycles is one vector. The
correction u (N x 3, the laser tool's translation in the base frame, mm) the robot adds to
its path, one entry per 4 ms cycle of the move (AlterQueue, PROTOCOL.md RS-5.39), moves the
laser by y = G u, with G (3N x 3N) lower block-triangular: each axis' response to a
setpoint pulse (:func:`kinematics.dynamics.simulate` of the application's model of the
arm), mapped through the Jacobian of the pass (a correction Δp becomes joint offsets
J⁻¹ Δp, each axis answers with its own dynamics, the laser moves by J Δq). The error of
trial j, e_j = reference − measured, teaches the next correction:

    u_{j+1} = Q (u_j + L e_j),   L = γ (GᵀWG + βI)⁻¹ GᵀW

with W the cycles where the error was measured (the laser window; the sensor cannot see
along the seam). Q is a zero-phase low-pass (forward and backward through a causal
second-order filter): it keeps what the model does not know (resonances, noise) out of
the learning. Norrlöf's criterion |Q(1 − L·G)| < 1 over the frequencies, in lifted form the
largest singular value of Q(I − LG), decides before the first trial whether the learning
converges (monotonically, for the model); :func:`check_convergence` gives it with the
spectral radius (converges at all: < 1).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kinematics.dynamics import ElasticParams, link_inertia, simulate
from kinematics.types import FloatArray
from spec.files import write_atomically

__all__ = [
    "Convergence",
    "IlcTable",
    "LearningDiverges",
    "check_convergence",
    "ilc_update",
    "learning_matrix",
    "lever_error",
    "lifted_model",
    "lifted_model_along",
    "q_filter",
]


#: Version of the table file.
TABLE_VERSION = 1


class LearningDiverges(ValueError):
    """Norrlöf's criterion fails for the model: the learning would diverge."""


def axis_pulse_responses(
    params: ElasticParams, jl: FloatArray, n: int, period: float, *, latency_s: float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Responses (..., n, 6) of the link and of the measured motor (delayed by
    ``latency_s``, linearly between cycles as the robot's joint log is) of each axis to a
    setpoint pulse of 1 rad in the first cycle, at the end of each cycle from that one on;
    ``jl`` (..., 6) the link inertias (one arm per leading index)."""
    jl = np.asarray(jl, dtype=np.float64)
    r = np.zeros((*jl.shape[:-1], n + 1, 6))
    r[..., 1, :] = 1.0
    motor, link = simulate(params, jl[..., None, :], r, period=period)
    if latency_s > 0.0:
        shift = latency_s / period
        whole = math.floor(shift)
        w = shift - whole
        padded = np.concatenate([np.zeros((*jl.shape[:-1], whole + 1, 6)), motor], axis=-2)
        motor = (1.0 - w) * padded[..., 1 : n + 1, :] + w * padded[..., :n, :]
    return link, motor


def lifted_model(
    params: ElasticParams,
    model: Any,
    q_deg: FloatArray,
    laser2flange: FloatArray,
    n: int,
    period: float,
    *,
    side: str = "link",
    latency_s: float = 0.0,
) -> FloatArray:
    """G (3N, 3N), rows and columns ordered (cycle, axis x/y/z): the laser's translation
    (mm, base frame) at each cycle of the pass for a unit translation correction at each
    cycle, linearised at joints ``q_deg`` (6,) (a :class:`~kinematics.robot.RobotModel`
    ``model``, the laser tool ``laser2flange`` (4, 4)). ``side``: ``link`` (where the laser
    truly is) or ``motor`` (what the measured joints say, ``latency_s`` late)."""
    if side not in ("link", "motor"):
        raise ValueError(f"side must be link or motor, got {side!r}")
    jl = link_inertia(model, q_deg, params)
    link, motor = axis_pulse_responses(params, jl, n, period, latency_s=latency_s)
    h = link if side == "link" else motor
    J = model.jacobian(q_deg, tool=laser2flange)  # mm/rad and rad/rad, base frame
    Jinv = np.linalg.inv(J)
    toeplitz = _toeplitz(h)  # (6, n, n)
    G = np.zeros((3 * n, 3 * n))
    for i in range(6):
        # a translation Δp (orientation kept) asks axis i for Jinv[i, :3]·Δp rad; axis i
        # moves the laser by J[:3, i] per rad
        mix = np.outer(J[:3, i], Jinv[i, :3])
        G += np.kron(toeplitz[i], mix)
    return G


def lever_error(
    params: ElasticParams,
    model: Any,
    q_cmd_deg: FloatArray,
    laser2flange: FloatArray,
    sensor2flange: FloatArray,
    period: float,
) -> FloatArray:
    """The model's laser error less its sensor's (N, 3) mm, base frame, at the end of each
    of the N cycles of a pass commanded through joints ``q_cmd_deg`` (N + 1, 6) deg, from
    rest at the first (:func:`kinematics.dynamics.simulate`, the link inertia of each
    cycle's pose): (R_link − R_cmd)·(laser − sensor), the flange's turn off its command
    acting on the lever between the two tools (flange frame, ``laser2flange`` and
    ``sensor2flange`` (4, 4)). The sensor measures where it went; the laser, 40 mm behind
    it on the same flange, went there too only where the tool did not turn."""
    q = np.asarray(q_cmd_deg, dtype=np.float64)
    jl = np.array([link_inertia(model, qk, params) for qk in q[1:]])
    _, link = simulate(params, jl, np.radians(q), period=period)
    turned = model.flange2base_batch(np.degrees(link))[:, :3, :3]
    commanded = model.flange2base_batch(q[1:])[:, :3, :3]
    lever = laser2flange[:3, 3] - sensor2flange[:3, 3]
    out: FloatArray = (turned - commanded) @ lever
    return out


def lifted_model_along(
    params: ElasticParams,
    model: Any,
    q_deg: FloatArray,
    laser2flange: FloatArray,
    period: float,
    *,
    side: str = "link",
    latency_s: float = 0.0,
    block: int | None = None,
) -> FloatArray:
    """The time-varying G (3N, 3N) of a pass whose cycle k has the arm at joints ``q_deg``
    (N, 6), ordered as :func:`lifted_model`: a translation Δp at cycle m asks the axes for
    J(q_m)⁻¹ Δp, each axis answers with its pulse response h_i, and the laser moves by
    J(q_k) δq at cycle k:

        G[k, m] = Σ_i h_i^(m)(k − m) · J_k[:3, i] ⊗ J_m⁻¹[i, :3]

    (the linear time-varying model of ref. [10]). h_i^(m) is for the link inertia at the
    middle cycle of the pass, or with ``block`` at the middle of m's block of that many
    cycles. With one pose throughout it is :func:`lifted_model`'s G."""
    if side not in ("link", "motor"):
        raise ValueError(f"side must be link or motor, got {side!r}")
    q = np.asarray(q_deg, dtype=np.float64)
    n = len(q)
    J = np.array([model.jacobian(qk, tool=laser2flange) for qk in q])  # (N, 6, 6)
    Jinv = np.linalg.inv(J)
    block = block or n
    mids = np.minimum(np.arange(0, n, block) + block // 2, n - 1)
    jl = np.array([link_inertia(model, q[m], params) for m in mids])  # (B, 6)
    link, motor = axis_pulse_responses(params, jl, n, period, latency_s=latency_s)
    h = link if side == "link" else motor  # (B, N, 6)
    k = np.arange(n)
    lag = k[:, None] - k[None, :]
    # T[k, m, i]: axis i's response at k to a pulse at m (m's block's inertia)
    T = np.where((lag >= 0)[..., None], h[(k // block)[None, :], np.clip(lag, 0, n - 1)], 0.0)
    G4 = np.einsum("kmi,kai,mib->kamb", T, J[:, :3, :], Jinv[:, :, :3], optimize=True)
    out: FloatArray = G4.reshape(3 * n, 3 * n)
    return out


def _toeplitz(h: FloatArray) -> FloatArray:
    """Lower-triangular Toeplitz matrices (6, n, n) of the responses h (n, 6)."""
    n = h.shape[0]
    k = np.arange(n)
    lag = k[:, None] - k[None, :]
    T = np.where(lag[None] >= 0, h.T[:, np.clip(lag, 0, n - 1)], 0.0)
    return T


def q_filter(n: int, cutoff_hz: float, period: float, channels: int = 3) -> FloatArray:
    """The zero-phase Q (channels·N square, same ordering as :func:`lifted_model`): a
    critically damped second-order low-pass of ``cutoff_hz`` run forward, then backward
    (Fᵀ F): no phase, |Q| = |F|² <= 1, unit gain at 0 Hz away from the pass's end."""
    if not (0.0 < cutoff_hz < 0.5 / period):
        raise ValueError(f"Q cutoff must be in (0, {0.5 / period:g}) Hz, got {cutoff_hz}")
    # discrete critically damped pole pair from the continuous one (matched z)
    p = math.exp(-2.0 * math.pi * cutoff_hz * period)
    # y_k = 2p y_{k-1} - p^2 y_{k-2} + (1 - p)^2 x_k
    h = np.zeros(n)
    y1 = y2 = 0.0
    for k in range(n):
        x = 1.0 if k == 0 else 0.0
        y = 2 * p * y1 - p * p * y2 + (1 - p) ** 2 * x
        h[k] = y
        y2, y1 = y1, y
    F = _toeplitz(np.repeat(h[:, None], 6, axis=1))[0]
    # not rescaled at the end of the pass (where the backward run starts, it sees part of
    # its window): |F| <= 1 keeps the lifted norm of Q <= 1, so the cycles nothing is
    # learned on fade instead of growing
    return np.kron(F.T @ F, np.eye(channels))


def learning_matrix(G: FloatArray, gain: float, weights: FloatArray, beta: float) -> FloatArray:
    """L = γ (GᵀWG + βI)⁻¹ GᵀW for cycle weights ``weights`` (3N,) (1 measured, 0 not)."""
    if not (math.isfinite(gain) and gain > 0.0):
        raise ValueError(f"the learning gain must be > 0, got {gain}")
    GW = G.T * weights[None, :]
    A = GW @ G + beta * np.eye(G.shape[1])
    out: FloatArray = np.asarray(gain * np.linalg.solve(A, GW), dtype=np.float64)
    return out


def ilc_update(
    u: FloatArray, e: FloatArray, Q: FloatArray, L: FloatArray, weight: float = 1.0
) -> FloatArray:
    """The next correction (lifted): ``weight`` (0..1] of the way from ``u`` to
    Q(u + L e). Weight 1 is the learning law above; a smaller one averages the updates
    (:attr:`welding.ilc_loop.IlcSettings.average_from`). Its loop has the fixed point of
    the law's and the norm |(1 − w)I + w·Q(I − LG)| <= (1 − w) + w·|Q(I − LG)|, so where
    Norrlöf's criterion holds for the law it holds for every weight."""
    if not (0.0 < weight <= 1.0):
        raise ValueError(f"the update's weight must be in (0, 1], got {weight}")
    target = Q @ (u + L @ e)
    out: FloatArray = u + weight * (target - u)
    return out


@dataclass(frozen=True)
class Convergence:
    """Norrlöf's criterion for the model: ``norm`` = max singular value of Q(I − LG)
    (< 1: the error of the model converges monotonically), ``radius`` = its spectral radius
    (< 1: the learning converges at all), and the largest |Q(1 − L·G)| over the frequency
    grid of the pass (the frequency-domain form, from the middle of the pass)."""

    norm: float
    radius: float
    frequency_max: float

    @property
    def converges(self) -> bool:
        return self.norm < 1.0

    def summary(self) -> dict[str, float | bool]:
        return {
            "norm": self.norm,
            "spectral_radius": self.radius,
            "frequency_max": self.frequency_max,
            "converges": self.converges,
        }


def check_convergence(
    Q: FloatArray, L: FloatArray, G: FloatArray, channels: int = 3
) -> Convergence:
    """The convergence of u_{j+1} = Q (u_j + L (r − G u_j)) (see :class:`Convergence`) for
    lifted matrices of ``channels`` interleaved channels."""
    M = Q @ (np.eye(G.shape[0]) - L @ G)
    norm = float(np.linalg.norm(M, 2))
    radius = float(np.abs(np.linalg.eigvals(M)).max())
    return Convergence(norm, radius, _frequency_max(M, channels))


def _frequency_max(M: FloatArray, c: int) -> float:
    """max over frequencies of the gain of M around the middle of the pass: the response
    of M's middle columns to e^{iωk}, per channel (the LTI reading of the lifted matrix)."""
    n = M.shape[0]
    cycles = n // c
    k = np.arange(cycles)
    worst = 0.0
    mid = slice(cycles // 4, 3 * cycles // 4)
    for f in np.linspace(0.0, 0.5, 65)[1:]:
        wave = np.exp(2j * math.pi * f * k)
        for ch in range(c):
            x = np.zeros(n, dtype=complex)
            x[ch::c] = wave
            y = (M @ x)[ch::c][mid]
            worst = max(worst, float(np.abs(y).max()))
    return worst


@dataclass
class IlcTable:
    """The learned correction of one pass: ``correction`` (N, 3) mm, base frame, at cycle k
    of the move (k·``period`` s after its start); ``seam`` the seam taught, rows (arc
    length along the nominal line mm, offset from it (3,) mm, base frame), which the laser
    follows (empty: the nominal line, a tracked pass); and what it was learned for: ``key``
    names a job's pass (its line in the base frame, ``""`` the cell's own pass), so a table
    is not reused on a path that moved. ``seen``: where the sensor read the seam off the
    taught one in the last trial learned from (rows (arc length, offset (3,)); empty: none
    yet): the arm's repeatable error where the sensor looks, 40 mm ahead of the laser, which
    a tracked weld with the table must not take for the workpiece's
    (:attr:`welding.tracking.Tracker.expected`)."""

    period: float
    speed_mm_s: float
    correction: FloatArray
    seam: FloatArray
    source: str
    trials: int
    key: str = ""
    seen: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))

    def offsets(self, s: FloatArray) -> FloatArray:
        """The taught seam's offsets (M, 3) at arc lengths ``s`` (M,), linear between its
        rows, its ends held; zero without a taught seam."""
        s = np.asarray(s, dtype=np.float64)
        if not len(self.seam):
            return np.zeros((len(s), 3))
        return np.column_stack(
            [np.interp(s, self.seam[:, 0], self.seam[:, 1 + c]) for c in range(3)]
        )

    def save(self, path: str | Path) -> None:
        """Write atomically (JSON)."""
        data = {
            "version": TABLE_VERSION,
            "period": self.period,
            "speed_mm_s": self.speed_mm_s,
            "source": self.source,
            "trials": self.trials,
            "correction": np.round(self.correction, 9).tolist(),
            "seam": np.round(self.seam, 9).tolist(),
            "pass": self.key,
            "seen": np.round(self.seen, 9).tolist(),
        }
        write_atomically(path, json.dumps(data) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> IlcTable:
        """ValueError naming the file when it is not a table of this version."""
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
            if data.get("version") != TABLE_VERSION:
                raise ValueError(f"version {data.get('version')!r}, not {TABLE_VERSION}")
            table = cls(
                float(data["period"]),
                float(data["speed_mm_s"]),
                np.array(data["correction"], dtype=np.float64).reshape(-1, 3),
                np.array(data["seam"], dtype=np.float64).reshape(-1, 4),
                str(data["source"]),
                int(data["trials"]),
                str(data.get("pass", "")),
                # absent in a table written before the field existed: none seen
                np.array(data.get("seen", []), dtype=np.float64).reshape(-1, 4),
            )
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"{path}: not an ILC table ({exc})") from None
        rows = (table.seam, table.seen)
        ok = np.all(np.isfinite(table.correction)) and all(np.all(np.isfinite(r)) for r in rows)
        if not ok or any(len(r) > 1 and not np.all(np.diff(r[:, 0]) > 0) for r in rows):
            raise ValueError(f"{path}: not an ILC table (bad correction or seam)")
        return table
