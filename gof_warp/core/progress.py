"""Progress of the commands: a training bar, per-stage reports and per-stage bars, with one rule.

**The rule.** When the output stream (default ``sys.stderr``) is a terminal (``stream.isatty()``) progress is
drawn with tqdm bars that refresh in place; otherwise (CI logs, files, pipes) it is written as plain lines —
no carriage returns, no ANSI codes — at most every ``interval`` seconds (5 s by default) plus a last line at
the end; with ``quiet=True`` nothing is written (errors and warnings go through ``logging`` as always).

**Training** (the trainer's ``progress(it, info)`` callback)::

    from gof_warp.core.progress import TrainingProgress

    with TrainingProgress(total=cfg.iterations, start=trainer.iteration, quiet=a.quiet) as progress:
        trainer.run(progress=progress)
    # terminal:  it  38%|███▊      | 456/1200 [00:41, ETA 01:07, 11.1it/s, loss 0.0412 psnr 27.31 N 8412]
    # a log:     it 456/1200 loss 0.0412 psnr 27.31 N 8412 11.1 it/s elapsed 0:41 ETA 1:07

**Stages of a multi-stage job** (extraction, bench runs)::

    from gof_warp.core.progress import Stages

    stages = Stages(quiet=a.quiet)             # one per command; pass it down to the library functions
    with stages.stage("delaunay"):             # terminal: a ticking "delaunay 0:12" line; a log: "delaunay ..."
        tets = delaunay(points)                # at the end, one line either way: "delaunay 12.3 s"
    with stages.stage("search"):
        with stages.bar(total=8, desc="step", unit="step") as bar:   # a bar inside the stage
            for k in range(8):
                refine(k)
                bar.update()                   # or bar.goto(n, postfix="...")
    stages.times                               # {"delaunay": 12.3, "search": 4.1}: seconds per stage

Stages may nest (``tetra › delaunay``); an inner stage's lines are indented. A library function
that takes ``stages=None`` can use :func:`as_stages` to get a silent one, so it needs no ``if`` around each
stage. While a bar or a stage line is live in a terminal, ``logging`` output is routed through
``tqdm.write`` so that log lines do not tear the bar (undone when the bar or the outermost stage ends). No
global state: each object owns its stream.
"""

from __future__ import annotations

import contextlib
import io
import sys
import threading
import time
from typing import Iterator, TextIO

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

PLAIN_INTERVAL = 5.0  # seconds between plain log lines (not a terminal)
TICK = 0.5  # seconds between refreshes of a stage's ticking line (terminal)
FALLBACK_WIDTH, FALLBACK_ROWS = 100, 24  # a terminal that does not say its size (tqdm would hide the bar)
BAR_FORMAT = "{desc} {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}, ETA {remaining}, {rate_fmt}{postfix}]"


def is_terminal(stream) -> bool:
    """Whether ``stream`` is an interactive terminal (bars) rather than a file, pipe or log (plain lines)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def _terminal_width(stream) -> int:
    """Columns of the terminal behind ``stream``; 0 when unknown (no file descriptor, or a pty of size 0)."""
    import os

    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, ValueError, OSError, io.UnsupportedOperation):
        return 0


def format_seconds(seconds: float) -> str:
    """``75.2`` → ``"1:15"``; ``3725`` → ``"1:02:05"``; ``"?"`` when unknown (NaN, inf, negative)."""
    if not (seconds == seconds) or seconds < 0 or seconds == float("inf"):
        return "?"
    s = int(round(seconds))
    h, m = divmod(s, 3600)
    m, s = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def _check_interval(interval: float) -> float:
    if not interval >= 0:
        raise ValueError(f"progress interval must be >= 0 seconds, got {interval!r}")
    return float(interval)


@contextlib.contextmanager
def _redirect_logging(active: bool):
    """Route ``logging`` through ``tqdm.write`` while a terminal bar is live (restored on exit)."""
    if not active:
        yield
        return
    with logging_redirect_tqdm():
        yield


class Bar:
    """A counter from ``initial`` to ``total``: a tqdm bar on a terminal, plain lines elsewhere, nothing when quiet.

    Args:
        total: the count at which the work is done (>= 0).
        desc: what is counted, shown first (``"it"``, ``"search"``).
        unit: unit of the rate (``"it"`` → ``it/s``).
        initial: where counting starts (a resumed run); rates and the ETA count only from here.
        stream: text stream (default ``sys.stderr``); quiet: write nothing.
        interval: seconds between plain lines (the last one is always written).
        on_close: called once, after the bar is closed.
        leave: keep the finished bar on the terminal (False: erase it, e.g. when a stage line follows).
    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, total: int, desc: str = "", *, unit: str = "it", initial: int = 0, stream: TextIO | None = None,
                 quiet: bool = False, interval: float = PLAIN_INTERVAL, on_close=None, leave: bool = True):
        if total is None or int(total) < 0:
            raise ValueError(f"progress total must be an integer >= 0, got {total!r}")
        self.total, self.desc, self.unit = int(total), desc, unit
        self.initial = self.n = int(initial)
        self.stream = sys.stderr if stream is None else stream
        self.quiet, self.interval = bool(quiet), _check_interval(interval)
        self.tty = not self.quiet and is_terminal(self.stream)
        self.postfix = ""
        self._t0 = time.monotonic()
        self._last_line = -float("inf")
        self._closed = False
        self._on_close = on_close
        self._tqdm = None
        if self.tty:
            sized = _terminal_width(self.stream) > 0  # a terminal of unknown size (0 columns): a fixed width
            self._tqdm = tqdm(total=self.total, initial=self.initial, desc=desc, unit=unit, file=self.stream,
                              bar_format=BAR_FORMAT, dynamic_ncols=sized, ncols=None if sized else FALLBACK_WIDTH,
                              nrows=None if sized else FALLBACK_ROWS, mininterval=0.2, leave=leave)

    # ------------------------------------------------------------------ counting
    def update(self, k: int = 1, postfix: str | None = None) -> None:
        """Count ``k`` more (and replace the text after the bar when ``postfix`` is given)."""
        self.goto(self.n + k, postfix)

    def goto(self, n: int, postfix: str | None = None) -> None:
        """Set the count to ``n`` (e.g. the iteration just finished)."""
        if self._closed:
            return
        if postfix is not None:
            self.postfix = postfix
        step, self.n = n - self.n, int(n)
        if self._tqdm is not None:
            if postfix is not None:
                self._tqdm.set_postfix_str(postfix, refresh=False)
            self._tqdm.update(step)
        elif not self.quiet:
            now = time.monotonic()
            if now - self._last_line >= self.interval or self.n >= self.total:
                self._last_line = now
                self._write_line()

    # ------------------------------------------------------------------ plain lines
    def rate(self) -> float:
        """Counts per second since the start (NaN before the first count)."""
        dt = time.monotonic() - self._t0
        done = self.n - self.initial
        return done / dt if dt > 0 and done > 0 else float("nan")

    def eta(self) -> float:
        """Seconds left at the mean rate so far (NaN when unknown)."""
        r = self.rate()
        return (self.total - self.n) / r if r == r and r > 0 else float("nan")

    def line(self) -> str:
        """The plain progress line: ``desc n/total [postfix] rate unit/s elapsed m:ss ETA m:ss``."""
        post = f" {self.postfix}" if self.postfix else ""
        r = self.rate()
        rate = f"{r:.1f} {self.unit}/s" if r == r else f"? {self.unit}/s"
        return (f"{self.desc + ' ' if self.desc else ''}{self.n}/{self.total}{post} {rate} "
                f"elapsed {format_seconds(time.monotonic() - self._t0)} ETA {format_seconds(self.eta())}")

    def _write_line(self) -> None:
        self.stream.write(self.line() + "\n")
        self.stream.flush()

    # ------------------------------------------------------------------ closing
    def close(self) -> None:
        """End the bar (a terminal keeps its last state on its own line); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._tqdm is not None:
            self._tqdm.close()
        if self._on_close is not None:
            self._on_close()

    def __enter__(self) -> "Bar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def training_postfix(info: dict) -> str:
    """``loss 0.0412 psnr 27.31 N 8412`` from the trainer's per-iteration ``info`` (missing terms left out)."""
    parts = []
    if "total" in info:
        parts.append(f"loss {info['total']:.4f}")
    if "psnr" in info:
        parts.append(f"psnr {info['psnr']:.2f}")
    if "num_gaussians" in info:
        parts.append(f"N {int(info['num_gaussians'])}")
    return " ".join(parts)


class TrainingProgress:
    """The trainer's ``progress(it, info)`` callback: iterations, loss, PSNR, Gaussian count and ETA.

    Args:
        total: the run's ``config.iterations``; start: the iteration it resumes from (0 for a new run).
        stream, quiet, interval, on_close, leave: as :class:`Bar`; desc: the label before the count.
    A context manager (the bar is closed on exit, also on Ctrl-C); logging goes through ``tqdm.write``
    while the bar is live on a terminal.
    """

    def __init__(self, total: int, start: int = 0, *, stream: TextIO | None = None, quiet: bool = False,
                 interval: float = PLAIN_INTERVAL, desc: str = "it", on_close=None, leave: bool = True):
        self.bar = Bar(total, desc, unit="it", initial=start, stream=stream, quiet=quiet, interval=interval,
                       on_close=on_close, leave=leave)
        self._redirect = contextlib.ExitStack()

    def __call__(self, it: int, info: dict) -> None:
        self.bar.goto(it, training_postfix(info))

    def close(self) -> None:
        self.bar.close()
        self._redirect.close()

    def __enter__(self) -> "TrainingProgress":
        self._redirect.enter_context(_redirect_logging(self.bar.tty))
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Stages:
    """Reports the stages of one job: a line per finished stage with its time; bars inside a stage.

    Args:
        stream: text stream (default ``sys.stderr``); quiet: write nothing (times are still recorded).
        interval: seconds between plain lines of a :meth:`bar` (not a terminal).
    Attributes:
        times: ``{stage name: seconds}`` of the finished stages (a repeated name accumulates).
    See the module docstring for an example.
    """

    def __init__(self, stream: TextIO | None = None, *, quiet: bool = False, interval: float = PLAIN_INTERVAL):
        self.stream = sys.stderr if stream is None else stream
        self.quiet, self.interval = bool(quiet), _check_interval(interval)
        self.tty = not self.quiet and is_terminal(self.stream)
        self.times: dict[str, float] = {}
        self._open: list[tuple[str, float]] = []  # (name, start) of the stages entered and not left, outermost first
        self._bars = 0  # bars live now: the ticking line is hidden while one is
        self._lock = threading.Lock()
        self._ticker: tqdm | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._redirect = contextlib.ExitStack()

    def path(self) -> str:
        """The names of the open stages, outermost first (``"tetra › delaunay"``)."""
        return " › ".join(name for name, _ in self._open)

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator["Stages"]:
        """Time the block as stage ``name``; writes ``name ...`` (plain) at the start and ``name 12.3 s`` at the end.

        On an exception the end line says ``name failed after 12.3 s`` and the exception propagates.
        """
        if not name:
            raise ValueError("a stage needs a name")
        if not self._open and self.tty:
            self._redirect.enter_context(_redirect_logging(True))
        start = time.monotonic()
        with self._lock:
            self._open.append((name, start))
        depth, path = len(self._open) - 1, self.path()
        if not self.quiet and not self.tty:
            self._write("  " * depth + f"{path} ...")
        self._show_ticker()
        ok = False
        try:
            yield self
            ok = True
        finally:
            seconds = time.monotonic() - start
            with self._lock:
                self._open.pop()
            self.times[name] = self.times.get(name, 0.0) + seconds
            self._hide_ticker()
            if not self.quiet:
                self._write("  " * depth + (f"{path} {seconds:.1f} s" if ok else f"{path} failed after {seconds:.1f} s"))
            if self._open:
                self._show_ticker()
            else:
                self._redirect.close()

    def bar(self, total: int, desc: str = "", *, unit: str = "it", initial: int = 0) -> Bar:
        """A :class:`Bar` on this job's stream, named after the open stages (``"search › step"``); the ticking
        stage line is hidden while it is live, and inside a stage the finished bar is erased (the stage's own
        line follows). Close it (or use ``with``)."""
        self._bar_opened()
        return Bar(total, self._label(desc), unit=unit, initial=initial, stream=self.stream, quiet=self.quiet,
                   interval=self.interval, on_close=self._bar_closed, leave=not self._open)

    def training(self, total: int, start: int = 0) -> TrainingProgress:
        """A :class:`TrainingProgress` on this job's stream (for a stage that trains); close it (or use ``with``)."""
        self._bar_opened()
        return TrainingProgress(total, start, stream=self.stream, quiet=self.quiet, interval=self.interval,
                                desc=self._label("it"), on_close=self._bar_closed, leave=not self._open)

    def _label(self, desc: str) -> str:
        return " › ".join(x for x in (self.path(), desc) if x)

    def _bar_opened(self) -> None:
        self._hide_ticker()
        self._bars += 1

    def _bar_closed(self) -> None:
        self._bars -= 1
        self._show_ticker()

    # ------------------------------------------------------------------ the ticking line (terminal only)
    def _write(self, text: str) -> None:
        if self.tty:
            tqdm.write(text, file=self.stream)
        else:
            self.stream.write(text + "\n")
            self.stream.flush()

    def _show_ticker(self) -> None:
        if not self.tty or self._bars or not self._open or self._ticker is not None:
            return
        sized = _terminal_width(self.stream) > 0
        self._ticker = tqdm(total=None, file=self.stream, bar_format="{desc}", leave=False, mininterval=0,
                            ncols=None if sized else FALLBACK_WIDTH, nrows=None if sized else FALLBACK_ROWS)
        self._refresh_ticker()
        self._stop.clear()
        self._thread = threading.Thread(target=self._tick, name="gof_warp-stage-ticker", daemon=True)
        self._thread.start()

    def _refresh_ticker(self) -> None:
        with self._lock:
            if self._ticker is None or not self._open:
                return
            start = self._open[-1][1]
            self._ticker.set_description_str(f"{self.path()} {format_seconds(time.monotonic() - start)}", refresh=True)

    def _tick(self) -> None:
        while not self._stop.wait(TICK):
            self._refresh_ticker()

    def _hide_ticker(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        with self._lock:
            if self._ticker is not None:
                self._ticker.close()
                self._ticker = None


def as_stages(stages: Stages | None) -> Stages:
    """``stages``, or a silent :class:`Stages` when None: library functions take ``stages=None`` and call this."""
    return stages if stages is not None else Stages(quiet=True)
