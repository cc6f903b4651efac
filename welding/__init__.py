"""The welding application (24-Laser, paper section III-C): jobs, the tool and frame
database, job processing through RobotSocket and seam teaching with SensorSocket.

It reaches the robot and the sensor only through :class:`robotsocket.client.RobotClient`,
:class:`sensorsocket.client.SensorClient` and :mod:`sync`, so it works against any
conforming endpoints; only the ``--emulate`` paths of the command line build a :mod:`cell`
(:mod:`welding.emulate`).

Modules: :mod:`~welding.job` (model, XML, schema ``job.xsd``), :mod:`~welding.xmlsafe`
(the safe reader), :mod:`~welding.tools` (the database), :mod:`~welding.process` (plan and
runner), :mod:`~welding.teach` (seam teaching), :mod:`~welding.cli` (``python -m welding``).

Where the later parts sit: real-time tracking runs a path's welding steps (the pure plan of
:func:`~welding.process.plan`) with corrections from the sync seam chain instead of the taught
points; tool calibration measures and writes ^N_L T / ^N_S T with
``ToolDB.update(..., expect_revision=n)``; the browser console drives the same library
(``JobRunner.on_progress``, the JSON run log, the database revision for concurrent editors).
"""
