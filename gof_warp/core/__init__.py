"""What every layer may use: cameras, scenes, the Gaussians, PLY files, config loading, errors, devices.

Owns the data types that pass between stages and the rules every stage follows: ``Camera`` (intrinsics +
world-to-camera pose, OpenCV axes), ``Scene``/``View`` (posed uint8 images and masks), ``Gaussians`` (raw
3DGS parameters and their activations), strict PLY and YAML IO, ``GofError`` (the input's fault, one
message), one rule for devices (``resolve_device``), atomic file output, progress bars.

Imports nothing above it (``tests/test_layout.py``). Memory: no module here holds more than its arguments.
"""

from .lazy import lazy_exports

_PUBLIC = {
    "Camera": "camera",
    "Intrinsics": "camera",
    "look_at": "camera",
    "camera_extent": "camera",
    "Scene": "scene",
    "View": "scene",
    "Gaussians": "model",
    "GofError": "errors",
    "ConfigError": "config",
    "SceneError": "errors",
    "ModelError": "errors",
    "PlyError": "errors",
    "resolve_device": "devices",
    "read_ply_vertices": "ply",
    "write_ply_vertices": "ply",
    "write_ply_mesh": "ply",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
