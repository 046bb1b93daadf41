"""Config dataclasses ⇄ YAML: strict keys, typed coercion, overrides, round trip."""

from dataclasses import dataclass, field

import pytest

from gof_warp.core.config import ConfigError, dump_yaml, from_dict, load_yaml, merge, parse_override, to_dict


@dataclass
class _Inner:
    lam: float = 0.05
    on: bool = True
    steps: int = 8


@dataclass
class _Outer:
    name: str = "x"
    levels: tuple[float, ...] = (0.5,)
    budget: int | None = None
    inner: _Inner = field(default_factory=_Inner)


def test_round_trip_through_yaml(tmp_path):
    cfg = _Outer(name="dtu", levels=(0.3, 0.5), budget=1000, inner=_Inner(lam=0.1, on=False, steps=3))
    p = tmp_path / "c.yaml"
    p.write_text(dump_yaml(cfg))
    back = from_dict(_Outer, load_yaml(p))
    assert back == cfg
    assert to_dict(back)["levels"] == [0.3, 0.5]


def test_partial_dict_keeps_defaults_and_coerces_ints_to_floats():
    cfg = from_dict(_Outer, {"inner": {"lam": 1}})
    assert cfg.inner.lam == 1.0 and isinstance(cfg.inner.lam, float)
    assert cfg.inner.steps == 8 and cfg.name == "x"


def test_unknown_and_mistyped_keys_are_errors():
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['lamda'\]"):
        from_dict(_Outer, {"inner": {"lamda": 1.0}})
    with pytest.raises(ConfigError, match="config.inner.steps: expected an integer"):
        from_dict(_Outer, {"inner": {"steps": 2.5}})
    with pytest.raises(ConfigError, match="expected true/false"):
        from_dict(_Outer, {"inner": {"on": "yes please"}})


def test_overrides_parse_yaml_values_and_merge():
    cfg = _Outer()
    cfg = merge(cfg, parse_override("inner.lam=0.2"))
    cfg = merge(cfg, parse_override("budget=5000"))
    cfg = merge(cfg, parse_override("levels=[0.4, 0.6]"))
    assert cfg.inner.lam == 0.2 and cfg.budget == 5000 and cfg.levels == (0.4, 0.6)
    cfg = merge(cfg, parse_override("budget=null"))
    assert cfg.budget is None
    with pytest.raises(ConfigError, match="unknown key"):
        merge(cfg, parse_override("inner.nope=1"))
    with pytest.raises(ConfigError, match="section.key=value"):
        parse_override("inner.lam")


def test_yaml_is_never_evaluated(tmp_path):
    p = tmp_path / "evil.yaml"
    p.write_text("name: !!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(ConfigError, match="cannot be read"):
        load_yaml(p)


def test_exponent_notation_without_a_dot_is_a_number():
    """YAML 1.1 reads ``1e-6`` as text; a float field takes it as the number, and real text is still refused."""
    from gof_warp.core.config import ConfigError, merge, parse_override
    from gof_warp.training.trainer import TrainConfig

    assert merge(TrainConfig(), parse_override("densify.grad_threshold=1e-6")).densify.grad_threshold == 1e-6
    assert merge(TrainConfig(), parse_override("loss.lambda_normal=5E+1")).loss.lambda_normal == 50.0
    with pytest.raises(ConfigError, match="expected a number"):
        merge(TrainConfig(), parse_override("loss.lambda_normal=1e"))


def test_overrides_checked_against_each_other_apply_in_either_order():
    """The trainer's overrides are merged together, then checked: the unbounded preset's near-camera prune needs the
    late prune, and turning both off works whichever comes first (one at a time, the first one was refused)."""
    from gof_warp.core.errors import GofError
    from gof_warp.training.presets import resolve_config

    both = ["densify.near_camera_fraction=0", "densify.late_prune_interval=0"]
    for overrides in (both, both[::-1]):
        cfg = resolve_config("unbounded", overrides, 123)
        assert cfg.densify.late_prune_interval == 0 and cfg.densify.near_camera_fraction == 0.0
        assert cfg.iterations == 123
    with pytest.raises(GofError, match="near_camera_fraction"):  # one alone is still checked
        resolve_config("unbounded", ["densify.late_prune_interval=0"], None)
    assert resolve_config("quick", ["loss.lambda_normal=0.1", "loss.lambda_normal=0.2"], None).loss.lambda_normal == 0.2
    with pytest.raises(ConfigError, match="densify.max_gausians"):
        resolve_config("quick", ["loss.lambda_normal=0.1", "densify.max_gausians=5"], None)
