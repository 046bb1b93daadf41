"""``python -m gof_warp.synthetic``: render a synthetic scene with exact ground truth. The command lives in
:mod:`gof_warp.cli.common.synthetic`."""

import sys

from ..cli.synthetic import main

if __name__ == "__main__":
    sys.exit(main())
