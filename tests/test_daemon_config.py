"""Daemon configuration validation and the device backend registry."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.runtime.realtime import RealtimeMode
from capstan.drivers import registry
from capstan.models.common.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent


def base() -> dict:
    return {"controller": {}, "motor": {"backend": "canopen"}, "imu": {"backend": "xsens", "port": "/dev/null"},
            "load_cells": {"backend": "serial", "port": "/dev/null"}}


@pytest.mark.parametrize("name", ["rig.yaml", "hil.yaml"])
def test_shipped_configs_validate(name: str) -> None:
    cfg = DaemonConfig.load(REPO / "config" / name)
    assert cfg.loop.period_s == pytest.approx(1e-3)
    assert cfg.logging.dir.is_absolute()
    from capstan.controller.law.config import ControllerConfig
    ControllerConfig.from_mapping(cfg.controller)


def test_rig_config_enforces_realtime_and_hil_warns() -> None:
    assert DaemonConfig.load(REPO / "config" / "rig.yaml").realtime.mode == RealtimeMode.ENFORCE
    assert DaemonConfig.load(REPO / "config" / "hil.yaml").realtime.mode == RealtimeMode.WARN


def test_defaults_and_relative_log_dir(tmp_path: Path) -> None:
    cfg = DaemonConfig.from_mapping(base(), base_dir=tmp_path)
    assert cfg.logging.dir == tmp_path / "runs" / "logs"
    assert cfg.realtime.mode == RealtimeMode.WARN and cfg.loop.overrun_streak_fault == 10


@pytest.mark.parametrize("patch, key, reason", [
    ({"loop": {"period_s": 0}}, "loop.period_s", ">= 0.0001"),
    ({"loop": {"busy_tail_s": 0.002}}, "loop.busy_tail_s", "shorter than period_s"),
    ({"loop": {"sensor_fresh_s": 0.0009}}, "loop.sensor_fresh_s", ">= period_s"),     # just below 1 ms
    ({"loop": {"overrun_streak_fault": 0}}, "loop.overrun_streak_fault", ">= 1"),
    ({"loop": {"limits": {"q_out_min_rad": 1.0, "q_out_max_rad": 0.5}}}, "loop.limits.q_out_max_rad", "> q_out_min"),
    ({"loop": {"limits": {"tension_max": 3}}}, "loop.limits.tension_max", "unknown key"),
    ({"realtime": {"mode": "strict"}}, "realtime.mode", "one of off, warn, enforce"),
    ({"realtime": {"priority": 120}}, "realtime.priority", "<= 99"),
    ({"realtime": {"cpus": [1, -1]}}, "realtime.cpus", "list of CPU numbers"),
    ({"logging": {"ring_records": 8}}, "logging.ring_records", ">= 64"),
    ({"motor": {"channel": "can0"}}, "motor.backend", "missing"),
    ({"controlller": {}}, "controlller", "unknown key"),
])
def test_bad_values_name_key_and_reason(patch: dict, key: str, reason: str) -> None:
    cfg = base()
    cfg.update(patch)
    with pytest.raises(ConfigError) as ei:
        DaemonConfig.from_mapping(cfg)
    assert ei.value.key == key
    assert reason in ei.value.reason


def test_sensor_freshness_of_one_period_is_accepted() -> None:
    cfg = base()
    cfg.update({"loop": {"period_s": 0.002, "sensor_fresh_s": 0.002}})
    assert DaemonConfig.from_mapping(cfg).loop.sensor_fresh_s == 0.002


def test_missing_section_is_named() -> None:
    cfg = base()
    del cfg["imu"]
    with pytest.raises(ConfigError, match="'imu'"):
        DaemonConfig.from_mapping(cfg)


def test_registry_unknown_backend_lists_choices() -> None:
    with pytest.raises(ConfigError) as ei:
        registry.create("imu", {"backend": "vectornav"})
    assert ei.value.key == "imu.backend" and "xsens" in ei.value.reason


def test_registry_passes_options_to_backend_validation() -> None:
    with pytest.raises(ConfigError) as ei:
        registry.create("imu", {"backend": "xsens", "port": "/dev/null", "baud": 9600})
    assert ei.value.key == "imu.baud"


def test_registry_builds_each_role() -> None:
    m = registry.create("motor", {"backend": "canopen", "interface": "capstan_unix", "channel": "/tmp/x"})
    assert type(m).__name__ == "CanopenMotor" and m.config.channel == "/tmp/x"
    assert type(registry.create("imu", {"backend": "xsens", "port": "/dev/null"})).__name__ == "XsensImu"
    lc = registry.create("load_cells", {"backend": "serial", "port": "/dev/null"})
    assert type(lc).__name__ == "SerialLoadCells"


def test_registry_imports_lazily() -> None:
    code = "import sys, drivers.registry; print('canopen' in sys.modules, 'serial' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=30)
    assert out.stdout.split() == ["False", "False"], out.stderr
