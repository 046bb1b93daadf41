"""What every ``python -m gof_warp.<command>`` shares: output set-up and the error contract.

A command's user sees ``error: <message>`` (exit code 2, no traceback) for anything that is the input's
fault (:class:`~gof_warp.errors.GofError`), and a short note (exit code 130) on Ctrl-C; every file the
commands write is written atomically, so an interrupted command leaves nothing half-written.
"""

from __future__ import annotations

import logging
import sys
from typing import Callable


def configure_output(quiet: bool = False) -> None:
    """Log progress at INFO (WARNING when ``quiet``); silence Warp's start-up banner and module-load lines."""
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, format="%(message)s")
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING


def run_command(body: Callable[[], int | None], interrupted_note: str = "") -> int:
    """Run a command's body and map its failures to exit codes (0 ok, 2 bad input, 130 interrupted)."""
    from .errors import GofError

    try:
        rc = body()
    except GofError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted{': ' + interrupted_note if interrupted_note else ''}", file=sys.stderr)
        return 130
    return 0 if rc is None else int(rc)
