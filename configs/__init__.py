"""YAML presets of gof_warp.trainer.TrainConfig (plain data; installed as gof_warp.configs)."""
