"""``python -m kinematics``: see ``kinematics.cli``."""

from __future__ import annotations

from kinematics.cli import main

raise SystemExit(main())
