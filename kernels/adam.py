"""Adam's update of one flat float32 parameter in a single pass over its memory, four floats a thread.

The Gaussians' parameters are the largest arrays a training step touches (59 floats a Gaussian). Adam reads the
parameter, its gradient and both moments and writes the parameter and the moments back, 28 bytes a float, so the
update is bound by memory bandwidth. :func:`adam_step` does it in one kernel with 16-byte loads and stores (a
``vec4`` view of each array) and the step's scalars worked out once on the host, in the form torch's ``Adam`` uses
(Kingma & Ba 2015, Algorithm 1)::

    m ← m + (1 − β₁)(g − m)                      (= β₁ m + (1 − β₁) g)
    v ← β₂ v + (1 − β₂) g²
    θ ← θ − step_size · m / (√v / bc₂ + ε),      step_size = lr / (1 − β₁ᵗ),  bc₂ = √(1 − β₂ᵗ)

for step ``t`` (counted from 1) of this parameter.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def adam_element(g: float, m: float, v: float, theta: float, beta2: float, one_minus_beta1: float,
                 one_minus_beta2: float, step_size: float, sqrt_bc2: float, eps: float):  # fmt: skip
    """One float's update: ``(m', v', θ')``."""
    m_new = m + one_minus_beta1 * (g - m)
    v_new = beta2 * v + one_minus_beta2 * g * g
    return wp.vec3(m_new, v_new, theta - step_size * (m_new / (wp.sqrt(v_new) / sqrt_bc2 + eps)))


@wp.kernel
def adam_step(grad4: wp.array(dtype=wp.vec4), grad: wp.array(dtype=float), n4: int, beta2: float,
              one_minus_beta1: float, one_minus_beta2: float, step_size: float, sqrt_bc2: float, eps: float,
              param4: wp.array(dtype=wp.vec4), exp_avg4: wp.array(dtype=wp.vec4), exp_avg_sq4: wp.array(dtype=wp.vec4),
              param: wp.array(dtype=float), exp_avg: wp.array(dtype=float), exp_avg_sq: wp.array(dtype=float)):  # fmt: skip
    """One Adam step, in place. ``grad, param, exp_avg, exp_avg_sq`` are the flat ``[n]`` arrays; the ``*4`` arrays
    are ``vec4`` views of their first ``4·n4`` floats (the same memory, 16-byte aligned). Launch ``dim = n4 + (n −
    4·n4)``: threads below ``n4`` update four floats each, the rest one float of the tail each. ``1 − β₁`` and
    ``1 − β₂`` come worked out on the host in double precision (``1 − 0.999`` rounded to float32 on the device would
    be off by 1.3e-5 of itself); ``step_size`` and ``sqrt_bc2`` are the bias corrections at the step."""
    i = wp.tid()
    if i < n4:
        g = grad4[i]
        m = exp_avg4[i]
        v = exp_avg_sq4[i]
        p = param4[i]
        a = adam_element(g[0], m[0], v[0], p[0], beta2, one_minus_beta1, one_minus_beta2, step_size, sqrt_bc2, eps)
        b = adam_element(g[1], m[1], v[1], p[1], beta2, one_minus_beta1, one_minus_beta2, step_size, sqrt_bc2, eps)
        c = adam_element(g[2], m[2], v[2], p[2], beta2, one_minus_beta1, one_minus_beta2, step_size, sqrt_bc2, eps)
        d = adam_element(g[3], m[3], v[3], p[3], beta2, one_minus_beta1, one_minus_beta2, step_size, sqrt_bc2, eps)
        exp_avg4[i] = wp.vec4(a[0], b[0], c[0], d[0])
        exp_avg_sq4[i] = wp.vec4(a[1], b[1], c[1], d[1])
        param4[i] = wp.vec4(a[2], b[2], c[2], d[2])
    else:
        k = 4 * n4 + (i - n4)
        r = adam_element(grad[k], exp_avg[k], exp_avg_sq[k], param[k], beta2, one_minus_beta1, one_minus_beta2,
                         step_size, sqrt_bc2, eps)
        exp_avg[k] = r[0]
        exp_avg_sq[k] = r[1]
        param[k] = r[2]
