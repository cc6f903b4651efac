"""The simulated cell's UDP trigger/data link of section V, run on the robot's 4 ms cycle
(pure: no sockets; the modelled network is :class:`~sync.network.DelayLink`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cell.timing import CellTiming
from sensorsocket.sensor import Sensor
from sensorsocket.udp import TriggerHandler
from sync.network import DelayLink
from sync.udp import RobotSyncCore

__all__ = ["SimTransport", "SimulatedLink"]


class SimTransport:
    """Trigger transport of the simulated cell: remembers the target; the cell's cycle hook
    sends through the modelled link."""

    def __init__(self) -> None:
        self.target: tuple[str, int] | None = None

    def set_target(self, host: str, port: int) -> None:
        self.target = (host, port)

    def wake(self) -> None:
        pass


class SimulatedLink:
    """Every 4 ms cycle: the robot's due triggers through the modelled network (``uplink``)
    to the sensor's trigger handler, once the arm's motion over the exposure is known; the
    data datagrams back (``downlink``) to the robot's sync core and its matcher.

    Args:
        core: the robot's sync core (triggers out, data in).
        handler: the sensor's trigger handler.
        sensor: the sensor (its settings decide how far ahead motion must be known).
        timing: the cell's timing (network delay and jitter, trigger-to-exposure delays).
        port: the sensor's UDP port; triggers sent to another port go nowhere.
        rng: draws the uplink's network jitter.
    """

    def __init__(
        self,
        core: RobotSyncCore,
        handler: TriggerHandler,
        sensor: Sensor,
        timing: CellTiming,
        port: int,
        rng: np.random.Generator,
    ) -> None:
        self.core = core
        self.handler = handler
        self.sensor = sensor
        self.timing = timing
        self.port = port
        self.uplink = DelayLink(
            delay_s=timing.network_delay_s, jitter_s=timing.network_jitter_s, rng=rng
        )
        self.downlink = DelayLink()  # the handler already adds the reply's network delay
        self.transport = SimTransport()

    def cycle(self, t: float, q_measured: NDArray[np.float64]) -> None:
        """The link's work of the robot cycle at time ``t`` s with measured joints (6,)."""
        core = self.core
        core.add_joint(t, q_measured)
        target = self.transport.target
        # Triggers for another port go nowhere, as on a real network.
        reachable = target is not None and target[1] == self.port
        for index, t_send in core.due_triggers(t):
            data = core.sent(index, t_send)
            if reachable:
                self.uplink.send(t_send, data)
        # The sensor may acquire once the arm's motion over the whole exposure is known.
        s = self.sensor.settings
        horizon = (
            1.0 / self.timing.poll_rate_hz
            + self.timing.start_jitter_s
            + self.timing.start_latency_s
            + self.sensor.acquisition_time()
            + s.exposure_s
        )
        for t_arrival, datagram in self.uplink.deliver(t - horizon):
            reply = self.handler.process(datagram, t_arrival)
            if reply is not None:
                self.downlink.send(reply.t_send, reply.data)
        for t_arrival, datagram in self.downlink.deliver(t):
            core.on_datagram(datagram, t_arrival)
        core.poll(t)
