"""Ctrl-C or SIGTERM during a long loop: finish the current iteration, then stop cleanly.

:func:`deferred_interrupt` is what :meth:`gof_warp.training.trainer.Trainer.run` wraps its loop in, so that an
interrupted run writes a checkpoint of a whole iteration instead of dying half-way through one. SIGTERM (what
job schedulers and ``kill`` send) is handled like Ctrl-C.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from pathlib import Path


class _Pressed:
    """``pressed() -> bool``: whether a deferred signal came; ``signum``: the first one's number (None: none)."""

    def __init__(self):
        self.signum: int | None = None

    def __call__(self) -> bool:
        return self.signum is not None


@contextlib.contextmanager
def deferred_interrupt():
    """Within: the first Ctrl-C (SIGINT) or SIGTERM only raises a flag, which the loop checks at the end of each
    iteration; a second one acts at once, as usual (Ctrl-C raises KeyboardInterrupt, SIGTERM ends the process).
    Yields ``pressed() -> bool``, whose ``signum`` is the signal that came.

    Each signal only where its default handler is installed (Python's own for SIGINT, ``SIG_DFL`` for SIGTERM)
    and in the main thread (signal handlers can be set nowhere else); otherwise it is left alone. The previous
    handlers are restored on exit.
    """
    pressed = _Pressed()
    if threading.current_thread() is not threading.main_thread():
        yield pressed
        return
    defaults = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL}
    mine = [s for s, default in defaults.items() if signal.getsignal(s) is default]

    def on_signal(signum, frame):
        if pressed.signum is None:
            pressed.signum = signum
        signal.signal(signum, defaults[signum])  # the next one of the same signal acts at once

    for s in mine:
        signal.signal(s, on_signal)
    try:
        yield pressed
    finally:
        for s in mine:
            signal.signal(s, defaults[s])


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped :meth:`Trainer.run` at the end of an iteration.

    Attributes:
        iteration: the last iteration completed.
        total: the run's ``config.iterations``.
        checkpoint: the checkpoint holding ``iteration`` (written at the interrupt), or the newest older
            one when it could not be written; None when the run has none.
        signum: the signal that stopped it (``signal.SIGINT`` or ``signal.SIGTERM``).
    """

    def __init__(self, iteration: int, total: int, checkpoint: Path | None, signum: int = signal.SIGINT):
        super().__init__(f"training interrupted at iteration {iteration} of {total}")
        self.iteration, self.total, self.checkpoint, self.signum = iteration, total, checkpoint, int(signum)
