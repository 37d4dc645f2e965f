"""``capstan run`` end to end against the independent CiA 402 peer (tests/cia402_peer): a daemon
killed with SIGKILL, and one stopped with SIGTERM, are each followed by a ``capstan run`` that
starts and runs without a manual step; the killed daemon's drive stops within its consumer
heartbeat time although the peer's own defaults (0x6007 = 0) would have kept the torque."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil_helpers import wait_for_stderr
from peer_rig import PeerRig
from cia402_peer import Ds402

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
CONSUMER_TIMEOUT_S = 0.1      # config/hil.yaml motor.consumer_timeout_s


def _argv(config: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "capstan.tools.cli", "run", "--config", str(config), *extra]


def _run_to_end(config: Path) -> tuple[subprocess.CompletedProcess, dict]:
    """``capstan run --duration 1 --json``; rerun (at most 3 times) only if a host stall faulted it.

    The returned ``stderr`` holds every attempt's log in order: a fault the first attempt
    reset at start-up is not there to reset again in a rerun."""
    logs: list[str] = []
    for _ in range(3):
        res = subprocess.run(_argv(config, "--duration-s", "1.0", "--json"), cwd=REPO, capture_output=True,
                             text=True, timeout=180)
        logs.append(res.stderr)
        summary = json.loads(res.stdout) if res.stdout.strip() else {}
        if not (res.returncode == 3 and "host stall" in " ".join(summary.get("faults", []))):
            break
    res.stderr = "".join(logs)
    return res, summary


def _wait_until(cond, timeout_s: float) -> float | None:
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout_s:
            return None
        time.sleep(0.0005)
    return time.monotonic() - t0


#: measured 2026-11-28 on the 2-core VM: the daemon against the in-process peer faulted on OVERRUN_STREAK within
#: ~20 ms of arming in most runs; since arming waits for loop.arm_on_time_cycles on-time cycles it passed in the
#: whole-suite run on an idle VM, but at load 7 the peer (threads of the test process) missed its heartbeat
#: while the daemon armed (HEARTBEAT_LOST): not strict until it holds on a loaded machine too
@pytest.mark.xfail(strict=False, reason="the in-process peer's heartbeat can starve while the daemon arms on a "
                                        "loaded VM (HEARTBEAT_LOST at load 7); passes on an idle one")
def test_capstan_run_after_sigkill_and_after_sigterm(tmp_path: Path) -> None:
    channel = str(tmp_path / "can0")
    rig = PeerRig(channel, q_out_rad=0.3)
    try:
        config = rig.run_config(tmp_path / "run.yaml", channel, tmp_path / "logs")
        peer = rig.peer
        # ---- 1. a running daemon killed with SIGKILL
        proc = subprocess.Popen(_argv(config), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        try:
            wait_for_stderr(proc, "armed after")
            time.sleep(0.5)
            assert peer.value(0x6007) == 1 and peer.value(0x1016, 1) == (127 << 16) | 100
            assert peer.value(0x6072) == 750                   # max_torque_Nm 15 of rated 20 Nm
            torque_before = peer.applied_torque_permille
            os.kill(proc.pid, signal.SIGKILL)
            stopped_s = _wait_until(lambda: peer.applied_torque_permille == 0 and peer.state == Ds402.FAULT, 2.0)
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.communicate(timeout=30)
        assert torque_before != 0
        # stopped by the drive's consumer heartbeat (0x8130 below), within the 2 s wait (liveness; the
        # latency's figures against the 100 ms consumer time: tests/bench_cia402_peer.py, SIGKILL)
        assert stopped_s is not None, stopped_s
        assert peer.value(0x603F) == 0x8130
        # ---- 2. restarted: the fault its predecessor left is reset, named, and the run completes
        res, summary = _run_to_end(config)
        assert res.returncode == 0, res.stderr[-3000:]
        assert "FAULT 0x8130 (life guard or heartbeat error)" in res.stderr
        assert summary["cycles"] >= 500 and summary["faults"] == []
        assert peer.state == Ds402.READY_TO_SWITCH_ON and peer.value(0x1016, 1) == 0
        # ---- 3. a running daemon stopped with SIGTERM leaves the drive restartable
        n_emcy = len(peer.emcy_sent)
        for _ in range(3):                      # rerun only if a host stall faulted the session
            proc = subprocess.Popen(_argv(config, "--json"), cwd=REPO, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            try:
                lines = wait_for_stderr(proc, "armed after")
                time.sleep(0.5)
                proc.send_signal(signal.SIGTERM)
                out, err = proc.communicate(timeout=60)
            finally:
                if proc.poll() is None:
                    proc.kill()
            err = "".join(lines) + err
            if "host stall" not in err:
                break
        assert proc.returncode == 0, err[-3000:]
        time.sleep(5 * CONSUMER_TIMEOUT_S)
        assert peer.state == Ds402.READY_TO_SWITCH_ON and peer.value(0x1016, 1) == 0
        assert 0x8130 not in peer.emcy_sent[n_emcy:]          # no heartbeat fault after the stop
        # ---- 4. and the next run starts without a reset
        res, summary = _run_to_end(config)
        assert res.returncode == 0, res.stderr[-3000:]
        assert "0x8130" not in res.stderr and summary["faults"] == []
        # ---- 5. the drive limits the torque itself (statusword bit 11): warned and counted in the
        # stats records of the log (decoded with a standard protobuf decoder from the logged schema)
        proc = subprocess.Popen(_argv(config, "--duration-s", "2.5", "--json"), cwd=REPO, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            lines = wait_for_stderr(proc, "armed after")
            with peer.lock:
                peer.od[(0x6072, 0)].value = 1          # derated to 1 per mille behind the master's back
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
        err = "".join(lines) + err
        assert "statusword bit 11, internal limit active" in err, err[-3000:]
        stats = _stats_records(json.loads(out)["log_path"])
        assert stats and stats[-1].drive_limit_total > 500, [m.drive_limit_total for m in stats]
    finally:
        rig.close()


def _stats_records(path: str) -> list:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        out, cls = [], None
        for schema, _, msg in reader.iter_messages(topics=["/capstan/stats"]):
            if cls is None:
                fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                pool = descriptor_pool.DescriptorPool()
                for f in fds.file:
                    pool.Add(f)
                cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
            out.append(cls.FromString(msg.data))
    return out
