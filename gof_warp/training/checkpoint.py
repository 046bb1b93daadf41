"""Training checkpoints: plain data only, written atomically, loaded safely, with a fallback on resume.

A checkpoint is one ``torch.save`` file ``ckpt_<iteration>.pt`` in ``RUN/checkpoints/`` holding
everything needed to continue bit-for-bit: parameters, optimizer moments, densification state, the
appearance model, every random generator's state and the resolved config.

Safe to load. A checkpoint holds only *plain data*: tensors, ``bool``/``int``/``float``/``str``/``None``,
and lists, tuples and dicts of them (:func:`plain_data` checks this before anything is written and names
the offending entry). It is read back with ``torch.load(..., weights_only=True)``, which rebuilds only those
types and refuses any other Python object, so a checkpoint from someone else cannot run code when loaded
(a pickled object with a malicious ``__reduce__`` is refused with a :class:`CheckpointError`).

Crash-safe. It is written to a temporary file and renamed, so a crash while saving leaves the previous
checkpoint intact; older checkpoints beyond ``keep`` are removed only after the new one is in place.

Off the training's path. :class:`CheckpointWriter` copies the state to host memory (a copy that shares nothing
with the training's tensors), checks it, and leaves serialising and writing to a background thread, so that
training goes on while the file is written; one write at a time, and a failed write is raised at the next
call. On DTU scan 24 (814k Gaussians, a 570 MB checkpoint) a synchronous save stalled training for ~1 s each
time (H200, 29 checkpoints: ~28 s of a 615 s run).
When the newest checkpoint of a run is unreadable anyway (a disk filled up, a file truncated by a copy),
:func:`load_newest` falls back to the newest one that loads and names every file it skipped.
"""

from __future__ import annotations

import collections
import logging
import os
import pickle
import re
import threading
import warnings
from pathlib import Path

import numpy as np
import torch

from ..core.errors import GofError
from ..core.io_utils import atomic_path

log = logging.getLogger(__name__)

_NAME = re.compile(r"^ckpt_(\d+)\.pt$")
CORRUPT_SUFFIX = ".corrupt"
_SCALARS = (bool, int, float, str, type(None))


class CheckpointError(GofError):
    """One checkpoint file cannot be used: unreadable, corrupt, not a gof_warp checkpoint, or refused as unsafe."""


def checkpoint_dir(run_dir) -> Path:
    return Path(run_dir) / "checkpoints"


def list_checkpoints(run_dir) -> list[tuple[int, Path]]:
    """``[(iteration, path), …]`` sorted by iteration (files set aside as ``*.corrupt`` are not listed)."""
    d = checkpoint_dir(run_dir)
    if not d.is_dir():
        return []
    found = []
    for p in d.iterdir():
        m = _NAME.match(p.name)
        if m:
            found.append((int(m.group(1)), p))
    return sorted(found)


def plain_data(obj, where: str = "state", tensor=None):
    """``obj`` as the plain data a checkpoint may hold (``torch.load(weights_only=True)`` rebuilds exactly these).

    Tensors (``nn.Parameter`` detached to a tensor), ``bool``/``int``/``float``/``str``/``None``, and
    lists, tuples and dicts (``OrderedDict`` kept, as ``nn.Module.state_dict`` returns) of them pass;
    NumPy scalars become Python numbers and NumPy arrays become tensors (the owner converts them back
    on load). Anything else is a programming error: ``TypeError`` naming ``where`` — the entry's path.
    ``tensor``: applied to every (detached) tensor, e.g. a copy to host memory (:func:`host_copy`).
    """
    if isinstance(obj, torch.Tensor):
        t = obj.detach() if type(obj) is not torch.Tensor else obj
        return t if tensor is None else tensor(t)
    if type(obj) in _SCALARS:
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    for t in (bool, int, float, str):  # subclasses (IntEnum, ...) would need their class to load: the plain value
        if isinstance(obj, t):
            return t(obj)
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.array(obj, copy=True))
    if isinstance(obj, dict):
        out = collections.OrderedDict() if isinstance(obj, collections.OrderedDict) else {}
        for k, v in obj.items():
            if not isinstance(k, (*_SCALARS, np.generic)):
                raise TypeError(f"checkpoint {where}: key {k!r} of type {type(k).__name__} is not plain data")
            out[plain_data(k, where)] = plain_data(v, f"{where}[{k!r}]", tensor)
        meta = getattr(obj, "_metadata", None)  # nn.Module.state_dict's version record
        if isinstance(out, collections.OrderedDict) and meta is not None:
            out._metadata = plain_data(meta, f"{where}._metadata")
        return out
    if isinstance(obj, (list, tuple)):
        items = [plain_data(v, f"{where}[{i}]", tensor) for i, v in enumerate(obj)]
        return items if isinstance(obj, list) else tuple(items)
    raise TypeError(f"checkpoint {where}: a {type(obj).__module__}.{type(obj).__qualname__} is not plain data "
                    "(checkpoints hold only tensors, numbers, strings, None, lists, tuples and dicts, so that "
                    "loading one cannot run code); convert it in the owner's state_dict")


def save_checkpoint(run_dir, iteration: int, state: dict, keep: int = 2) -> Path:
    """Write ``state`` (checked by :func:`plain_data` first) as the checkpoint of ``iteration``;
    keep the newest ``keep`` checkpoints."""
    state = plain_data(state)
    path = checkpoint_dir(run_dir) / f"ckpt_{iteration:07d}.pt"
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    for _, old in list_checkpoints(run_dir)[:-keep] if keep > 0 else []:
        old.unlink(missing_ok=True)
    return path


def host_copy(obj, pinned: bool = True):
    """:func:`plain_data` of ``obj`` with every tensor copied to host memory (a new tensor, also for CPU tensors:
    the caller may go on changing the originals in place while the copy is written).

    CUDA tensors are copied into page-locked memory without blocking, then the streams they were copied on are
    synchronised once (``pinned=False``, or page-locked memory refused: one blocking copy into pageable memory)."""
    streams = set()

    def copy(t: torch.Tensor) -> torch.Tensor:
        if pinned and t.is_cuda:
            try:
                host = torch.empty(t.shape, dtype=t.dtype, device="cpu", pin_memory=True)
            except RuntimeError:  # page-locked memory refused (a limit of the host): the pageable copy
                return t.to("cpu", copy=True)
            host.copy_(t, non_blocking=True)
            streams.add(torch.cuda.current_stream(t.device))
            return host
        return t.to("cpu", copy=True)

    out = plain_data(obj, tensor=copy)
    for stream in streams:
        stream.synchronize()
    return out


class CheckpointWriter:
    """Writes checkpoints in a background thread, one at a time (module docstring).

    :meth:`submit` waits for the previous write, copies ``state`` to host memory and checks it
    (:func:`plain_data`: a non-plain entry raises here, in the caller), then returns the path the checkpoint
    will have while a thread writes it with :func:`save_checkpoint`. :meth:`wait` blocks until the write is done
    and raises :class:`CheckpointError` if it failed (the previous checkpoints are then untouched). Call it
    before reading the run's checkpoints and before the process ends (the thread is not a daemon, so an
    interpreter exiting normally finishes the write first).
    """

    def __init__(self, pinned: bool = True):
        self.pinned = pinned  # host copies of CUDA tensors in page-locked memory (:func:`host_copy`)
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._path: Path | None = None

    def submit(self, run_dir, iteration: int, state: dict, keep: int = 2) -> Path:
        self.wait()
        state = host_copy(state, pinned=self.pinned)
        self._path = checkpoint_dir(run_dir) / f"ckpt_{iteration:07d}.pt"

        def write():
            try:
                save_checkpoint(run_dir, iteration, state, keep=keep)
            except BaseException as e:  # raised in the training's thread by wait()
                self._error = e

        self._thread = threading.Thread(target=write, name=f"gof-checkpoint-{iteration}")
        self._thread.start()
        return self._path

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait(self) -> None:
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._error is not None:
            error, self._error = self._error, None
            raise CheckpointError(f"writing the checkpoint {self._path} failed: {error} (the earlier checkpoints "
                                  "are kept)") from error


def _unsafe_reason(message: str) -> str:
    """The one useful sentence of torch's weights-only refusal (e.g. ``Unsupported global: GLOBAL io.open ...``)."""
    _, _, rest = message.partition("WeightsUnpickler error:")
    first = next((line.strip() for line in rest.splitlines() if line.strip()), "")
    return first.split(". Please use")[0][:200]


def read_checkpoint(path, map_location="cpu") -> dict:
    """Load one checkpoint file with ``weights_only=True``; :class:`CheckpointError` saying why it cannot be used."""
    p = Path(path)
    if not p.is_file():
        raise CheckpointError(f"checkpoint {p} not found")
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols of foreign files; the error says it all
            warnings.simplefilter("ignore")
            state = torch.load(p, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        if "weights only" in str(e).lower() or "weightsunpickler" in str(e).lower():
            reason = _unsafe_reason(str(e))
            raise CheckpointError(f"checkpoint {p} was refused: it holds Python objects other than tensors and plain "
                                  f"data, and loading it could run code ({reason or 'not a weights-only file'}). "
                                  "gof_warp never writes such files: it was made elsewhere or altered") from None
        raise CheckpointError(f"checkpoint {p} is unreadable or corrupt: {e}") from None
    except Exception as e:  # torch raises several types for corrupt files (RuntimeError, EOFError, ...)
        msg = str(e).split(". ")[0] or type(e).__name__
        raise CheckpointError(f"checkpoint {p} is unreadable or corrupt ({msg})") from None
    if not isinstance(state, dict) or "iteration" not in state:
        raise CheckpointError(f"checkpoint {p} is not a gof_warp checkpoint")
    return state


def _set_aside(path: Path) -> Path | None:
    """Rename ``path`` to ``<name>.corrupt`` (``.corrupt.1``, … if taken); None if the rename fails."""
    target = path.with_name(path.name + CORRUPT_SUFFIX)
    n = 0
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}{CORRUPT_SUFFIX}.{n}")
    try:
        os.rename(path, target)
    except OSError:
        return None
    return target


def load_newest(run_dir, map_location="cpu", set_aside: bool = False) -> tuple[dict, Path]:
    """The newest checkpoint of ``run_dir`` that loads, and its path.

    A newer checkpoint that cannot be used (see :func:`read_checkpoint`) is skipped with a warning naming
    it, why, and the checkpoint used instead. With ``set_aside`` (what resuming does) each skipped file is
    renamed to ``<name>.corrupt`` so that it no longer counts as one of the run's checkpoints — it is never
    deleted. :class:`GofError` when there is no checkpoint or none loads (then nothing is renamed).
    """
    found = list_checkpoints(run_dir)
    if not found:
        raise GofError(f"no checkpoint found in {checkpoint_dir(run_dir)} (nothing to resume)")
    skipped: list[tuple[Path, str]] = []
    for _, path in reversed(found):
        try:
            state = read_checkpoint(path, map_location)
        except CheckpointError as e:
            skipped.append((path, str(e)))
            continue
        for bad, why in skipped:
            moved = _set_aside(bad) if set_aside else None
            where = (f"; renamed it to {moved.name}" if moved else
                     "; left in place" + (" (could not rename it)" if set_aside else ""))
            log.warning("%s; using the older checkpoint %s instead%s", why, path, where)
        return state, path
    reasons = "; ".join(why for _, why in skipped)
    raise GofError(f"no usable checkpoint in {checkpoint_dir(run_dir)}: {reasons}")


def load_checkpoint(path_or_run, map_location="cpu") -> dict:
    """Load a checkpoint file, or the newest usable one of a run folder (:func:`load_newest`, files left in place)."""
    p = Path(path_or_run)
    if p.is_dir():
        return load_newest(p, map_location)[0]
    return read_checkpoint(p, map_location)


def plain_rng_state(state):
    """A NumPy bit generator's state as plain data: its arrays (MT19937's key) as tensors, its scalars as ints."""
    if isinstance(state, dict):
        return {k: plain_rng_state(v) for k, v in state.items()}
    if isinstance(state, np.ndarray):
        return torch.from_numpy(state.copy())
    return state.item() if isinstance(state, np.generic) else state


def numpy_rng_state(state):
    """The inverse of :func:`plain_rng_state` (PCG64, the default, holds Python ints only)."""
    if isinstance(state, dict):
        return {k: numpy_rng_state(v) for k, v in state.items()}
    return state.numpy() if isinstance(state, torch.Tensor) else state
