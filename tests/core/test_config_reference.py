"""docs/config.md is generated from the config dataclasses and must be regenerated when they change."""

from gof_warp.cli.configdoc import DOC_PATH, REGENERATE, config_reference
from gof_warp.core.config import to_dict
from gof_warp.training.trainer import TrainConfig


def test_config_reference_is_current():
    assert DOC_PATH.is_file() and DOC_PATH.read_text() == config_reference(), \
        f"docs/config.md is stale: regenerate it with `{REGENERATE}`"


def test_reference_names_every_training_key_and_experimental_last():
    text = config_reference()

    def keys(d, prefix=""):
        for k, v in d.items():
            yield from keys(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]

    for key in keys(to_dict(TrainConfig())):
        assert f"| `{key}` |" in text, key
    training = text.split("## Mesh extraction")[0]
    assert training.rindex("### `experimental`") > training.rindex("### `performance`") > training.index("### `densify`")
