"""User-facing errors.

Everything that is the user's input's fault (a missing file, a corrupt PLY, a camera model we do not
support, NaN parameters) raises a subclass of :class:`GofError`. The command-line tools catch
``GofError`` and print its message without a traceback; library users can catch it (it is also a
``ValueError``) or let it propagate.
"""

from __future__ import annotations


class GofError(ValueError):
    """Base class of errors caused by bad input. The message names the file or argument."""


class SceneError(GofError):
    """A scene folder that cannot be read: missing/corrupt images, unknown format, bad cameras."""


class PlyError(GofError):
    """A PLY file that cannot be read or does not hold 3D Gaussians in the 3DGS layout."""


class ModelError(GofError):
    """Gaussian parameters that are not usable (NaN/inf, non-positive scales, wrong shapes)."""


def error_summary(error: BaseException, limit: int = 400) -> str:
    """``"TypeName: message"`` on one line (whitespace runs folded), the message cut to ``limit`` characters: why an
    optional compiled path fell back, for logs and ``metrics.json``."""
    return f"{type(error).__name__}: {' '.join(str(error).split())[:limit]}"
