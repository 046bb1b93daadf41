"""Accuracy against faces and time for the two tetrahedral grids: ``octree_chart.py STUDY.json [...] --out PNG``.

Reads ``octree_study.py`` results (rows with ``vs_exact``) and plots the Chamfer distance to the exact mesh against
the face count and against the extraction time, one point per grid setting.
"""

from __future__ import annotations

import argparse
import json

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("studies", nargs="+")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for path in a.studies:
        d = json.load(open(path))
        label = f"{d['binary_steps']} search steps"
        rows = [r for r in d["rows"] if "vs_exact" in r]
        for ax, key in zip(axes, ("faces", "total_s")):
            oct_rows = [r for r in rows if r["setting"] != "delaunay"]
            ax.plot([r[key] for r in oct_rows], [r["vs_exact"]["chamfer"] for r in oct_rows], "o-",
                    label=f"octree ({label})")
            for r in oct_rows:
                ax.annotate(r["setting"].split()[-1], (r[key], r["vs_exact"]["chamfer"]), fontsize=7,
                            textcoords="offset points", xytext=(3, 3))
            for r in rows:
                if r["setting"] == "delaunay":
                    ax.plot([r[key]], [r["vs_exact"]["chamfer"]], "s", ms=8, label=f"Delaunay ({label})")
    axes[0].set_xlabel("faces")
    axes[1].set_xlabel("extraction time (s, 2-core CPU)")
    for ax in axes:
        ax.set_ylabel("Chamfer to the exact mesh")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("default scene: octree grid (cell factor) vs Delaunay grid")
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    print(a.out)


if __name__ == "__main__":
    main()
