"""The systemd unit in the repo: required settings, consistency with the daemon, verify."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from capstan.tools.commands.run import EXIT_DEVICE_LOST, EXIT_FAULT
from capstan.controller.runtime.config import DaemonConfig

REPO = Path(__file__).resolve().parent.parent
UNIT = REPO / "config" / "systemd" / "capstan.service"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Sections -> key -> values (systemd allows repeated keys)."""
    out: dict[str, dict[str, list[str]]] = {}
    sec = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            sec = line[1:-1]
            out.setdefault(sec, {})
            continue
        key, _, value = line.partition("=")
        out[sec].setdefault(key.strip(), []).append(value.strip())
    return out


@pytest.fixture(scope="module")
def unit() -> dict[str, dict[str, list[str]]]:
    return parse_unit(UNIT.read_text())


def one(unit: dict, key: str, section: str = "Service") -> str:
    vals = unit[section].get(key)
    assert vals, f"{section}.{key} missing"
    return vals[-1]


def test_notify_watchdog_restart(unit: dict) -> None:
    assert one(unit, "Type") == "notify"
    assert one(unit, "NotifyAccess") == "main"
    assert one(unit, "WatchdogSec").rstrip("s") and float(one(unit, "WatchdogSec").rstrip("s")) > 0
    assert one(unit, "Restart") == "on-failure"
    # a latched control fault, or a drive that went away, must not re-enable the drive by itself
    assert one(unit, "RestartPreventExitStatus").split() == [str(EXIT_FAULT), str(EXIT_DEVICE_LOST)]
    assert one(unit, "KillMode") == "mixed"


def test_realtime_limits(unit: dict) -> None:
    assert int(one(unit, "LimitRTPRIO")) >= DaemonConfig.load(REPO / "config" / "rig.yaml").realtime.priority
    assert one(unit, "LimitMEMLOCK") == "infinity"
    assert one(unit, "RestrictRealtime") == "no"
    assert one(unit, "MemoryDenyWriteExecute") == "no"      # Numba JIT


def test_hardening(unit: dict) -> None:
    assert one(unit, "NoNewPrivileges") == "yes"
    assert one(unit, "ProtectSystem") == "strict"            # read-only system
    assert one(unit, "ProtectHome") == "yes"
    assert set(one(unit, "RestrictAddressFamilies").split()) == {"AF_UNIX", "AF_CAN"}
    assert one(unit, "CapabilityBoundingSet") == ""
    assert "ReadWritePaths" not in unit["Service"]           # the log directory is the only writable path


def test_log_directory_matches_rig_config(unit: dict) -> None:
    cfg = DaemonConfig.load(REPO / "config" / "rig.yaml")
    assert cfg.logging.dir == Path("/var/log") / one(unit, "LogsDirectory")


def test_exec_start_runs_the_rig_config(unit: dict) -> None:
    argv = one(unit, "ExecStart").split()
    assert argv[0].endswith("/capstan") and argv[1] == "run"
    assert argv[argv.index("--config") + 1].endswith("rig.yaml")


def test_systemd_analyze_verify_is_clean(tmp_path: Path) -> None:
    analyzer = shutil.which("systemd-analyze")
    if analyzer is None:
        pytest.skip("systemd-analyze not installed (apt-get install systemd)")
    text = UNIT.read_text()
    exe = REPO / ".venv" / "bin" / "capstan"
    if not exe.exists():
        pytest.skip("no installed capstan console script to point ExecStart at")
    # the installed paths (/opt/capstan, /etc/capstan) do not exist here: point at the repo
    local = "\n".join(f"ExecStart={exe} run --config {REPO / 'config' / 'rig.yaml'}"
                      if line.startswith("ExecStart=") else line for line in text.splitlines())
    path = tmp_path / "capstan.service"
    path.write_text(local + "\n")
    res = subprocess.run([analyzer, "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "capstan.service" not in res.stderr, res.stderr
