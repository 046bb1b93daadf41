"""``python -m gof_warp.pictures``: a run's pictures. The command lives in :mod:`gof_warp.cli.common.pictures`."""

import sys

from .cli.pictures import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.pictures import main

if __name__ == "__main__":
    sys.exit(main())
