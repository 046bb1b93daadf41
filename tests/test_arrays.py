"""gof_warp.arrays: NumPy helpers."""

import numpy as np


def test_distinct_is_np_unique():
    """``arrays.distinct`` (a sort) gives ``np.unique`` (flattened, sorted) on ints, floats, 2-D arrays and the empty."""
    from gof_warp.arrays import distinct

    rng = np.random.default_rng(0)
    for a in (rng.integers(-5, 50, 1000), rng.integers(0, 2**62, (40, 3)), rng.random(7).round(1),
              np.zeros(0, np.int32), np.array([3])):
        got = distinct(a)
        assert np.array_equal(got, np.unique(a)) and got.dtype == a.dtype
