"""Map a function over parts of one big input in forked worker processes (Linux), pickling only part numbers and
results: the input is read from each child's copy of the parent's memory.

The two CPU-bound stages that Python threads cannot spread over cores use it: the chunked Delaunay's Qhull
pieces (:mod:`gof_warp.mesh.delaunay`) and the opacity field's points on the CPU, where Warp runs a kernel on one
core (:mod:`gof_warp.rendering.opacity_field`).
"""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Callable

# Inputs of the running map_forked calls, keyed by a token of each call, set just before its workers fork and
# removed when the call ends.
_FORKED: dict[int, tuple] = {}


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


def _in_child(fn: Callable, token: int, part: int):
    return fn(*_FORKED[token], part)


def map_forked(fn: Callable, inputs: tuple, parts: int, workers: int) -> list:
    """``[fn(*inputs, i) for i in range(parts)]`` on ``workers`` forked processes, in order. ``fn`` must be a
    module-level function (it is pickled by name); ``inputs`` are not pickled."""
    token = id(inputs) ^ time.perf_counter_ns()
    _FORKED[token] = inputs
    try:
        with ProcessPoolExecutor(max(1, workers), mp_context=multiprocessing.get_context("fork")) as pool:
            return list(pool.map(_in_child, [fn] * parts, [token] * parts, range(parts)))
    finally:
        del _FORKED[token]
