"""RobotSocket: the robot server of the framework, its robot API, emulator and client.

Modules: ``interface`` (abstract robot API), ``trajectory`` (pure 4 ms generator),
``clock`` (simulated and real-time clocks), ``emulator`` (RobotEmulator), ``service``
(registry commands -> robot API), ``client`` (RobotClient); CLI: ``python -m robotsocket``.
"""
