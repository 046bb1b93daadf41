"""Adam's update of one flat float32 parameter array in a single pass over its memory.

The Gaussians' parameters are the largest arrays a training step touches (59 floats a Gaussian). Adam reads the
parameter, its gradient and both moments and writes the parameter and the moments back: 28 bytes a float, so the
update is bound by memory bandwidth. :func:`adam_update` does it in one kernel, one thread per float, with the
step's scalars worked out once on the host (Kingma & Ba 2015, Algorithm 1, in the form torch's ``Adam`` uses)::

    m ← m + (1 − β₁)(g − m)                      (= β₁ m + (1 − β₁) g)
    v ← β₂ v + (1 − β₂) g²
    θ ← θ − step_size · m / (√v / bc₂ + ε),      step_size = lr / (1 − β₁ᵗ),  bc₂ = √(1 − β₂ᵗ)

for iteration ``t`` (counted from 1) of this parameter.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def adam_update(grad: wp.array(dtype=float), beta2: float, one_minus_beta1: float, one_minus_beta2: float,
                step_size: float, sqrt_bc2: float, eps: float, param: wp.array(dtype=float),
                exp_avg: wp.array(dtype=float), exp_avg_sq: wp.array(dtype=float)):  # fmt: skip
    """One Adam step, in place. Launch ``dim = param.shape[0]``; every array ``[n]`` float32, flat.

    ``1 − β₁`` and ``1 − β₂`` come worked out on the host in double precision (``1 − 0.999`` rounded to float32 on the
    device would be off by 1.3e-5 of itself); ``step_size = lr / (1 − β₁ᵗ)`` and ``sqrt_bc2 = √(1 − β₂ᵗ)`` are the
    bias corrections at step ``t``. ``param``, ``exp_avg`` (m) and ``exp_avg_sq`` (v) are read and written; ``grad``
    is only read."""
    i = wp.tid()
    g = grad[i]
    m = exp_avg[i]
    m = m + one_minus_beta1 * (g - m)
    v = beta2 * exp_avg_sq[i] + one_minus_beta2 * g * g
    exp_avg[i] = m
    exp_avg_sq[i] = v
    param[i] = param[i] - step_size * m / (wp.sqrt(v) / sqrt_bc2 + eps)
