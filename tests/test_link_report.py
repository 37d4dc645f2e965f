"""Link counters in the daemon's stats records, status line and summary (fake devices)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from capstan.controller.runtime.link_report import LINK_STATS_FIELDS, link_status
from capstan.controller.runtime.session_log import STATS_DTYPE
from capstan.drivers.interfaces import LinkStats
from tests.daemon_fakes import FakeImu
from tests.test_daemon import make


class CountingImu(FakeImu):
    """A fake IMU whose link sees one bad frame and 7 skipped bytes per 50 polls."""

    def poll(self):  # type: ignore[no-untyped-def]
        s = super().poll()
        if self.polls % 50 == 0:
            self.stats.bad_frames += 1
            self.stats.resyncs += 1
            self.stats.bytes_skipped += 7
        if s is not None:
            self.stats.good_frames += 1
        return s


def test_counters_reach_stats_records_status_line_and_summary(tmp_path: Path) -> None:
    imu = CountingImu()
    d, _motor, _ctl, sink, _journal, listener = make(tmp_path, imu=imu)
    summary = d.run(duration_s=0.4)
    assert set(name for name, _ in LINK_STATS_FIELDS) <= set(STATS_DTYPE.names or ())
    recs = np.concatenate(sink.stats)
    bad = recs["imu_bad_total"]
    assert len(recs) >= 3 and np.all(np.diff(bad.astype(np.int64)) >= 0) and bad[-1] >= 3
    assert np.all(recs["imu_skipped_bytes_total"] == 7 * recs["imu_bad_total"])
    assert np.all(recs["lc_bad_total"] == 0)
    # the summary holds the final counts: at least what the last record saw
    assert summary.links["imu"]["bad_frames"] == imu.stats.bad_frames >= bad[-1]
    assert summary.links["imu"]["bytes_skipped"] == 7 * imu.stats.bad_frames
    assert set(summary.links) == {"imu", "load_cells"}
    status = [m for m in listener.messages() if m.startswith("STATUS=running")]
    m = re.search(r"links imu (\d+) ok/(\d+) bad/(\d+) resync/(\d+) B skipped, load_cells 0 ok/0 bad", status[-1])
    assert m and int(m.group(2)) >= 1 and int(m.group(4)) == 7 * int(m.group(2))


def test_status_text() -> None:
    st = LinkStats(good_frames=5, bad_frames=1, resyncs=2, bytes_skipped=30)
    assert link_status({"imu": st}) == "imu 5 ok/1 bad/2 resync/30 B skipped"
