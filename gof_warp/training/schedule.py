"""GOF's training schedule compressed to a short run, and the image size such a run trains at on a CPU.

The ``cpu`` preset (``configs/cpu.yaml``) trains a real capture in a few thousand iterations or fewer.
GOF's schedule is written for 30,000 iterations (densify 500–15k every 100, regularisers from 15k, SH degree
+1 every 1k, 3D filter until 29.9k); :func:`compress_schedule` expresses it in units of ``u = iterations / 12``
— the unit of the ``quick`` preset's schedule (100 of its 1,200 iterations):

==============================  ====================  ============================================
setting                         value                 why
==============================  ====================  ============================================
``densify.start_iter``          u                     densification starts after a first unit
``densify.interval``            u                     8 densifications in all (quick's)
``densify.stop_iter``           9u (0.75·N)           a short run needs its growth longer than
                                                      GOF's half
``densify.opacity_reset_*``     10·N (never)          a reset's recovery takes hundreds of
                                                      iterations, a large share of a short run
``densify.prune_big_after``     round(0.1·N)          GOF's 3k of 30k
``densify.sh_degree_interval``  u                     SH degree 3 at 3u (GOF: at 0.1·N)
``densify.filter_3d_until``     11u                   quick's
``densify.late_prune_interval`` u                     late prunes at 9u and 10u
``densify.hidden_prune_iters``  [10u, 11u]            after growth, as GOF's 15k…29k are
``loss.regularization_from``    6u (0.5·N)            GOF's 15k of 30k
``optim.means_lr_max_steps``    N                     the learning-rate decay ends with the run
==============================  ====================  ============================================

``u`` is ``round(N / 12)``, so every iteration above is an exact multiple of it and the order of the stages
holds for any ``N >= MIN_ITERATIONS``.

:func:`cpu_downscale` is the rule for the image size: the smallest integer factor that brings a view to at most
:data:`CPU_MAX_PIXELS` pixels (the cost of a CPU iteration grows with the pixel count).
"""

from __future__ import annotations

import math

from ..core.config import ConfigError

#: the fewest iterations :func:`compress_schedule` accepts (a unit of 10 iterations)
MIN_ITERATIONS = 120
#: pixels of one view that the ``cpu`` preset trains at, at most (the fox's 540×960 at downscale 3: 57,600)
CPU_MAX_PIXELS = 64_000


def schedule_unit(iterations: int) -> int:
    """``u = round(iterations / 12)``: the unit of :func:`compress_schedule`."""
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < MIN_ITERATIONS:
        raise ConfigError(f"a compressed schedule needs an integer number of iterations >= {MIN_ITERATIONS}, "
                          f"got {iterations!r}")
    return round(iterations / 12)


def compress_schedule(iterations: int) -> dict:
    """The schedule settings of a run of ``iterations`` (module docstring), as a nested override mapping
    (``{"iterations": N, "densify": {...}, "loss": {...}, "optim": {...}}``) for
    :func:`gof_warp.core.config.merge`. Raises :class:`ConfigError` below :data:`MIN_ITERATIONS`."""
    u = schedule_unit(iterations)
    return {
        "iterations": iterations,
        "densify": {"start_iter": u, "interval": u, "stop_iter": 9 * u, "opacity_reset_interval": 10 * iterations,
                    "prune_big_after": max(1, round(0.1 * iterations)), "sh_degree_interval": u,
                    "filter_3d_until_iter": 11 * u, "late_prune_interval": u,
                    "hidden_prune_iters": [10 * u, 11 * u]},
        "loss": {"regularization_from_iter": 6 * u},
        "optim": {"means_lr_max_steps": iterations},
    }


def cpu_downscale(width: int, height: int, max_pixels: int = CPU_MAX_PIXELS) -> int:
    """The smallest integer ``d >= 1`` with ``round(width / d) · round(height / d) <= max_pixels``
    (the size :func:`gof_warp.data.load_scene` gives a view at ``downscale = d``)."""
    if width < 1 or height < 1 or max_pixels < 1:
        raise ConfigError(f"cpu_downscale needs a positive image size and pixel budget, got {width}x{height}, "
                          f"{max_pixels}")
    d = max(1, math.floor(math.sqrt(width * height / max_pixels)))
    while round(width / d) * round(height / d) > max_pixels:
        d += 1
    return d


# ------------------------------------------------------------------------------------- expected time
#: seconds of one training iteration per megapixel of the training view on a CPU, and how much slower the whole
#: run's mean iteration is than its first ones (the model grows by densification, the regularisers start). Both
#: from the cpu preset on the fox (benchmarks/cpu_preset: 1.39 process-CPU seconds an iteration at 0.0576 MP, on a
#: 2-core box shared with other jobs, so upper bounds): an estimate, not a promise.
CPU_SECONDS_PER_MEGAPIXEL = 24.0
CPU_GROWTH = 1.8
#: seconds of one iteration on a CUDA GPU, whatever the image size (an H100: DTU scan24 at 800×600, 30,000
#: iterations in 296 s, benchmarks/RESULTS.md); at the small sizes of the cpu preset launches dominate, not pixels.
CUDA_SECONDS_PER_ITERATION = 0.01
#: iterations after which the train command prints an ETA from their measured pace
ETA_AFTER_ITERATIONS = 20


def expected_train_seconds(iterations: int, pixels: int, device: str) -> float | None:
    """A rough training time for ``iterations`` on views of ``pixels`` pixels on ``device`` (``"cpu"``,
    ``"cuda"``, ``"cuda:N"``): ``iterations × CPU_SECONDS_PER_MEGAPIXEL × pixels / 10⁶`` on a CPU,
    ``iterations × CUDA_SECONDS_PER_ITERATION`` on CUDA; None for another device."""
    if str(device) == "cpu":
        return iterations * CPU_SECONDS_PER_MEGAPIXEL * pixels / 1e6
    if str(device).startswith("cuda"):
        return iterations * CUDA_SECONDS_PER_ITERATION
    return None


def eta_from_pace(seconds_per_iteration: float, remaining: int, device: str) -> float:
    """The time left for ``remaining`` iterations after the first ones ran at ``seconds_per_iteration``: on a CPU
    × :data:`CPU_GROWTH` (later iterations draw more Gaussians); on CUDA as measured."""
    return remaining * seconds_per_iteration * (CPU_GROWTH if str(device) == "cpu" else 1.0)
