"""``python -m gof_warp.prepare``: camera poses for plain photos. The command lives in :mod:`gof_warp.cli.prepare`."""

import sys

from .cli.prepare import main

if __name__ == "__main__":
    sys.exit(main())
