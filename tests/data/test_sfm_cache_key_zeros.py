"""The triangulation cache key is the same for the same cameras on every machine: signed zeros do not count."""

from __future__ import annotations

import dataclasses

import numpy as np

from _scene_fixtures import random_image
from gof_warp.core.camera import Camera
from gof_warp.core.scene import View
from gof_warp.data.sfm import SfmConfig, cache_key


def _views(sign: float, shift: float = 0.0) -> list[View]:
    """Two axis-aligned cameras whose pose has many exact zeros, stored as ``sign * 0.0``, and tiny values that
    round to zero at the key's precision."""
    views = []
    for i in range(2):
        R = np.eye(3) + 0.0
        R[R == 0] = sign * 0.0
        R[0, 1] = sign * 1e-12  # rounds to (signed) zero
        t = np.array([sign * 0.0, sign * 0.0, 4.0 + i + shift])
        cam = Camera(R=R, t=t, fx=40.0, fy=40.0, cx=24.0, cy=18.0, width=48, height=36, name=f"{i}")
        views.append(View(camera=cam, image=random_image(seed=i), mask=None, name=f"{i}"))
    return views


def test_signed_zeros_give_the_same_cache_key():
    plus, minus = _views(1.0), _views(-1.0)
    assert np.signbit(minus[0].camera.t[0]) and not np.signbit(plus[0].camera.t[0])
    assert cache_key(plus, SfmConfig()) == cache_key(minus, SfmConfig())


def test_a_real_change_still_changes_the_key():
    base = cache_key(_views(1.0), SfmConfig())
    assert cache_key(_views(1.0, shift=1e-3), SfmConfig()) != base
    moved = _views(-1.0)
    moved[1] = dataclasses.replace(moved[1], camera=dataclasses.replace(moved[1].camera, fx=41.0))
    assert cache_key(moved, SfmConfig()) != base
