"""Rotation by size and by age, and retention of the newest N bytes of logs."""

from __future__ import annotations

import numpy as np
import pytest

from capstan.controller.log.mcap_log import McapLog
from capstan.controller.log.reader import read_log
from capstan.controller.runtime.config import DaemonConfig
from capstan.models.common.errors import ConfigError

DT = np.dtype([("cycle", "<u8"), ("t_s", "<f8"), ("x", "<f8")])


def _records(k0: int, n: int) -> np.ndarray:
    r = np.zeros(n, DT)
    r["cycle"] = np.arange(k0, k0 + n)
    r["t_s"] = 10.0 + r["cycle"] * 1e-3
    r["x"] = np.random.default_rng(k0).normal(size=n)          # incompressible: sizes are predictable
    return r


def test_rotation_by_size_and_retention_keeps_the_newest_bytes(tmp_path) -> None:
    keep = 200_000
    log = McapLog(tmp_path, "capstan", DT, rotate_size_bytes=60_000, keep_bytes=keep, flush_interval_s=0)
    for k in range(0, 40_000, 1000):
        log.write_records(_records(k, 1000))
        log.flush()
        log.tick()
    log.close()
    files = sorted(tmp_path.glob("capstan_*.mcap"))
    assert len(log.files) > 6 and log.deleted                  # rotated, and old files went
    assert all(not f.exists() for f in log.deleted) and log.deleted[0] == log.files[0]
    assert sum(f.stat().st_size for f in files[:-1]) <= keep   # the set fits, the open file aside
    assert files[-1] == log.files[-1]
    # what is left is the newest cycles, contiguous up to the last one written
    cycles = np.concatenate([read_log(f).records["cycle"] for f in files])
    assert cycles[-1] == 39_999 and np.all(np.diff(cycles.astype(np.int64)) == 1)
    notices = [e for f in files for e in read_log(f).events if e["reason"].startswith("retention: deleted")]
    assert notices                                              # each deletion is on record


def test_rotation_by_age(tmp_path) -> None:
    log = McapLog(tmp_path, "capstan", DT, rotate_time_s=10.0)
    log.write_records(_records(0, 100))
    log.tick(log._opened_at + 5.0)
    log.write_records(_records(100, 100))
    log.tick(log._opened_at + 10.5)                             # 10 s old: next file
    log.write_records(_records(200, 100))
    log.close()
    assert len(log.files) == 2
    assert list(read_log(log.files[1]).records["cycle"][[0, -1]]) == [200, 299]


@pytest.mark.parametrize("key,value", [("rotate_size_MB", -5), ("rotate_size_MB", 0.5), ("rotate_age_s", 1.0),
                                       ("keep_newest_GB", float("nan")), ("on_writer_loss", "ignore"),
                                       ("max_writer_restarts", -1)])
def test_bad_logging_settings_are_refused_by_key(key: str, value: object) -> None:
    with pytest.raises(ConfigError) as err:
        DaemonConfig.from_mapping({"controller": {}, "motor": {"backend": "canopen"},
                                   "imu": {"backend": "xsens", "port": "/dev/null"},
                                   "load_cells": {"backend": "serial", "port": "/dev/null"},
                                   "logging": {key: value}})
    assert err.value.key == f"logging.{key}"
