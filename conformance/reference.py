"""Our own reference servers, started in-process when no endpoint is given.

The imports of robotsocket and sensorsocket are lazy and live only here: the cases never
import them (they drive endpoints through the public protocol only). When a package is not
installed or fails to start, :class:`ReferenceUnavailable` says why (exit code 1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass


class ReferenceUnavailable(RuntimeError):
    """The reference server for a service cannot be started here."""


@dataclass
class Reference:
    """A running in-process reference endpoint: its address and how to stop it."""

    host: str
    port: int
    stop: Callable[[], None]


def start(service: str) -> Reference:
    """Start the reference robot or sensor server (TCP) or sensor trigger listener (UDP)."""
    try:
        if service == "robot":
            return _robot()
        if service == "sensor":
            return _sensor()
        if service == "sync":
            return _sync()
    except ImportError as exc:
        raise ReferenceUnavailable(
            f"no endpoint given and the reference {service} implementation is not importable"
            f" ({exc}); pass HOST:PORT"
        ) from None
    except Exception as exc:  # noqa: BLE001  fault barrier: any start failure is one message
        raise ReferenceUnavailable(
            f"the reference {service} server failed to start: {type(exc).__name__}: {exc}"
        ) from None
    raise ReferenceUnavailable(f"unknown service {service!r}")


def _robot() -> Reference:
    from robotsocket.emulator import RobotEmulator
    from robotsocket.service import RobotService
    from robotsocket.sync_service import attach_udp_sync
    from spec.server import FramedServer

    robot = RobotEmulator("RX90B", clock="real")
    service = RobotService(robot)
    _, endpoint = attach_udp_sync(service, robot, host="127.0.0.1")
    server = FramedServer(service, "127.0.0.1", 0)
    robot.start()
    endpoint.start()
    server.start()

    def stop() -> None:
        server.shutdown()
        endpoint.stop()
        robot.close()

    return Reference(server.address[0], server.address[1], stop)


def _sensor() -> Reference:
    from sensorsocket.sensor import build_sensor
    from sensorsocket.service import SensorService
    from spec.server import FramedServer

    sensor = build_sensor(clock=time.monotonic)
    sensor.acquire()  # a first measurement, so GetData, GetImage and GetProfile can be checked
    server = FramedServer(SensorService(sensor), "127.0.0.1", 0)
    server.start()
    return Reference(server.address[0], server.address[1], server.shutdown)


def _sync() -> Reference:
    from sensorsocket.sensor import build_sensor
    from sensorsocket.udp import TriggerHandler, TriggerListener

    sensor = build_sensor(clock=time.monotonic)
    listener = TriggerListener(TriggerHandler(sensor), "127.0.0.1", 0, clock=time.monotonic)
    listener.start()
    return Reference(listener.address[0], listener.address[1], listener.stop)
