"""Hardware-in-the-loop: the daemon, unchanged, against the simulated rig in its own process.

Each test starts ``capstan hil`` as a process (simulated drive on the cross-process
CAN bus, IMU and load cells on ptys) and checks what an operator relies on: the JSON
summary, a valid log, the ramp to zero on SIGTERM, and after SIGKILL a readable log
and a drive that stops on its own (its consumer heartbeat on the daemon).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from capstan.controller.log.reader import read_log
from capstan.tools.commands.run import EXIT_FAULT
from hil_helpers import hil_argv, host_stalled, run_until_undisturbed, shortest_sensor_timeout_s, wait_for_stderr

REPO = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.slow


@pytest.fixture()
def hil_config(tmp_path: Path) -> Path:
    cfg = yaml.safe_load((REPO / "config" / "hil.yaml").read_text())
    cfg["logging"]["dir"] = str(tmp_path / "logs")
    cfg["realtime"]["lock_memory"] = False          # keeps the test start-up short
    path = tmp_path / "hil.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _start(config: Path, duration_s: float, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(hil_argv(config, duration_s, *extra), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def test_hil_json_summary_valid_log_and_notify(hil_config: Path, tmp_path: Path) -> None:
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(0.2)
    msgs: list[str] = []
    done = threading.Event()

    def listen() -> None:                    # like systemd: read while the service runs
        while not done.is_set():
            try:
                msgs.append(notify.recv(4096).decode().split("\n")[0])
            except socket.timeout:
                pass

    env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "200000"}

    def attempt() -> tuple[subprocess.CompletedProcess, str]:
        msgs.clear()
        done.clear()
        listener = threading.Thread(target=listen, daemon=True)
        listener.start()
        res = subprocess.run(hil_argv(hil_config, 2, "--json"), cwd=REPO, capture_output=True, text=True,
                             timeout=150, env=env)
        time.sleep(0.3)
        done.set()
        listener.join()
        return res, res.stdout

    res, out = run_until_undisturbed(attempt, hil_config)
    assert res.returncode == 0, res.stderr[-3000:]
    # READY first (the watchdog is pinged from the loop's first on-time cycles, arming included)
    assert [m for m in msgs if m != "WATCHDOG=1"][0] == "READY=1"
    log = read_log(out["log_path"])
    phases = log.records["phase"]
    arming = int(np.sum(phases == 0))                       # cycles before READY: loop.arm_on_time_cycles on time
    assert 200 <= arming < 1000
    loop_s = (out["cycles"] + out["missed"]) * 1e-3
    # one ping per 100 ms of healthy loop (half of WATCHDOG_USEC), STATUS each second
    assert loop_s / 0.1 - 3 <= msgs.count("WATCHDOG=1") <= loop_s / 0.1 + 1
    assert sum(m.startswith(("STATUS=running: jitter", "STATUS=ramping: jitter")) for m in msgs) == 2
    assert "STOPPING=1" in msgs and msgs.index("STOPPING=1") > msgs.index("READY=1")
    for key in ("cycles", "missed", "jitter_p50_us", "jitter_p99_us", "jitter_p999_us", "jitter_max_us",
                "faults", "dropped_log_records", "log_path"):
        assert key in out
    assert out["faults"] == [] and out["dropped_log_records"] == 0
    # arming, then 2 s of control + 0.2 s ramp at 1 kHz; missed slots are not cycles
    running = int(np.sum(phases >= 1))
    assert 2200 - 50 <= running + out["missed"] <= 2200 + 50
    assert out["jitter_p50_us"] <= out["jitter_p99_us"] <= out["jitter_p999_us"] <= out["jitter_max_us"] + 1
    assert not log.truncated
    rec = log.records
    assert len(rec) == out["cycles"]
    assert np.all(np.diff(rec["cycle"].astype(np.int64)) == 1)
    assert rec["tau_m_cmd_Nm"][-1] == 0.0 and np.all(rec["fault_bits"] == 0)
    running = rec[rec["tau_m_cmd_Nm"] != 0.0]
    assert len(running) > 1000                          # the controller drove the motor
    # real feedback came through every protocol: tensions near the 150 N pretension,
    # motor and IMU data fresh
    assert np.all(np.abs(rec["T_up_in_N"][100:] - 150.0) < 60.0)
    assert np.all(rec["t_s"][100:] - rec["motor_t_s"][100:] < 0.02)
    assert np.all(rec["t_s"][100:] - rec["imu_t_s"][100:] < 0.025)
    assert log.stats is not None and len(log.stats) >= 1
    assert log.config["controller"]["dt_s"] == 0.001                 # the resolved controller config
    # command quality: the summary's figures agree with the logged commands, and the shipped
    # loop is quiet in the delayed loop (the lock-step gains changed it by 1.15 Nm/cycle rms)
    cmd = out["command"]
    in_run = rec["phase"] == 1
    run_cmd = rec["tau_m_cmd_Nm"][in_run].astype(float)
    # the summary's change is taken inside each statistics window (the window of a stats row holds the
    # cycles up to and including its t_s): the changes across a window's edge are not in it
    window = np.searchsorted(log.stats["t_s"], rec["t_s"][in_run], side="left")
    inside = np.diff(window) == 0
    log_change = float(np.sqrt(np.mean(np.diff(run_cmd)[inside] ** 2)))
    assert cmd["cycles"] == len(run_cmd) and cmd["rate_limit_hits"] == 0
    # the same cycles' commands: equal to float rounding (the summary sums squares as it runs,
    # the log is reduced here at once; 1e-6 is far above that rounding and far below any real gap)
    assert cmd["cmd_change_rms_Nm"] == pytest.approx(log_change, rel=1e-6, abs=1e-12)
    assert cmd["cmd_std_Nm"] == pytest.approx(float(np.std(run_cmd)), rel=1e-6, abs=1e-12)
    assert cmd["cmd_change_rms_Nm"] <= 0.02
    assert np.all(np.isfinite(log.stats["cmd_std_Nm"])) and np.all(log.stats["rate_limit_hits"] == 0)
    # the daemon's log replays bit for bit: arming cycles (no step), the ramp-down factor
    # and every controller step follow from the logged inputs and gating alone
    assert rec["phase"][0] == 0 and rec["phase"][-1] == 2
    assert np.all(rec["tau_m_cmd_Nm"][rec["phase"] == 0] == 0.0)
    assert rec["cmd_scale"][-1] == 0.0 and np.all(rec["cmd_scale"][rec["phase"] == 1] == 1.0)
    rep = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "replay", out["log_path"], "--json"],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert rep.returncode == 0, rep.stderr[-3000:]
    replay = json.loads(rep.stdout)
    assert replay["max_abs_dtau_m_Nm"] == 0.0 and replay["cycles_different"] == 0
    assert replay["cycles"] == out["cycles"]


def test_sigterm_ramps_to_zero_and_closes_the_log(hil_config: Path) -> None:
    def attempt() -> tuple[subprocess.CompletedProcess, str]:
        proc = _start(hil_config, 60.0, "--json")
        wait_for_stderr(proc, "armed after")
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        return subprocess.CompletedProcess(proc.args, proc.returncode, out, err), out

    res, summary = run_until_undisturbed(attempt, hil_config)
    assert res.returncode == 0, res.stderr[-3000:]
    assert summary["faults"] == []
    log = read_log(summary["log_path"])
    assert not log.truncated
    tau = log.records["tau_m_cmd_Nm"]
    ramp = tau[-200:]                                    # ramp_down_s 0.2 s = 200 cycles
    assert ramp[-1] == 0.0
    # the last 200 cycles ramp: the loop's factor falls linearly to zero ...
    assert np.all(log.records["phase"][-200:] == 2)
    np.testing.assert_array_equal(log.records["cmd_scale"][-200:], np.arange(199, -1, -1) / 200.0)
    # ... and each sent command is the controller's command times that factor: a replay that
    # recomputes the controller and applies the logged factor reproduces it bit for bit
    rp = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "replay", summary["log_path"], "--json"],
                        cwd=REPO, capture_output=True, text=True, timeout=300)
    assert rp.returncode == 0, rp.stderr[-2000:]
    assert json.loads(rp.stdout)["max_abs_dtau_m_Nm"] == 0.0


def test_sigkill_leaves_a_readable_log_and_the_drive_stops_itself(hil_config: Path) -> None:
    proc = _start(hil_config, 60.0)
    wait_for_stderr(proc, "armed after")
    time.sleep(1.5)
    t_kill = time.monotonic()
    os.kill(proc.pid, signal.SIGKILL)
    # the simulated drive sees the daemon's heartbeat stop and faults itself (torque off)
    lines = wait_for_stderr(proc, "heartbeat of node 127 lost", timeout_s=10.0)
    t_stop = time.monotonic()
    assert t_stop - t_kill < 1.0, "".join(lines[-10:])
    # the orphaned rig stops after its grace time and removes the bus directory its dead
    # parent made (no temporary directory left per killed run)
    line = wait_for_stderr(proc, "removed the bus directory", timeout_s=10.0)[-1]
    channel = Path(line.split("removed the bus directory ")[1].split(" its parent")[0])
    assert channel.name.startswith("capstan-can-") and not channel.exists()
    proc.wait(timeout=10)
    logs = sorted((hil_config.parent / "logs").glob("capstan_*.mcap"))
    assert len(logs) == 1
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:                    # the writer finishes on its own
        log = read_log(logs[0])
        if any(e.get("kind_name") == "PRODUCER_LOST" for e in log.events):
            break
        time.sleep(0.2)
    assert len(log.records) > 1000
    # at most 1 s lost: the last logged cycle is less than 1 s older than the kill
    assert t_kill - float(log.records["t_s"][-1]) < 1.0
    assert np.all(np.diff(log.records["cycle"].astype(np.int64)) == 1)


def test_a_host_stall_longer_than_the_sensor_timeouts_faults_and_the_reason_says_so(hil_config: Path) -> None:
    # the whole machine held for 60 ms, as a hypervisor can: daemon and simulated rig stopped together
    proc = _start(hil_config, 60.0, "--json")
    wait_for_stderr(proc, "armed after")
    time.sleep(0.5)
    children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
    pids = [proc.pid, *map(int, children)]
    assert len(pids) >= 2                               # the daemon, the rig process, the log writer
    for pid in pids:
        os.kill(pid, signal.SIGSTOP)
    time.sleep(0.06)
    for pid in pids:
        os.kill(pid, signal.SIGCONT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_FAULT, err[-3000:]   # a control fault, not a crash
    summary = json.loads(out)
    assert len(summary["faults"]) == 1
    fault = summary["faults"][0]
    assert "STALE_MOTOR" in fault and "the loop itself had not run for" in fault
    assert 0.055 <= summary["fault_gap_s"] < 1.0
    assert summary["plant"]["lost_s"] > 0.0
    assert host_stalled(summary, shortest_sensor_timeout_s(hil_config))      # what the HIL tests rerun on
    log = read_log(summary["log_path"])
    assert [e for e in log.events if e.get("kind_name") == "FAULT"]
    assert log.records["tau_m_cmd_Nm"][-1] == 0.0 and log.records["fault_bits"][-1] != 0
