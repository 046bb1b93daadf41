"""One view's densification statistics added into the running sums, in one pass (GOF Sec. 3.3, 3DGS Sec. 5.2).

After each training view the densifier adds, for every Gaussian the view saw (screen radius > 0), the norm of its
view-space gradient and its per-pixel-norm sum, counts the view, and keeps the largest radius. Done with torch's
elementwise operators that is ten kernels over ``N`` (two masks, two adds, a cast, a maximum, ...) and as many host
calls every step; :func:`accumulate_view_stats` is one. Only additions and a maximum: the sums are the bits the
operators give (a view's terms arrive already scaled).
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def accumulate_view_stats(grad_norm: wp.array(dtype=float), grad_abs: wp.array(dtype=float),
                          radii: wp.array(dtype=wp.int32),
                          grad_sum: wp.array(dtype=float), grad_abs_sum: wp.array(dtype=float),
                          count: wp.array(dtype=wp.int32), max_radii: wp.array(dtype=wp.int32)):  # fmt: skip
    """For each Gaussian ``i`` with ``radii[i] > 0``: ``grad_sum[i] += grad_norm[i]``, ``grad_abs_sum[i] +=
    grad_abs[i]``, ``count[i] += 1``, ``max_radii[i] = max(max_radii[i], radii[i])``; the others are left as they are.
    All arrays ``[N]``; launch ``dim = N``."""
    i = wp.tid()
    r = radii[i]
    if r > 0:
        grad_sum[i] = grad_sum[i] + grad_norm[i]
        grad_abs_sum[i] = grad_abs_sum[i] + grad_abs[i]
        count[i] = count[i] + 1
        max_radii[i] = wp.max(max_radii[i], r)
