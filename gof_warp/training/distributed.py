"""Data-parallel training over processes with ``torch.distributed`` (NCCL on GPUs, gloo on CPUs).

Launched by ``torchrun --nproc_per_node N -m gof_warp.train ...``; every process (a *rank*) holds the whole
model. One training step takes ``views_per_step`` views from the same shuffled view stack on every rank (the
stack's seed is shared), and rank ``r`` renders views ``r, r + N, r + 2N, …`` of them. Each rank's loss is the
mean over the step's views of its own share (``L_v / views_per_step``), so after the gradients are summed
over the ranks (:meth:`Ranks.sum_gradients`, one all-reduce of one flat buffer) every rank holds the
gradient of the mean loss over all the step's views — what one process rendering all of them computes, up to
floating-point summation order. Densification statistics are summed (maximum for the screen radii) before
each densification decision (:meth:`Ranks.reduce_densify_stats`), the densifier's sampler has the same seed
everywhere, so every rank makes the same decisions and holds identical Gaussians; :meth:`Ranks.check_identical`
compares a checksum of the parameters across ranks every ``checksum_every`` steps and stops on a mismatch.
Rank 0 alone writes the run folder (checkpoints load on any number of ranks: they hold one model).

Extraction (``torchrun --nproc_per_node N -m gof_warp.extract RUN``) shares out the views of the opacity field
at the grid points the same way (:meth:`Ranks.reduce_field`: the minimum over the ranks is exact, so every rank
holds the one-process field bit for bit; the ranks' points are checked to be the same:
:meth:`Ranks.check_same_points`). Every rank builds the same octree grid, or rank 0 alone runs the Delaunay and
broadcasts the tetrahedra (:meth:`Ranks.broadcast_rows`). The marching is then split by space: rank ``r`` marches its
consecutive share of the tetrahedra (:meth:`Ranks.my_range`). The binary search is split by views, as the grid
points' field: every rank takes the union of the ranks' crossing edges (:meth:`Ranks.all_gather_objects`) and each
search step evaluates its views at all their midpoints, the minimum reduced over the ranks (a search step's cost is
mostly the per-view preparation of every Gaussian, not the points). Rank 0 joins the pieces by their edge keys
(:meth:`Ranks.gather_to_main`, :func:`gof_warp.mesh.marching.merge_keyed_pieces`) into the one-process mesh and writes
it.

A single process is the same code with ``Ranks.single()`` (every collective a no-op).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from ..core.arrays import even_split
from ..core.devices import cuda_available
from ..core.errors import GofError

# points per float64 chunk of check_same_points' checksums (~0.9 GB of work). Whole, the float64 copies took ~56 B per
# point: at 360M points the two-GPU field stage would peak 12 GB above one GPU's
CHECKSUM_ROWS = 1 << 24


@dataclass(frozen=True)
class Ranks:
    """Where this process stands: ``rank`` of ``world`` processes, ``local_rank`` on its host."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @classmethod
    def single(cls) -> "Ranks":
        return cls()

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1

    def my_views(self, views: list[int]) -> list[int]:
        """This rank's share of one step's views (every ``world``-th, from ``rank``)."""
        return views[self.rank :: self.world]

    def my_range(self, n: int) -> tuple[int, int]:
        """This rank's consecutive share ``[start, end)`` of ``n`` items (the ranks' shares in rank order tile
        ``[0, n)``; sizes differ by at most one)."""
        bounds = even_split(n, self.world)
        return bounds[self.rank], bounds[self.rank + 1]

    def gather_to_main(self, obj):
        """Every rank's ``obj`` (picklable, e.g. numpy arrays) on rank 0 as a list in rank order; None on the
        other ranks. Single process: ``[obj]``."""
        if not self.active:
            return [obj]
        out = [None] * self.world if self.is_main else None
        torch.distributed.gather_object(obj, out, dst=0)
        return out

    def all_gather_objects(self, obj) -> list:
        """Every rank's ``obj`` (picklable) on every rank, as a list in rank order. Single process: ``[obj]``."""
        if not self.active:
            return [obj]
        out = [None] * self.world
        torch.distributed.all_gather_object(out, obj)
        return out

    def sum_gradients(self, params: list[torch.Tensor]) -> None:
        """Sum ``.grad`` of ``params`` over the ranks, in place (parameters without a gradient, e.g. just
        replaced by densification, are skipped — identically on every rank)."""
        if not self.active:
            return
        grads = [p.grad for p in params if p.grad is not None]
        if not grads:
            return
        flat = torch.cat([g.reshape(-1) for g in grads])
        torch.distributed.all_reduce(flat, op=torch.distributed.ReduceOp.SUM)
        at = 0
        for g in grads:
            g.copy_(flat[at : at + g.numel()].view_as(g))
            at += g.numel()

    def reduce_densify_stats(self, stats) -> None:
        """Densification statistics (``grad``, ``grad_abs``, ``count`` summed; ``max_radii`` maximum) over the
        ranks, in place; ``stats`` is the densifier's accumulator (None: nothing gathered)."""
        if not self.active or stats is None:
            return
        flat = torch.cat([stats.grad, stats.grad_abs, stats.count.to(torch.float32)])
        torch.distributed.all_reduce(flat, op=torch.distributed.ReduceOp.SUM)
        n = stats.grad.shape[0]
        stats.grad.copy_(flat[:n])
        stats.grad_abs.copy_(flat[n : 2 * n])
        stats.count.copy_(flat[2 * n :].round().to(torch.int32))
        torch.distributed.all_reduce(stats.max_radii, op=torch.distributed.ReduceOp.MAX)

    def reduce_field(self, field: torch.Tensor, seen: torch.Tensor) -> None:
        """The opacity field of views shared out among the ranks, in place: the minimum of ``field`` and the
        sum of ``seen`` (view counts) over the ranks. The minimum does not depend on the order, so every rank
        ends with exactly the one-process field of all the views."""
        if not self.active:
            return
        torch.distributed.all_reduce(field, op=torch.distributed.ReduceOp.MIN)
        torch.distributed.all_reduce(seen, op=torch.distributed.ReduceOp.SUM)

    def check_identical(self, params: dict[str, torch.Tensor], iteration: int) -> None:
        """Raise :class:`GofError` unless every rank holds the same parameters (float64 checksums compared)."""
        if not self.active:
            return
        sums = torch.stack([torch.stack([p.detach().double().sum(), p.detach().double().abs().sum()])
                            for p in params.values()]).reshape(-1)
        r = self._first_rank_differing(sums)
        if r is not None:
            raise GofError(f"the model on rank {r} differs from rank {self.rank}'s at iteration {iteration} "
                           "(data-parallel ranks must hold identical Gaussians): stopping")

    def _first_rank_differing(self, sums: torch.Tensor) -> int | None:
        """Gather every rank's ``sums`` (checksums); the first rank whose differ from this rank's, None if none."""
        every = [torch.empty_like(sums) for _ in range(self.world)]
        torch.distributed.all_gather(every, sums)
        return next((r for r, other in enumerate(every) if not torch.equal(other, sums)), None)

    def _collective_device(self) -> torch.device:
        """Where tensors for a collective live: this rank's GPU under NCCL, else the host (gloo)."""
        if torch.distributed.get_backend() == "nccl":
            return torch.device("cuda", self.local_rank)
        return torch.device("cpu")

    def broadcast_rows(self, rows: np.ndarray | None) -> np.ndarray:
        """Rank 0's 2-D integer array ``rows`` (``[R, C]``, e.g. tetrahedra) on every rank; the other ranks pass
        None. Single process: ``rows`` itself."""
        if not self.active:
            return rows
        dev = self._collective_device()
        head = torch.zeros(3, dtype=torch.int64, device=dev)
        if self.is_main:
            if rows.ndim != 2 or rows.dtype.kind not in "iu":
                raise GofError(f"broadcast_rows takes a 2-D integer array, got {rows.dtype} of shape {rows.shape}")
            head[0], head[1], head[2] = rows.shape[0], rows.shape[1], rows.dtype.itemsize
        torch.distributed.broadcast(head, src=0)
        n, c, size = (int(v) for v in head.tolist())
        dtype = torch.int32 if size <= 4 else torch.int64
        buf = (torch.as_tensor(np.ascontiguousarray(rows)).to(dev, dtype) if self.is_main
               else torch.empty((n, c), dtype=dtype, device=dev))
        torch.distributed.broadcast(buf, src=0)
        return rows if self.is_main else buf.cpu().numpy()

    def check_same_points(self, points, what: str) -> None:
        """Raise :class:`GofError` unless every rank passes the same ``points`` (``[M, 3]``, numpy or torch) to a
        shared field evaluation: their count and float64 checksums are gathered and compared. Ranks that
        evaluated different points would reduce values of different points into one another."""
        if not self.active:
            return
        x = torch.as_tensor(points).detach()
        sums = torch.zeros(3, dtype=torch.float64, device=x.device)
        sums[0] = float(x.shape[0])
        for s in range(0, x.shape[0], CHECKSUM_ROWS):  # float64 work for CHECKSUM_ROWS points at a time
            c = x[s:s + CHECKSUM_ROWS].to(torch.float64)
            w = torch.arange(s + 1, s + 1 + c.shape[0], dtype=torch.float64, device=x.device)[:, None]
            sums[1:] += torch.stack([c.sum(), (c * w).sum()])
        sums = sums.to(self._collective_device())
        r = self._first_rank_differing(sums)
        if r is not None:
            raise GofError(f"{what}: rank {r} evaluates other points than rank {self.rank} (the ranks' grids "
                           "differ): stopping")

    def barrier(self) -> None:
        if self.active:
            torch.distributed.barrier()

    def close(self) -> None:
        """Leave the process group (at the end of the command; after a :meth:`barrier` when it ends normally)."""
        if self.active and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()


def ranks_from_environment() -> Ranks:
    """The process group ``torchrun`` describes in the environment (``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``),
    initialised (NCCL when CUDA is available, else gloo); ``Ranks.single()`` when not launched that way."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Ranks.single()
    try:
        rank, local = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", os.environ["RANK"]))
    except (KeyError, ValueError) as e:
        raise GofError(f"WORLD_SIZE={world} but RANK/LOCAL_RANK are missing or not integers ({e}): launch with torchrun")
    if not torch.distributed.is_available():
        raise GofError("this torch build has no torch.distributed: train with one process")
    if not torch.distributed.is_initialized():
        backend = "nccl" if cuda_available() else "gloo"  # the project's one device rule (gof_warp.core.devices)
        if backend == "nccl":
            torch.cuda.set_device(local)
        join_process_group(backend=backend)
    return Ranks(rank=rank, world=world, local_rank=local)


def join_process_group(**kwargs) -> None:
    """``torch.distributed.init_process_group(**kwargs)``, with ``torch._dynamo`` imported first.

    Imported after the group exists (the trainer's first use of torch's compiler or optimizers imports it), dynamo
    keeps references to the default process group that :meth:`Ranks.close`'s ``destroy_process_group`` cannot drop:
    the group and its gloo threads then live on into interpreter shutdown, where a rank could abort (``terminate
    called without an active exception``, SIGABRT; 2 of 82 two-rank CPU trainings on a loaded 2-core machine, and
    torchrun then reports the whole job failed after rank 0 has written it). Imported first, it holds none: the group
    and its threads end at ``close`` (no abort in 140 such runs)."""
    import torch._dynamo  # noqa: F401  (see above: the import order is the fix)

    torch.distributed.init_process_group(**kwargs)


def rank_device(device: str, ranks: Ranks) -> str:
    """The device of this rank: ``cuda:<local_rank>`` when training on CUDA with several ranks, else ``device``."""
    if ranks.active and device.startswith("cuda"):
        return f"cuda:{ranks.local_rank}"
    return device
