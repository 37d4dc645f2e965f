import pytest

from capstan.models.common.config_tools import get_choice, get_float, get_int, load_yaml, reject_unknown
from capstan.models.common.errors import ConfigError


def test_get_float_bounds_and_types():
    assert get_float({"a": 2}, "a") == 2.0
    assert get_float({}, "a", default=1.5) == 1.5
    with pytest.raises(ConfigError, match="ctl.a.*must be > 0"):
        get_float({"a": 0}, "a", "ctl", min_value=0.0, min_exclusive=True)
    with pytest.raises(ConfigError, match="must be a number"):
        get_float({"a": "x"}, "a")
    with pytest.raises(ConfigError, match="must be finite"):
        get_float({"a": float("nan")}, "a")
    with pytest.raises(ConfigError, match="missing"):
        get_float({}, "a")
    with pytest.raises(ConfigError, match="must be a number"):
        get_float({"a": True}, "a")


def test_int_choice_unknown():
    with pytest.raises(ConfigError, match="must be an integer"):
        get_int({"n": 1.5}, "n")
    assert get_choice({"m": "x"}, "m", ("x", "y")) == "x"
    with pytest.raises(ConfigError, match="one of x, y"):
        get_choice({"m": "z"}, "m", ("x", "y"))
    with pytest.raises(ConfigError, match="'s.cutof_hz': unknown key"):
        reject_unknown({"cutof_hz": 1}, {"cutoff_hz"}, "s")


def test_load_yaml_errors(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_yaml(tmp_path / "nope.yaml")
    p = tmp_path / "bad.yaml"
    p.write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_yaml(p)
    p.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_yaml(p)
