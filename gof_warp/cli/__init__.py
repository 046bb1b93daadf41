"""The commands: one thin module each, ``python -m gof_warp.<command>`` or ``gof-warp <command>``.

Each command parses its arguments and a config, calls the library, and owns progress output and exit codes
(``common``: ``error: <message>`` and exit 2 for a :class:`~gof_warp.core.errors.GofError`, no traceback).
Library code never imports this package (``tests/test_layout.py``).
"""

from __future__ import annotations

import importlib
import sys

from .common import configure_output, run_command  # noqa: F401 - the contract every command shares

COMMANDS = {
    "train": ("train", "train Gaussians on a scene folder (or the built-in synthetic scene)"),
    "extract": ("extract", "extract a mesh (or a NanoVDB volume) from a run"),
    "evaluate": ("evaluate", "score a mesh against a ground-truth mesh or point cloud"),
    "pictures": ("pictures", "draw photo | render | depth | normal | mesh for a few views of a run"),
    "view": ("view", "serve a run in the browser (live viewer)"),
    "prepare": ("prepare", "camera poses for a folder of plain photos (structure from motion) → a scene folder"),
    "inspect": ("inspect_scene", "what gof_warp makes of a scene folder"),
    "bench": ("bench", "benchmark and stability suites"),
    "synthetic": ("synthetic", "render a synthetic scene with exact ground truth"),
}


def main(argv: list[str] | None = None) -> int:
    """``gof-warp <command> [args]``: the console script; the same as ``python -m gof_warp.<command> [args]``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        width = max(map(len, COMMANDS))
        print("usage: gof-warp <command> [args]   (gof-warp <command> --help for its options)\n\ncommands:")
        for name, (_, text) in COMMANDS.items():
            print(f"  {name:<{width}}  {text}")
        print("\nThe same as python -m gof_warp <command> [args], or python -m gof_warp.<command> [args].")
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: unknown command {name!r}; one of: {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    module = importlib.import_module(f".{COMMANDS[name][0]}", __name__)
    sys.argv = [f"gof-warp {name}", *rest]
    return module.main(rest)
