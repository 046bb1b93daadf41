"""How much device memory a training run will hold at its largest, estimated before it starts, and the check that
warns when the chosen device has less free.

The estimate (:func:`estimate_training_memory`) counts what the trainer keeps on the device, in bytes:

* **images**: every training photo as float32 RGB (``4 · 3 · H · W`` each) and its mask (``4 · H · W``), uploaded once;
* **Gaussians**: ``GAUSSIAN_BYTES_PER_FLOAT`` bytes per trained float (the parameter, its gradient and Adam's two
  moments: 4 × 4 B) times the floats of one Gaussian (``3 + 4 + 3 + 1 + 3 · (sh_degree + 1)²``), plus
  ``GAUSSIAN_BYTES_EXTRA`` per Gaussian for the renderer's per-Gaussian buffers, its tile lists and the
  densification statistics; the count is ``densify.max_gaussians`` when set, else :data:`DEFAULT_GAUSSIANS`
  (a DTU scan 24 run ends near 0.8 M; real 360° captures reach several million: set ``densify.max_gaussians``
  to bound it);
* **per pixel**: ``PIXEL_BYTES`` per pixel of the largest view for the render's outputs, their gradients and the
  loss's temporaries.

The constants are fitted to a measured run (DTU scan 24, 49 views of 800 × 600 with masks, one H100,
``benchmarks/train/results/dtu_scan24_30k_h100_metrics.json``): at warm-up (38 k Gaussians) torch allocated 756 MiB,
which sets the per-pixel term; at its peak (0.82 M Gaussians) torch's 1,574 MiB plus Warp's pool's 270 MiB, which
sets the per-Gaussian term; the rule gives 1,893 MiB there. Torch's caching allocator reserves more than it
allocates; :data:`RESERVE_FACTOR` is the margin asked of the device on top of the estimate. Checked on a later DTU run
with expandable segments (``core.devices.expandable_cuda_segments``; one H200,
``benchmarks/train/results/dtu_scan24_30k_h200_expandable_cap8gib_metrics.json``): the rule, with its 1 M Gaussians
assumed (the preset sets no bound), gives 2,150 MiB and asks for 3,225 MiB free; the run reserved 2,440 MiB in torch
and 270 MiB in Warp's pool, and the device's used memory peaked at 3,509 MiB, the CUDA context (there before the
check reads the free memory) and the libraries' handles included.
"""

from __future__ import annotations

from dataclasses import dataclass

GAUSSIAN_BYTES_PER_FLOAT = 16  # float32 parameter + gradient + Adam's two moments
GAUSSIAN_BYTES_EXTRA = 550  # projected 2-D terms, tile-list entries (Warp's pool), densification statistics, 3-D filter
PIXEL_BYTES = 800  # rendered colour, depth, normal, alpha and their gradients, the compiled loss's buffers
DEFAULT_GAUSSIANS = 1_000_000
RESERVE_FACTOR = 1.5


@dataclass(frozen=True)
class MemoryEstimate:
    """An estimate of a run's peak device memory (bytes), by part; see the module docstring for the rule."""

    images: int
    gaussians: int
    pixels: int
    num_gaussians: int
    bounded: bool  # True when num_gaussians is the run's densify.max_gaussians, False when assumed

    @property
    def total(self) -> int:
        return self.images + self.gaussians + self.pixels

    def describe(self) -> str:
        count = f"{self.num_gaussians:,} Gaussians" + ("" if self.bounded else " (assumed; densify.max_gaussians unset)")
        return (f"{self.total / 1e9:.2f} GB ({self.images / 1e9:.2f} GB images, {self.gaussians / 1e9:.2f} GB for "
                f"{count}, {self.pixels / 1e9:.2f} GB per-pixel)")


def floats_per_gaussian(sh_degree: int) -> int:
    """Trained floats of one Gaussian: mean 3, rotation 4, log-scale 3, opacity 1, SH ``3 (d + 1)²``."""
    return 3 + 4 + 3 + 1 + 3 * (int(sh_degree) + 1) ** 2


def estimate_training_memory(image_sizes, masks: int, sh_degree: int, max_gaussians: int | None) -> MemoryEstimate:
    """The estimate for a run on training images of ``image_sizes`` (``[(W, H), ...]``), ``masks`` of them with a
    mask, at ``sh_degree``, with ``max_gaussians`` (None: :data:`DEFAULT_GAUSSIANS` assumed)."""
    sizes = [(int(w), int(h)) for w, h in image_sizes]
    if not sizes:
        raise ValueError("estimate_training_memory: no training images")
    pixels = [w * h for w, h in sizes]
    # masks: counted at the largest sizes (which views have one is not known here)
    images = 12 * sum(pixels) + 4 * sum(sorted(pixels, reverse=True)[:max(0, int(masks))])
    n = int(max_gaussians) if max_gaussians else DEFAULT_GAUSSIANS
    per_gaussian = GAUSSIAN_BYTES_PER_FLOAT * floats_per_gaussian(sh_degree) + GAUSSIAN_BYTES_EXTRA
    return MemoryEstimate(images=images, gaussians=n * per_gaussian, pixels=PIXEL_BYTES * max(pixels),
                          num_gaussians=n, bounded=bool(max_gaussians))


def scene_estimate(scene, config) -> MemoryEstimate:
    """:func:`estimate_training_memory` for ``scene``'s training views under a ``TrainConfig``."""
    train = scene.train
    return estimate_training_memory([(v.camera.width, v.camera.height) for v in train],
                                    sum(v.mask is not None for v in train), config.model.sh_degree,
                                    config.densify.max_gaussians)


def memory_warning(estimate: MemoryEstimate, free_bytes: int, total_bytes: int, device: str) -> str | None:
    """The warning to print before training when ``RESERVE_FACTOR ×`` the estimate exceeds the device's free
    memory (None when it fits)."""
    need = RESERVE_FACTOR * estimate.total
    if need <= free_bytes:
        return None
    return (f"{device} has {free_bytes / 1e9:.1f} GB free of {total_bytes / 1e9:.1f} GB; this run is estimated to "
            f"need {estimate.describe()}, {need / 1e9:.1f} GB with the allocator's margin. It may run out of memory: "
            f"lower densify.max_gaussians, or raise data.downscale")
