"""``python -m gof_warp.cli.configdoc [--check]``: write ``docs/config.md``, the reference of every training key
(``key=value`` overrides, preset YAML) and of the mesh extraction config, generated from the config dataclasses
(:mod:`gof_warp.core.config_doc`). ``--check``: exit 1 if the file is stale, write nothing."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DOC_PATH = Path(__file__).resolve().parents[2] / "docs" / "config.md"
REGENERATE = "python -m gof_warp.cli.configdoc"

HEADER = f"""# Configuration reference

Generated from the config dataclasses by `{REGENERATE}`; do not edit by hand (a test fails when it is stale).

Training keys are set in a preset (`configs/*.yaml`, `--config FILE`) or on the command line as `section.key=value`
(`python -m gof_warp.train SCENE loss.lambda_normal=0.1`). A bad key or value is an `error:` line naming it.
`performance` only overrides decisions about speed; `experimental` holds alternatives to GOF's choices that no preset
turns on. Keys of older configs (`loss.multiview.*`, `render.tile_cull`, `optim.fused`, `compile_loss`, …) are
still read, moved to their new place with a warning."""


def config_reference() -> str:
    """The text of ``docs/config.md``."""
    from ..core.config_doc import render_config_reference
    from ..mesh.extraction import MeshConfig
    from ..training.trainer import TrainConfig

    return render_config_reference([("Training (`TrainConfig`)", TrainConfig, ""),
                                     ("Mesh extraction (`MeshConfig`)", MeshConfig, "")], HEADER)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=REGENERATE, description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/config.md is stale; write nothing")
    a = ap.parse_args(argv)
    text = config_reference()
    if a.check:
        stale = not DOC_PATH.is_file() or DOC_PATH.read_text() != text
        if stale:
            print(f"{DOC_PATH} is stale: run {REGENERATE}", file=sys.stderr)
        return int(stale)
    DOC_PATH.write_text(text)
    print(f"wrote {DOC_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
