"""Training checkpoints: written atomically, found and loaded with clear errors.

A checkpoint is one ``torch.save`` file ``ckpt_<iteration>.pt`` in ``RUN/checkpoints/`` holding
everything needed to continue bit-for-bit: parameters, optimizer moments, densification state, the
appearance model, every random generator's state and the resolved config. It is written to a temporary
file and renamed, so a crash while saving leaves the previous checkpoint intact; older checkpoints
beyond ``keep`` are removed only after the new one is in place.
"""

from __future__ import annotations

import re
from pathlib import Path

import torch

from .errors import GofError
from .io_utils import atomic_path

_NAME = re.compile(r"^ckpt_(\d+)\.pt$")


def checkpoint_dir(run_dir) -> Path:
    return Path(run_dir) / "checkpoints"


def list_checkpoints(run_dir) -> list[tuple[int, Path]]:
    """``[(iteration, path), …]`` sorted by iteration."""
    d = checkpoint_dir(run_dir)
    if not d.is_dir():
        return []
    found = []
    for p in d.iterdir():
        m = _NAME.match(p.name)
        if m:
            found.append((int(m.group(1)), p))
    return sorted(found)


def save_checkpoint(run_dir, iteration: int, state: dict, keep: int = 2) -> Path:
    """Write ``state`` as the checkpoint of ``iteration``; keep the newest ``keep`` checkpoints."""
    path = checkpoint_dir(run_dir) / f"ckpt_{iteration:07d}.pt"
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    for _, old in list_checkpoints(run_dir)[:-keep] if keep > 0 else []:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path_or_run, map_location="cpu") -> dict:
    """Load a checkpoint file, or the newest one of a run folder."""
    p = Path(path_or_run)
    if p.is_dir():
        found = list_checkpoints(p)
        if not found:
            raise GofError(f"no checkpoint found in {checkpoint_dir(p)} (nothing to resume)")
        p = found[-1][1]
    if not p.is_file():
        raise GofError(f"checkpoint {p} not found")
    try:
        state = torch.load(p, map_location=map_location, weights_only=False)
    except Exception as e:  # torch raises several types for corrupt files
        raise GofError(f"checkpoint {p} is unreadable or corrupt: {e}") from None
    if not isinstance(state, dict) or "iteration" not in state:
        raise GofError(f"checkpoint {p} is not a gof_warp checkpoint")
    return state
