"""Ctrl-C during a long loop: finish the current iteration, then stop cleanly.

:func:`deferred_interrupt` is what :meth:`gof_warp.trainer.Trainer.run` wraps its loop in, so that an
interrupted run writes a checkpoint of a whole iteration instead of dying half-way through one.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from pathlib import Path


@contextlib.contextmanager
def deferred_interrupt():
    """Within: the first Ctrl-C (SIGINT) only raises a flag, which the loop checks at the end of each
    iteration; a second Ctrl-C interrupts at once, as usual. Yields ``pressed() -> bool``.

    Only where Python's own SIGINT handler is installed and in the main thread (signal handlers can be set
    nowhere else); otherwise Ctrl-C is left alone and ``pressed`` is always False. The previous handler is
    restored on exit.
    """
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield lambda: False
        return
    pressed = []

    def on_sigint(signum, frame):
        pressed.append(signum)
        signal.signal(signal.SIGINT, signal.default_int_handler)  # the next Ctrl-C raises KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield lambda: bool(pressed)
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped :meth:`Trainer.run` at the end of an iteration.

    Attributes:
        iteration: the last iteration completed.
        total: the run's ``config.iterations``.
        checkpoint: the checkpoint holding ``iteration`` (written at the interrupt), or the newest older
            one when it could not be written; None when the run has none.
    """

    def __init__(self, iteration: int, total: int, checkpoint: Path | None):
        super().__init__(f"training interrupted at iteration {iteration} of {total}")
        self.iteration, self.total, self.checkpoint = iteration, total, checkpoint
