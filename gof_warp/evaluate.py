"""``python -m gof_warp.evaluate``: mesh scores. The command lives in :mod:`gof_warp.cli.common.evaluate`."""

import sys

from .cli.evaluate import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.evaluate import main

if __name__ == "__main__":
    sys.exit(main())
