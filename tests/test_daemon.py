"""The daemon loop against in-process fake devices: arming, READY, faults, ramp-down."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from capstan.controller.runtime.daemon import LIMIT_VIOLATION, Daemon, Phase
from capstan.controller.runtime.session_log import NullSink
from capstan.controller.law.records import FaultBits
from capstan.controller.runtime.sd_notify import SdNotifier
from capstan.models.common.errors import ControlFaultError, DeviceTimeoutError
from tests.daemon_fakes import (FakeController, FakeImu, FakeLoadCells, FakeMotor, NotifyListener, config,
                                devices)


def make(tmp_path: Path, watchdog_usec: int | None = None, **kw):
    journal: list[str] = []
    listener = NotifyListener(tmp_path)
    env = {"NOTIFY_SOCKET": listener.path}
    if watchdog_usec:
        env["WATCHDOG_USEC"] = str(watchdog_usec)
    notifier = SdNotifier(env)

    orig = notifier.notify

    def notify(msg: str) -> bool:
        journal.append(msg.split("\n")[0])
        return orig(msg)
    notifier.notify = notify  # type: ignore[method-assign]
    motor = kw.pop("motor", None) or FakeMotor(journal)
    motor.journal = journal
    dev = devices(journal, motor, kw.pop("imu", None), kw.pop("cells", None))
    ctl = FakeController(stale_s=kw.pop("stale_s", 0.05))
    sink = NullSink()
    d = Daemon(config(**kw), devices=dev, controller=ctl, sink=sink, notifier=notifier)
    return d, motor, ctl, sink, journal, listener


def test_normal_run_ready_after_enable_then_ramp_and_disable(tmp_path: Path) -> None:
    d, motor, ctl, sink, journal, listener = make(tmp_path)
    summary = d.run(duration_s=0.4)
    assert ctl.warmed
    # READY only after the drive was enabled; STOPPING on the way out; disabled at the end
    assert journal.index("motor enabled") < journal.index("READY=1")
    assert journal.index("READY=1") < journal.index("STOPPING=1")
    assert any(j.startswith("motor disabled") for j in journal)
    msgs = listener.messages()
    assert msgs[0].startswith("READY=1") and any(m.startswith("STOPPING=1") for m in msgs)
    assert any(m.startswith("STATUS=running: jitter") for m in msgs)
    assert summary.phase == Phase.STOPPED.name and summary.faults == []
    # ~0.4 s of 1 ms slots plus arming and the 50-cycle ramp (a late cycle skips slots)
    assert 380 <= summary.cycles + summary.missed <= 520
    sent = np.array(motor.sent)
    # the ramp: the last 50 commands go linearly from 0.5 Nm to 0
    ramp = sent[-50:]
    assert ramp[-1] == 0.0
    assert np.all(np.diff(ramp) <= 1e-12)
    np.testing.assert_allclose(ramp, 0.5 * np.arange(49, -1, -1) / 50, atol=1e-12)
    assert sink.pushed == summary.cycles and sink.closed
    assert len(sink.stats) >= 3                      # one timing record per 0.1 s window
    assert summary.timing["cycles"] == summary.cycles


def test_drive_fault_zero_torque_same_cycle_and_disable(tmp_path: Path) -> None:
    journal: list[str] = []
    motor = FakeMotor(journal, fault_at=200)
    d, motor, ctl, sink, journal, _ = make(tmp_path, motor=motor)
    with pytest.raises(ControlFaultError, match="DRIVE_FAULT.*over current") as ei:
        d.run(duration_s=2.0)
    assert len(motor.sent) == 200                    # the faulting cycle was the last one
    assert motor.sent[-1] == 0.0 and motor.sent[-2] == 0.5
    assert motor.disabled >= 1
    last = ei.value.last_cycles
    assert len(last) == 50 and last["cycle"][-1] == 199
    assert np.all(np.diff(last["cycle"].astype(int)) == 1)
    assert last["ext_fault_bits"][-1] & FaultBits.DRIVE_FAULT
    assert sink.faults and sink.faults[0][2] & FaultBits.DRIVE_FAULT
    assert d.phase == Phase.FAULTED


def test_heartbeat_lost_is_a_fault(tmp_path: Path) -> None:
    journal: list[str] = []
    d, motor, *_ = make(tmp_path, motor=FakeMotor(journal, hb_lost_at=100))
    with pytest.raises(ControlFaultError, match="HEARTBEAT_LOST"):
        d.run(duration_s=2.0)
    assert motor.sent[-1] == 0.0 and motor.disabled >= 1


def test_stale_imu_fault_within_two_cycles_of_detection(tmp_path: Path) -> None:
    d, motor, ctl, *_ = make(tmp_path, imu=FakeImu(stop_after=150))
    with pytest.raises(ControlFaultError, match="STALE_IMU") as ei:
        d.run(duration_s=2.0)
    last = ei.value.last_cycles
    assert motor.sent[-1] == 0.0 and motor.disabled >= 1
    age = last["t_s"] - last["imu_t_s"]
    # the first cycle that saw the IMU older than 50 ms is the last one, and it sent zero
    assert age[-1] > ctl.stale_s and np.all(age[:-1] <= ctl.stale_s)
    assert last["fault_bits"][-1] & FaultBits.STALE_IMU and np.all(last["fault_bits"][:-1] == 0)
    assert last["tau_m_cmd_Nm"][-1] == 0.0 and last["tau_m_cmd_Nm"][-2] == 0.5


def test_non_finite_measurement_is_a_fault(tmp_path: Path) -> None:
    d, motor, *_ = make(tmp_path, cells=FakeLoadCells(nan_at=120))
    with pytest.raises(ControlFaultError, match="NONFINITE_INPUT|T_up_in_N"):
        d.run(duration_s=2.0)
    assert len(motor.sent) == 120 and motor.sent[-1] == 0.0


def test_limit_violation_is_a_fault(tmp_path: Path) -> None:
    imu = FakeImu(q_of_poll=lambda n: 0.2 if n < 200 else 2.5)   # beyond q_out_max_rad = 2.0
    d, motor, *_ = make(tmp_path, imu=imu)
    with pytest.raises(ControlFaultError, match=r"q_out_rad 2.5 outside") as ei:
        d.run(duration_s=2.0)
    assert ei.value.last_cycles["ext_fault_bits"][-1] & LIMIT_VIOLATION
    assert motor.sent[-1] == 0.0 and motor.disabled >= 1


def test_overrun_streak_is_a_fault(tmp_path: Path) -> None:
    journal: list[str] = []
    motor = FakeMotor(journal, slow_from=100, slow_s=0.0025)
    d, motor, *_ = make(tmp_path, motor=motor, stale_s=10.0)   # only the overruns are under test
    with pytest.raises(ControlFaultError, match="OVERRUN_STREAK"):
        d.run(duration_s=2.0)
    # 5 consecutive late cycles (the configured streak) and one more to act on it
    assert 100 + 4 <= len(motor.sent) <= 100 + 8
    assert motor.sent[-1] == 0.0


def test_late_cycles_before_arming_are_a_start_up_timeout_not_a_fault(tmp_path: Path) -> None:
    """A loop that cannot hold its period from the start never commands torque: no OVERRUN_STREAK
    fault while arming (the command is zero), a start-up timeout that names the loop instead."""
    journal: list[str] = []
    motor = FakeMotor(journal, slow_from=0, slow_s=0.0025)          # every cycle 2.5 ms
    d, motor, ctl, *_ = make(tmp_path, motor=motor, stale_s=10.0)
    with pytest.raises(DeviceTimeoutError, match="did not hold its 1 ms period"):
        d.run(duration_s=2.0)
    assert set(motor.sent) == {0.0} and ctl.steps == 0 and "READY=1" not in journal


def test_arms_after_the_configured_on_time_cycles(tmp_path: Path) -> None:
    """READY and the first stepped cycle come after loop.arm_on_time_cycles on-time cycles."""
    d, motor, ctl, sink, journal, _ = make(tmp_path)
    d.run(duration_s=0.2)
    first_step = len(motor.sent) - ctl.steps                        # zero-torque cycles before the first step
    assert 20 <= first_step <= 40 and ctl.steps > 0                 # 20 on time (a late one restarts the count)


def test_sensor_never_healthy_refuses_ready(tmp_path: Path) -> None:
    d, motor, ctl, sink, journal, listener = make(tmp_path, imu=FakeImu(stop_after=0))
    with pytest.raises(DeviceTimeoutError, match="imu"):
        d.run(duration_s=1.0)
    assert "READY=1" not in journal
    assert set(motor.sent) == {0.0}                  # never any torque
    assert motor.disabled >= 1 and ctl.steps == 0


def test_sigterm_ramps_down_and_disables(tmp_path: Path) -> None:
    d, motor, ctl, sink, journal, _ = make(tmp_path)
    def terminate_after_ready() -> None:
        while d.phase != Phase.RUNNING:
            time.sleep(0.005)
        time.sleep(0.3)
        os.kill(os.getpid(), signal.SIGTERM)

    timer = threading.Thread(target=terminate_after_ready)
    timer.start()
    summary = d.run(duration_s=None)
    timer.join()
    assert summary.phase == Phase.STOPPED.name and not summary.faults
    assert motor.sent[-1] == 0.0 and motor.disabled >= 1
    assert 250 <= summary.cycles + summary.missed <= 450
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL   # handler restored


def test_watchdog_pings_only_while_healthy(tmp_path: Path) -> None:
    d, motor, ctl, sink, journal, listener = make(tmp_path, watchdog_usec=20_000, imu=FakeImu(stop_after=300))
    with pytest.raises(ControlFaultError):
        d.run(duration_s=2.0)
    pings = [i for i, j in enumerate(journal) if j == "WATCHDOG=1"]
    # from the loop while it runs, none after the fault: a ping is due 10 ms (half of
    # WATCHDOG_USEC) after the previous one and sent by the first on-time cycle from then,
    # so consecutive pings are 10..11 ms apart, more only across late cycles
    wall, late = d.summary.loop_wall_s, d.summary.timing["late"]
    assert wall > 0.25
    assert wall / 0.011 - late - 2 <= len(pings) <= wall / 0.010 + 2
    assert pings[-1] < max(i for i, j in enumerate(journal) if j.startswith("motor disabled"))
