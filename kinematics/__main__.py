"""``python -m kinematics``: see ``kinematics.cli``."""

from __future__ import annotations

from kinematics.cli import main
from spec.cliargs import run_cli

raise SystemExit(run_cli(main))
