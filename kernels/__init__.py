"""gof_warp.kernels: pure Warp kernels and ``@wp.func``s (no torch).

Installed as the subpackage ``gof_warp.kernels`` so that other Warp programs can embed them. Every
kernel takes its inputs first and its outputs last; each has a float64 reference in the tests.
"""
