"""``python -m gof_warp.train``: training. The command lives in :mod:`gof_warp.cli.common.train`."""

import sys

from .cli.train import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.train import main

if __name__ == "__main__":
    sys.exit(main())
