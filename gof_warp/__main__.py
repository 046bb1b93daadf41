"""``python -m gof_warp <command> [args]``: the same as ``gof-warp <command> [args]``."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
