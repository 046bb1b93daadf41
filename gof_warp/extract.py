"""``python -m gof_warp.extract``: mesh extraction. The command lives in :mod:`gof_warp.cli.common.extract`."""

import sys

from .cli.extract import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.extract import main

if __name__ == "__main__":
    sys.exit(main())
