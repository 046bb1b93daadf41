"""Pictures and the live viewer of a run.

``write_run_pictures`` draws photo | Gaussian render | depth | normal | mesh (shaded, or in its colours) for a few views
(``panels`` holds the drawing, ``curves`` the training curves); ``Viewer`` serves a run in the browser
(viser), rendered by our renderer from the browser's camera.

Library only: the commands live in ``gof_warp.cli.common``.
"""

from ..core.lazy import lazy_exports

_PUBLIC = {
    "write_run_pictures": "pictures",
    "pictures_or_warning": "pictures",
    "Viewer": "viewer",
    "open_run": "viewer",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
