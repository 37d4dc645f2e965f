"""SerialLoadCells against the simulated amplifier over a real pty; config validation."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator

import pytest

from capstan.drivers.interfaces import LoadCells
from capstan.drivers.serial.loadcell import LoadCellConfig, SerialLoadCells
from capstan.drivers.sim.serial_devices import PtyPair, SerialFault, SimLoadCellAmp, open_pty_pair
from capstan.models.common.errors import ConfigError, DeviceTimeoutError

SECTION = {"scale_N_per_mV_V": [200.0, 250.0, 300.0, 400.0], "offset_N": [1.0, -2.0, 0.0, 5.0]}


def tensions_of_k(k: int) -> tuple[float, float, float, float]:
    """Pull-pull cables around 150 N pretension; input-side upper/lower in antiphase."""
    s = 40.0 * math.sin(2 * math.pi * k / 500)
    return (150.0 + s, 140.0 + 0.9 * s, 140.0 - 0.9 * s, 150.0 - s)


class AmpRunner:
    """Emits frames at 1 kHz on absolute deadlines in a thread (the simulated rig)."""

    def __init__(self, amp: SimLoadCellAmp) -> None:
        self.amp = amp
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.error: BaseException | None = None
        self.k = 0

    def _run(self) -> None:
        try:
            t0 = time.monotonic()
            while not self._stop.is_set():
                self.amp.service()
                now = time.monotonic()
                while t0 + self.k / 1000 <= now:
                    self.amp.emit(tensions_of_k(self.k))
                    self.k += 1
                time.sleep(0.0005)
        except BaseException as exc:
            self.error = exc

    def __enter__(self) -> AmpRunner:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        assert self.error is None, self.error


@pytest.fixture
def pty() -> Iterator[PtyPair]:
    p = open_pty_pair()
    yield p
    p.close()


def _values_seen(k_max: int) -> list[tuple[float, ...]]:
    return [tensions_of_k(k) for k in range(k_max + 1)]


def _match(t: tuple[float, ...], candidates: list[tuple[float, ...]]) -> bool:
    # float32 of raw mV/V: relative error <= 6e-8 of ~0.7 mV/V, times scale <= 400 -> ~2e-5 N
    return any(all(abs(a - b) < 1e-4 for a, b in zip(t, c)) for c in candidates)


def test_driver_streams_scaled_tensions(pty: PtyPair) -> None:
    cfg = LoadCellConfig.from_mapping({"port": pty.slave_path, **SECTION})
    amp = SimLoadCellAmp.from_config(pty.master_fd, {"port": "-", **SECTION})
    lc = SerialLoadCells(cfg)
    assert isinstance(lc, LoadCells)
    with AmpRunner(amp) as run:
        lc.start()
        samples = []
        end = time.monotonic() + 0.4
        while time.monotonic() < end:
            s = lc.poll()
            if s is not None:
                samples.append(s.tensions_N)
            time.sleep(0.001)
        k_max = run.k
    lc.close()
    assert len(samples) > 50
    seen = _values_seen(k_max)
    assert all(_match(t, seen) for t in samples)
    assert lc.stats.bad_frames == 0
    # 1 kHz stream: good frames ~ frames emitted since start (loose, shared machine)
    assert lc.stats.good_frames > 0.5 * 400


def test_tare_removes_bridge_bias(pty: PtyPair) -> None:
    cfg = LoadCellConfig.from_mapping({"port": pty.slave_path, "tare_samples": 50, **SECTION})
    amp = SimLoadCellAmp.from_config(pty.master_fd, {"port": "-", **SECTION}, bias_mV_V=(0.05, -0.02, 0.0, 0.01))
    lc = SerialLoadCells(cfg)
    stop = threading.Event()

    def run() -> None:  # constant tensions (cables unloaded) during the tare
        while not stop.is_set():
            amp.emit((0.0, 0.0, 0.0, 0.0))
            time.sleep(0.001)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        lc.start()
    finally:
        stop.set()
        th.join(2.0)
    # reading at zero tension = scale * ((0 - offset)/scale + bias) + offset = scale * bias
    assert lc.tare_N == pytest.approx((200 * 0.05, 250 * -0.02, 0.0, 400 * 0.01), abs=1e-4)
    amp.emit((100.0, 100.0, 100.0, 100.0))
    time.sleep(0.01)
    s = lc.poll()
    lc.close()
    assert s is not None and s.tensions_N == pytest.approx((100.0,) * 4, abs=1e-3)


def test_bad_frames_and_recovery(pty: PtyPair) -> None:
    cfg = LoadCellConfig.from_mapping({"port": pty.slave_path, **SECTION})
    amp = SimLoadCellAmp.from_config(pty.master_fd, {"port": "-", **SECTION}, seed=2)
    lc = SerialLoadCells(cfg)
    stop = threading.Event()

    def run() -> None:  # stream until start() has seen a frame
        while not stop.is_set():
            amp.emit(tensions_of_k(0))
            time.sleep(0.001)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        lc.start()
    finally:
        stop.set()
        th.join(2.0)
    time.sleep(0.01)
    lc.poll()  # drain what the thread wrote
    good0, bad0, resync0 = lc.stats.good_frames, lc.stats.bad_frames, lc.stats.resyncs
    for fault in (SerialFault.CORRUPT_CHECKSUM, SerialFault.TRUNCATE, SerialFault.GARBAGE):
        amp.emit(tensions_of_k(1))
        amp.inject_fault(fault)
        amp.emit(tensions_of_k(2))
        amp.emit(tensions_of_k(3))
    time.sleep(0.02)
    s = lc.poll()
    lc.close()
    assert s is not None and s.tensions_N == pytest.approx(tensions_of_k(3), abs=1e-4)
    assert lc.stats.bad_frames - bad0 >= 3 and lc.stats.resyncs - resync0 == 3
    # per fault: frames 1 and 3 good, frame 2 good only behind garbage
    assert lc.stats.good_frames - good0 == 2 * 3 + 1


def test_start_times_out_without_stream(pty: PtyPair) -> None:
    lc = SerialLoadCells(LoadCellConfig.from_mapping({"port": pty.slave_path, "timeout_s": 0.05}))
    with pytest.raises(DeviceTimeoutError):
        lc.start()
    lc.close()


@pytest.mark.parametrize("bad,key", [
    ({}, "load_cells.port"),
    ({"port": "/dev/x", "scale_N_per_mV_V": [1, 2, 3]}, "load_cells.scale_N_per_mV_V"),
    ({"port": "/dev/x", "scale_N_per_mV_V": [1, 0, 3, 4]}, "load_cells.scale_N_per_mV_V"),
    ({"port": "/dev/x", "offset_N": [1, 2, "a", 4]}, "load_cells.offset_N"),
    ({"port": "/dev/x", "baudrate": 115200}, "load_cells.baudrate"),
    ({"port": "/dev/x", "tare": 3}, "load_cells.tare"),
])
def test_bad_config_names_key(bad: dict, key: str) -> None:
    with pytest.raises(ConfigError) as ei:
        LoadCellConfig.from_mapping(bad)
    assert ei.value.key == key
