"""``python -m gof_warp.inspect``: what gof_warp makes of a scene folder. The command lives in :mod:`gof_warp.cli.common.inspect_scene`."""

import sys

from .cli.inspect_scene import *  # noqa: F401,F403 - the command's public names, where they were first importable
from .cli.inspect_scene import main

if __name__ == "__main__":
    sys.exit(main())
