"""The welding application (24-Laser, paper section III-C): jobs, the tool and frame
database, job processing through RobotSocket and seam teaching with SensorSocket.

It reaches the robot and the sensor only through :class:`robotsocket.client.RobotClient`,
:class:`sensorsocket.client.SensorClient` and :mod:`sync`, so it works against any
conforming endpoints; only the ``--emulate`` paths of the command line build a :mod:`cell`.
"""
