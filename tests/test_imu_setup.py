"""``capstan imu setup PORT``: a factory-default MTi (simulated, 115200 Bd) brought to the running rate."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from capstan.drivers.sim.serial_devices import PtyPair, SimXsens, open_pty_pair
from capstan.drivers.serial.xsens import XsensConfig, XsensImu
from capstan.tools.cli import main

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


class Device:
    """The simulated MTi in a thread: services commands and streams at 400 Hz."""

    def __init__(self, sim: SimXsens) -> None:
        self.sim = sim
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        k = 0
        t0 = time.monotonic()
        while not self._stop.is_set():
            self.sim.service()
            while t0 + k / 400 <= time.monotonic():
                self.sim.emit(k / 400, 0.0, 0.0)
                k += 1
            time.sleep(0.0005)

    def __enter__(self) -> Device:
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join(2.0)


@pytest.fixture
def pty() -> Iterator[PtyPair]:
    p = open_pty_pair()
    yield p
    p.close()


def test_setup_finds_a_new_unit_and_stores_the_running_rate(pty: PtyPair, capsys: pytest.CaptureFixture[str]) -> None:
    sim = SimXsens(pty.master_fd, boot_baudrate=115200)
    with Device(sim):
        rc = main(["imu", "setup", pty.slave_path, "--config", str(CONFIG_DIR / "serial_devices.yaml")])
    out = capsys.readouterr().out
    assert rc == 0
    assert f"MTi on {pty.slave_path}: found at 115200 Bd, switched to 921600 Bd (stored in the device)" in out
    assert "QUATERNION|FLOAT32|ENU" in out and "400 Hz" in out
    assert sim.stored_baudrate == 921600 and sim.baudrate == 921600 and sim.resets == 1
    # the daemon's driver now finds it at the first try, without a reset
    imu = XsensImu(XsensConfig.from_mapping({"port": pty.slave_path, "baud_search": False}))
    with Device(sim):
        imu.start()
    imu.close()
    assert imu.found_baudrate == 921600 and sim.resets == 1


def test_setup_json_and_another_running_rate(pty: PtyPair, capsys: pytest.CaptureFixture[str]) -> None:
    sim = SimXsens(pty.master_fd, boot_baudrate=115200)
    with Device(sim):
        rc = main(["imu", "setup", pty.slave_path, "--baudrate", "460800", "--json"])
    rep = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert (rep["found_baudrate"], rep["baudrate"]) == (115200, 460800)
    assert sim.baudrate == 460800
    assert {"item": "RATE_OF_TURN|FLOAT32", "rate_hz": 400} in rep["output_configuration"]


def test_setup_without_device_names_the_rates_and_exits_2(pty: PtyPair, capsys: pytest.CaptureFixture,
                                                          tmp_path: Path) -> None:
    cfg = tmp_path / "imu.yaml"
    cfg.write_text("imu: {backend: xsens, port: /dev/null, timeout_s: 0.02, retries: 1}\n")
    rc = main(["imu", "setup", pty.slave_path, "--config", str(cfg)])
    assert rc == 2
    assert "no answer to GoToConfig at 921600, 115200" in capsys.readouterr().err


def test_setup_refuses_a_rate_the_device_cannot_run(pty: PtyPair, capsys: pytest.CaptureFixture) -> None:
    assert main(["imu", "setup", pty.slave_path, "--baudrate", "115200"]) == 2
    err = capsys.readouterr().err
    assert "imu.baudrate" in err and "cannot carry 400 Hz" in err
