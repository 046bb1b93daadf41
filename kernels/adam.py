"""Adam's update of one flat float32 parameter in a single pass over its memory, four floats a thread.

The Gaussians' parameters are the largest arrays a training step touches (59 floats a Gaussian). Adam reads the
parameter, its gradient and both moments and writes the parameter and the moments back, 28 bytes a float, so the
update is bound by memory bandwidth. :func:`adam_step` does it in one kernel with 16-byte loads and stores (a
``vec4`` view of each array).

The arithmetic is that of torch's fused CUDA Adam (``_fused_adam_``, ``ATen/native/cuda/fused_adam_utils.cuh``), float
for float, so that on a GPU the two give the same bits: everything in float32, ``lr``, ``β₁``, ``β₂`` and ``ε`` rounded
to float32 first, the moments through fused multiply-adds, and the bias corrections from the step count on the
device::

    m ← fma(β₁, m, fma(−β₁, g, g))               (= β₁ m + (1 − β₁) g, one rounding each)
    v ← fma(β₂, v, fma(−β₂, g·g, g·g))           (g·g rounded first)
    θ ← θ − ((lr / (1 − β₁ᵗ)) · m) / (√v / √(1 − β₂ᵗ) + ε)

for step ``t`` (counted from 1) of this parameter (Kingma & Ba 2015, Algorithm 1). Written with ``fma`` the implicit
``1 − β`` is ``1 − fl(β)`` exactly, so ``β + (1 − β) = 1`` holds for the float32 ``β``: the second moment of a constant
gradient settles at ``g²``, not 1.3e-5 above it as it does when ``1 − 0.999`` is rounded on its own.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func_native("return fmaf(a, b, c);")
def fma32(a: float, b: float, c: float) -> float:
    """``a·b + c`` with one rounding (C's ``fmaf``): what the compiler cannot reorder or round twice."""
    ...


@wp.func
def adam_element(g: float, m: float, v: float, theta: float, beta1: float, beta2: float, step_size: float,
                 bc2_sqrt: float, eps: float):  # fmt: skip
    """One float's update: ``(m', v', θ')``."""
    m_new = fma32(beta1, m, fma32(-beta1, g, g))
    g2 = g * g
    v_new = fma32(beta2, v, fma32(-beta2, g2, g2))
    denom = wp.sqrt(v_new) / bc2_sqrt + eps
    return wp.vec3(m_new, v_new, theta - (step_size * m_new) / denom)


@wp.kernel
def adam_step(grad4: wp.array(dtype=wp.vec4), grad: wp.array(dtype=float), n4: int, lr: float, beta1: float,
              beta2: float, eps: float, step: float,
              param4: wp.array(dtype=wp.vec4), exp_avg4: wp.array(dtype=wp.vec4), exp_avg_sq4: wp.array(dtype=wp.vec4),
              param: wp.array(dtype=float), exp_avg: wp.array(dtype=float), exp_avg_sq: wp.array(dtype=float)):  # fmt: skip
    """One Adam step, in place. ``grad, param, exp_avg, exp_avg_sq`` are the flat ``[n]`` arrays; the ``*4`` arrays
    are ``vec4`` views of their first ``4·n4`` floats (the same memory, 16-byte aligned). Launch ``dim = n4 + (n −
    4·n4)``: threads below ``n4`` update four floats each, the rest one float of the tail each. ``lr, beta1, beta2,
    eps``: the group's settings as float32; ``step``: this step's count ``t`` (1 for the first), from which each thread
    forms the bias corrections ``1 − β₁ᵗ`` and ``√(1 − β₂ᵗ)`` as torch's kernel does."""
    i = wp.tid()
    step_size = lr / (float(1.0) - wp.pow(beta1, step))
    bc2_sqrt = wp.sqrt(float(1.0) - wp.pow(beta2, step))
    if i < n4:
        g = grad4[i]
        m = exp_avg4[i]
        v = exp_avg_sq4[i]
        p = param4[i]
        a = adam_element(g[0], m[0], v[0], p[0], beta1, beta2, step_size, bc2_sqrt, eps)
        b = adam_element(g[1], m[1], v[1], p[1], beta1, beta2, step_size, bc2_sqrt, eps)
        c = adam_element(g[2], m[2], v[2], p[2], beta1, beta2, step_size, bc2_sqrt, eps)
        d = adam_element(g[3], m[3], v[3], p[3], beta1, beta2, step_size, bc2_sqrt, eps)
        exp_avg4[i] = wp.vec4(a[0], b[0], c[0], d[0])
        exp_avg_sq4[i] = wp.vec4(a[1], b[1], c[1], d[1])
        param4[i] = wp.vec4(a[2], b[2], c[2], d[2])
    else:
        k = 4 * n4 + (i - n4)
        r = adam_element(grad[k], exp_avg[k], exp_avg_sq[k], param[k], beta1, beta2, step_size, bc2_sqrt, eps)
        exp_avg[k] = r[0]
        exp_avg_sq[k] = r[1]
        param[k] = r[2]
