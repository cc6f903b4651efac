"""Timing laws s(t) of a move (its velocity profile), pure.

A move follows its geometric path q(s), s in [0, 1], by a timing law s(t). Laws are
trapezoidal in s: accelerate, cruise, decelerate (:class:`Trapezoid`, limits from
:mod:`robotsocket.paths`). Stopping turns a law into a deceleration from the current
(s, ds/dt) (:class:`Decel`), so the arm stops *on its path*, then :class:`Hold` keeps it there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from kinematics.types import FloatArray

__all__ = ["TIME_EPS_S", "Decel", "Hold", "Law", "Trapezoid", "ended"]

#: Times on the cycle grid compare within this (s): a cycle's k·period and a law's end
#: summed another way (t0 + ta + tc + td) differ in the last bits, and a move whose end falls
#: on a cycle must end on it, not one cycle later (which shifts the next move by 4 ms: a
#: timed path's corrections then land a cycle off). Far below a cycle, far above the
#: rounding of a day of robot time (1e-11 s).
TIME_EPS_S = 1e-9


def ended(t: float, t_end: float) -> bool:
    """Whether a law ending at ``t_end`` has ended at the cycle time ``t``."""
    return t >= t_end - TIME_EPS_S


class Law(Protocol):
    @property
    def t_end(self) -> float:
        """Time (s) from which the law stands still."""
        ...

    def at(self, t: float) -> tuple[float, float]:
        """(s, ds/dt) at time t (s)."""
        ...

    def s_array(self, t: FloatArray) -> FloatArray: ...


@dataclass(frozen=True)
class Trapezoid:
    """From rest at s0 (time t0) to rest at s = 1: accelerate with ``acc``, cruise at most
    ``vmax``, decelerate with ``dec`` (all in 1/s, 1/s^2)."""

    t0: float
    s0: float
    vmax: float
    acc: float
    dec: float
    vpeak: float = field(init=False)
    ta: float = field(init=False)
    tc: float = field(init=False)
    td: float = field(init=False)
    t_end: float = field(init=False)

    def __post_init__(self) -> None:
        dist = max(1.0 - self.s0, 0.0)
        vp = self.vmax
        if dist <= 0.0 or not math.isfinite(vp):
            vp = 0.0  # nothing to do, or no limit at all: jump at once
        elif vp * vp * (0.5 / self.acc + 0.5 / self.dec) > dist:
            vp = math.sqrt(2.0 * dist * self.acc * self.dec / (self.acc + self.dec))
        ta = vp / self.acc if vp > 0 else 0.0
        td = vp / self.dec if vp > 0 else 0.0
        tc = (dist - 0.5 * vp * ta - 0.5 * vp * td) / vp if vp > 0 else 0.0
        object.__setattr__(self, "vpeak", vp)
        object.__setattr__(self, "ta", ta)
        object.__setattr__(self, "tc", max(tc, 0.0))
        object.__setattr__(self, "td", td)
        object.__setattr__(self, "t_end", self.t0 + ta + max(tc, 0.0) + td)

    def at(self, t: float) -> tuple[float, float]:
        tau = t - self.t0
        vp = self.vpeak
        if tau <= 0.0:
            return self.s0, 0.0
        if t >= self.t_end:
            return 1.0, 0.0
        if tau < self.ta:
            return self.s0 + 0.5 * self.acc * tau * tau, self.acc * tau
        tau -= self.ta
        if tau < self.tc:
            return self.s0 + 0.5 * vp * self.ta + vp * tau, vp
        r = self.t_end - t  # time left
        return 1.0 - 0.5 * self.dec * r * r, self.dec * r

    def s_array(self, t: FloatArray) -> FloatArray:
        return np.array([self.at(float(x))[0] for x in t])


@dataclass(frozen=True)
class Decel:
    """Decelerate from (s0, v0) at t0 with ``dec`` until at rest."""

    t0: float
    s0: float
    v0: float
    dec: float
    t_end: float = field(init=False)
    s_end: float = field(init=False)

    def __post_init__(self) -> None:
        tb = self.v0 / self.dec if self.v0 > 0 else 0.0
        object.__setattr__(self, "t_end", self.t0 + tb)
        object.__setattr__(self, "s_end", min(self.s0 + 0.5 * self.v0 * tb, 1.0))

    def at(self, t: float) -> tuple[float, float]:
        if t >= self.t_end:
            return self.s_end, 0.0
        tau = max(t - self.t0, 0.0)
        return min(self.s0 + self.v0 * tau - 0.5 * self.dec * tau * tau, 1.0), self.v0 - (
            self.dec * tau
        )

    def s_array(self, t: FloatArray) -> FloatArray:
        return np.array([self.at(float(x))[0] for x in t])


@dataclass(frozen=True)
class Hold:
    """Stand still at s (after a StopMove)."""

    s: float
    t_end: float = -math.inf

    def at(self, t: float) -> tuple[float, float]:
        return self.s, 0.0

    def s_array(self, t: FloatArray) -> FloatArray:
        return np.full(len(t), self.s)
