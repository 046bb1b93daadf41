"""What every ``python -m gof_warp.<command>`` shares: output set-up and the error contract.

A command's user sees ``error: <message>`` (exit code 2, no traceback) for anything that is the input's
fault (:class:`~gof_warp.core.errors.GofError`), and a short note (exit code 130) on Ctrl-C; every file the
commands write is written atomically, so an interrupted command leaves nothing half-written.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Callable


def downscale_arg(text: str) -> int:
    """``--downscale``'s value: an integer >= 1 (argparse reports anything else as a usage error, exit 2)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1 or str(value) != text.strip().lstrip("+"):
        raise argparse.ArgumentTypeError(f"must be an integer >= 1 that divides the resolution (1: full size), "
                                         f"got {text!r}")
    return value


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The commands' ``--help`` layout: description and epilog printed as written (plain text, line breaks
    kept), and ``(default: X)`` after an option's help unless that help already states its default. A flag that
    takes no value is off unless given; an option whose default is None says in its help what None means."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (not action.option_strings or "default" in text.lower() or default is None
                or default is argparse.SUPPRESS or (action.nargs == 0 and default is False)):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


def configure_output(quiet: bool = False) -> None:
    """Log progress at INFO (WARNING when ``quiet``); silence Warp's start-up banner and module-load lines."""
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, format="%(message)s")
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING


def run_command(body: Callable[[], int | None],
                interrupted_note: str | Callable[[KeyboardInterrupt], str] = "") -> int:
    """Run a command's body and map its failures to exit codes (0 ok, 2 bad input, 130 interrupted; 143 where
    training stopped on SIGTERM, :class:`~gof_warp.training.interrupts.TrainingInterrupted` with its ``signum``).

    On Ctrl-C one line ``interrupted: <note>`` is printed; ``interrupted_note`` is that note, or a function
    of the ``KeyboardInterrupt`` (which may carry details, e.g. the iteration training reached) returning it.
    """
    from ..core.errors import GofError

    try:
        rc = body()
    except GofError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        note = interrupted_note(e) if callable(interrupted_note) else interrupted_note
        end_progress_line = "\n" if sys.stderr.isatty() else ""  # a progress line may be open
        print(f"{end_progress_line}interrupted{': ' + note if note else ''}", file=sys.stderr)
        return 128 + int(getattr(e, "signum", 2))  # 130 for Ctrl-C (SIGINT), 143 for a deferred SIGTERM
    return 0 if rc is None else int(rc)
