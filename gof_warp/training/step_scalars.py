"""Per-iteration loss terms kept on the device and read back in batches.

Reading a CUDA scalar (``float(loss)``, ``if torch.isfinite(loss)``) waits for every kernel queued before
it: the GPU then idles while Python launches the next iteration's work. The trainer therefore keeps each
iteration's terms as device tensors in :class:`PendingScalars` and converts a batch of iterations with one
device-to-host copy (:meth:`PendingScalars.flush`) — every ``flush_every`` iterations and whenever a
value is needed on the host (a log line, a snapshot, a checkpoint, the end of training).

On the CPU the copy is free and nothing changes; on CUDA the only synchronisations left in a training step
are the renderer's list sizing and the densification steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class IterationScalars:
    """One iteration's record: host-known fields and, after :meth:`PendingScalars.flush`, ``values``."""

    iteration: int
    view: str
    num_gaussians: int
    restart_monitor: bool  # the loss-spike window restarts before this iteration's loss is recorded
    elapsed_s: float
    values: dict


class PendingScalars:
    """A queue of iterations whose scalar terms (0-d device tensors) are not yet on the host."""

    def __init__(self):
        self._records: list[IterationScalars] = []
        self._tensors: list[tuple[tuple[str, ...], torch.Tensor]] = []

    def __len__(self) -> int:
        return len(self._records)

    def add(self, record: IterationScalars, terms: dict[str, torch.Tensor]) -> None:
        """Queue ``record`` with its ``terms`` (name → 0-d tensor, any device); stacking is asynchronous."""
        names = tuple(terms)
        stacked = torch.stack([t.detach().reshape(()).to(torch.float32) for t in terms.values()]) if names else None
        self._records.append(record)
        self._tensors.append((names, stacked))

    def flush(self) -> list[IterationScalars]:
        """All queued records, oldest first, with ``values`` filled (one device-to-host copy); empties the queue."""
        records, tensors = self._records, self._tensors
        self._records, self._tensors = [], []
        present = [t for _, t in tensors if t is not None]
        host = torch.cat(present).cpu().tolist() if present else []
        at = 0
        for record, (names, t) in zip(records, tensors):
            count = 0 if t is None else len(names)
            record.values = dict(zip(names, host[at:at + count]))
            at += count
        return records
