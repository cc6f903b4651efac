"""The operator console (the paper's 24-Laser, section III-C) as a web application.

``python -m welding console --emulate`` serves it; :mod:`welding.console.backend` holds the
robot and sensor connections, :mod:`welding.console.app` is the Starlette application and
``static/`` the page. Needs the optional ``console`` extra; the servers never import it.
"""
