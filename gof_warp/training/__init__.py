"""GOF's optimisation: ``Trainer`` and ``TrainConfig`` wire the stage objects of one run.

Owns the loss (paper Eq. 12: colour, depth distortion, depth–normal consistency; ``losses``), adaptive
density control as a policy object with explicit state (``densify``), Adam and the one optimizer-state
surgery function (``optim``), the decoupled appearance network (``appearance``), Mip-Splatting's 3D filter
(``filter3d``), checkpoints as plain data (``checkpoint``), data-parallel training (``distributed``),
the run folder's layout (``run_folder``) and the preset a scene needs (``presets``). Options that are not
GOF's (the multi-view term, late/hidden pruning) are off unless a preset or ``experimental`` turns them on.

Memory: the Gaussians and their Adam moments (~59 floats each) plus one view's render; densification
statistics are per Gaussian.
"""

from ..core.lazy import lazy_exports

_PUBLIC = {
    "Trainer": "trainer",
    "TrainConfig": "trainer",
    "TrainingLoss": "losses",
    "LossConfig": "losses",
    "DensifyConfig": "densify",
    "Densifier": "densify",
    "load_run": "run_folder",
    "resolve_config": "presets",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
