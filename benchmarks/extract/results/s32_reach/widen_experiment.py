"""Experiment: the reach filter with each box's half extents widened to at least kappa x its largest (3 max s)."""
import sys
import torch
import gof_warp.tetra as tetra
from gof_warp.extract import main as extract_main

ply, scene, out, kappa = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
orig = tetra.points_in_boxes


def widened(points, means, rotations, half):
    r = half.max(dim=1, keepdim=True).values
    return orig(points, means, rotations, torch.maximum(half, kappa * r))


tetra.points_in_boxes = widened
sys.exit(extract_main([ply, "--scene", scene, "--grid", "octree", "--binary-steps", "4", "--no-pictures", "--quiet",
                       "--out", out] + sys.argv[5:]))
