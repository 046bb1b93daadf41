"""``python -m gof_warp.bench``: benchmark suites. The command lives in :mod:`gof_warp.cli.common.bench`."""

import sys

from .cli.bench import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.bench import main

if __name__ == "__main__":
    sys.exit(main())
