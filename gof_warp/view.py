"""``python -m gof_warp.view``: the live viewer. The command lives in :mod:`gof_warp.cli.common.view`."""

import sys

from .cli.view import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.view import main

if __name__ == "__main__":
    sys.exit(main())
