"""Safety settings that a typo cannot switch off: plausible ranges with the key in the
message, the explicit lab override (with a reason, stored with the config in every log)."""

from __future__ import annotations

from pathlib import Path

import pytest

from capstan.controller.law.config import ControllerConfig
from capstan.controller.runtime.config import DaemonConfig
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def _raw(path: str, value) -> dict:
    raw = load_yaml(ROOT / "config" / "hil.yaml")
    node = raw
    keys = path.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    node[keys[-1]] = value
    return raw


@pytest.mark.parametrize("key", [
    "controller.safety.imu_timeout_s",          # 1e9: stale-IMU detection off
    "controller.safety.loadcell_timeout_s",
    "controller.safety.motor_timeout_s",
    "loop.ramp_down_s",                         # 1e9: SIGTERM never finishes
    "controller.feedback.kp",
    "controller.feedback.ki_1_s",
    "motor.max_torque_Nm",
    "motor.consumer_timeout_s",
    "controller.safety.dtau_max_Nm_s",
])
def test_absurd_value_is_refused_naming_the_key(key):
    with pytest.raises(ConfigError) as err:
        DaemonConfig.from_mapping(_raw(key, 1e9))
    assert err.value.key == key
    assert "plausible range" in err.value.reason and "lab_override" in err.value.reason


def test_tau_max_alone_is_blamed_on_tau_max_not_on_the_fault_limit():
    with pytest.raises(ConfigError) as err:
        DaemonConfig.from_mapping(_raw("controller.safety.tau_max_Nm", 1e9))
    assert err.value.key == "controller.safety.tau_max_Nm"
    # also where the controller section itself is parsed (replay, experiments)
    with pytest.raises(ConfigError) as err:
        ControllerConfig.from_mapping({"safety": {"tau_max_Nm": 1e9}})
    assert err.value.key == "controller.safety.tau_max_Nm"


def test_both_set_names_the_fault_limit_below_the_clamp():
    with pytest.raises(ConfigError) as err:
        ControllerConfig.from_mapping({"safety": {"tau_max_Nm": 30.0, "tau_fault_Nm": 20.0}})
    assert err.value.key == "controller.safety.tau_fault_Nm"


def test_lab_override_accepts_with_a_reason_and_lists_the_key():
    raw = _raw("controller.safety.imu_timeout_s", 0.5)
    raw["lab_override"] = {"ranges": True, "reason": "IMU on a slow bench adapter"}
    cfg = DaemonConfig.from_mapping(raw)
    assert cfg.overridden and cfg.overridden[0].startswith("controller.safety.imu_timeout_s")
    assert cfg.raw["lab_override"]["reason"] == "IMU on a slow bench adapter"   # stored with the config


def test_lab_override_without_reason_is_refused():
    raw = _raw("controller.safety.imu_timeout_s", 0.5)
    raw["lab_override"] = {"ranges": True}
    with pytest.raises(ConfigError) as err:
        DaemonConfig.from_mapping(raw)
    assert err.value.key == "lab_override.reason"


def test_lab_override_does_not_bypass_hard_validity():
    raw = _raw("loop.ramp_down_s", -1.0)
    raw["lab_override"] = {"ranges": True, "reason": "x"}
    with pytest.raises(ConfigError) as err:
        DaemonConfig.from_mapping(raw)
    assert err.value.key == "loop.ramp_down_s"


@pytest.mark.parametrize("name", ["hil.yaml", "rig.yaml"])
def test_shipped_configs_are_plausible(name):
    cfg = DaemonConfig.load(ROOT / "config" / name)
    assert cfg.overridden == () and not cfg.lab_override.active
