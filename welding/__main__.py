"""``python -m welding``: see :mod:`welding.cli`."""

from __future__ import annotations

import sys

from spec import cliargs
from welding.cli import main

__all__ = ["main"]  # python -m welding's entry point, which tests call as welding.__main__.main

if __name__ == "__main__":
    sys.exit(cliargs.run_cli(main))
