"""gof_warp.core.arrays: NumPy helpers."""

import numpy as np


def test_distinct_is_np_unique():
    """``arrays.distinct`` (a sort) gives ``np.unique`` (flattened, sorted) on ints, floats, 2-D arrays and the empty."""
    from gof_warp.core.arrays import distinct

    rng = np.random.default_rng(0)
    for a in (rng.integers(-5, 50, 1000), rng.integers(0, 2**62, (40, 3)), rng.random(7).round(1),
              np.zeros(0, np.int32), np.array([3])):
        got = distinct(a)
        assert np.array_equal(got, np.unique(a)) and got.dtype == a.dtype


def test_used_vertices_renumbers_faces():
    """``arrays.used_vertices`` keeps the vertices some face uses, in order, and renumbers the faces so they pick the
    same points; a hand-built case with unused vertices at the start, middle and end."""
    from gof_warp.core.arrays import used_vertices

    vertices = np.arange(8 * 3, dtype=float).reshape(8, 3)
    faces = np.array([[1, 3, 2], [3, 6, 2]])
    used, renumbered = used_vertices(faces, len(vertices))
    assert used.tolist() == [1, 2, 3, 6]
    assert renumbered.tolist() == [[0, 2, 1], [2, 3, 1]]
    assert np.array_equal(vertices[used][renumbered], vertices[faces])
    used, renumbered = used_vertices(np.zeros((0, 3), np.int64), 4)
    assert used.size == 0 and renumbered.shape == (0, 3)


def test_even_split_tiles_the_items():
    """``arrays.even_split``: consecutive ranges from 0 to n whose sizes differ by at most one, also with more parts
    than items; hand-checked 10 items in 3 parts."""
    from gof_warp.core.arrays import even_split

    assert even_split(10, 3) == [0, 3, 6, 10]
    for n, parts in ((0, 1), (5, 8), (1000, 7), (2**40 + 3, 5)):
        b = even_split(n, parts)
        sizes = [hi - lo for lo, hi in zip(b, b[1:])]
        assert b[0] == 0 and b[-1] == n and len(sizes) == parts and max(sizes) - min(sizes) <= 1
