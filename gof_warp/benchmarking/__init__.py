"""The benchmark and stability harness behind ``python -m gof_warp.bench``: not part of the library API.

``runs`` defines a run (scene, schedule, budget) and trains or reuses it; ``report`` measures the machine,
peak memory and scores and writes the table and charts; ``stability`` finds where each extraction method
breaks (degenerate models, hard scenes, ``stability_scenes``) and ``stability_inputs`` runs the commands on
bad inputs and counts clear errors, warnings and crashes (the one module that imports the CLIs: that is its
job); ``equivalence`` tests whether two sets of PSNRs are equivalent (Welch's interval).
"""

from ..core.lazy import lazy_exports

_PUBLIC = {
    "Run": "runs",
    "Method": "runs",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
