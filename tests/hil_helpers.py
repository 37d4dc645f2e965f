"""Running ``capstan hil`` in tests on a shared VM: telling a host stall from a defect.

A real-time run faults, by design, when the whole machine stops for longer than a sensor
timeout (the loop got no CPU; on a shared VM the hypervisor can take both vCPUs for tens
of milliseconds). On a rig that is a fault worth having; in a test it says nothing about
the code. :func:`run_until_undisturbed` reruns a session only when the daemon itself
reports such a stall *and* the simulated rig lost time as well — any other fault, and a
stall that happens three times in a row, still fails the test.
"""

from __future__ import annotations

import json
import select
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Callable

import yaml

from capstan.tools.commands.run import EXIT_DEVICE_LOST, EXIT_FAULT


def shortest_sensor_timeout_s(config: Path) -> float:
    """The smallest staleness timeout of the config's ``controller.safety`` [s]."""
    safety = yaml.safe_load(Path(config).read_text())["controller"]["safety"]
    return min(float(safety[k]) for k in ("imu_timeout_s", "loadcell_timeout_s", "motor_timeout_s"))


def host_stalled(summary: dict[str, Any], timeout_s: float) -> bool:
    """True if the run faulted after the loop and the rig were both held off the CPU.

    :param summary: the JSON summary of ``capstan hil --json``.
    :param timeout_s: the shortest sensor timeout of the run's config [s].
    """
    faults = summary.get("faults") or []
    rig_lost_s = summary.get("plant", {}).get("lost_s", 0.0)
    # the daemon names a host stall itself when its loop had not run for > 5 periods before
    # the faulted cycle; a gap of a whole sensor timeout is one whatever the text says
    stalled = summary.get("fault_gap_s", 0.0) >= timeout_s or any("host stall" in f for f in faults)
    # or the simulated rig's own process got no CPU (it fell behind by more than its catch-up
    # bound) and the fault is the silence that left: a device lost or stale
    rig_silent = rig_lost_s > 0.0 and any(("device loss" in f or "STALE_" in f) for f in faults)
    return bool(faults) and (stalled or rig_silent) and rig_lost_s > 0.0


def run_until_undisturbed(attempt: Callable[[], tuple[subprocess.CompletedProcess, str]], config: Path,
                          tries: int = 3) -> tuple[subprocess.CompletedProcess, dict[str, Any]]:
    """Run ``attempt`` (returns the finished process and its stdout) until it did not end
    on a host stall, at most ``tries`` times; returns the last process and its summary."""
    timeout_s = shortest_sensor_timeout_s(config)
    for k in range(1, tries + 1):
        res, out = attempt()
        summary = json.loads(out) if out.strip() else {}
        if k == tries or not (res.returncode in (EXIT_FAULT, EXIT_DEVICE_LOST) and host_stalled(summary, timeout_s)):
            break
        warnings.warn(f"host stall of {summary['fault_gap_s'] * 1e3:.0f} ms faulted the HIL run "
                      f"(rig lost {summary['plant']['lost_s'] * 1e3:.0f} ms); rerunning", stacklevel=2)
    return res, summary


def hil_argv(config: Path, duration_s: float, *extra: str) -> list[str]:
    """The command line of ``capstan hil --config CONFIG --duration D [EXTRA...]``."""
    return [sys.executable, "-m", "capstan.tools.cli", "hil", "--config", str(config), "--duration-s", str(duration_s),
            *extra]


def run_hil(config: Path, duration_s: float, cwd: Path,
            timeout_s: float = 240.0) -> tuple[subprocess.CompletedProcess, dict[str, Any]]:
    """``capstan hil --config CONFIG --duration D --json``, rerun after a host stall."""
    def attempt() -> tuple[subprocess.CompletedProcess, str]:
        res = subprocess.run(hil_argv(config, duration_s, "--json"), cwd=cwd, capture_output=True, text=True,
                             timeout=timeout_s)
        return res, res.stdout

    return run_until_undisturbed(attempt, config)


def wait_for_stderr(proc: subprocess.Popen, needle: str, timeout_s: float = 90.0) -> list[str]:
    """Read ``proc``'s stderr lines until one contains ``needle``; returns the lines read.

    :raises AssertionError: (after killing ``proc``) if the stream ends or ``timeout_s``
        passes first, with the last lines read.
    """
    lines: list[str] = []
    end = time.monotonic() + timeout_s
    assert proc.stderr is not None
    while time.monotonic() < end:
        ready, _, _ = select.select([proc.stderr], [], [], 1.0)
        if ready:
            line = proc.stderr.readline()
            if not line:
                break
            lines.append(line)
            if needle in line:
                return lines
    proc.kill()
    raise AssertionError(f"{needle!r} not seen; stderr:\n" + "".join(lines[-30:]))
