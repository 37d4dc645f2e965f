"""Serial link health in the daemon's reports: the stats record, the status line, the summary.

Per device (``imu``, ``load_cells``) the counters of its
:class:`capstan.drivers.interfaces.LinkStats` since start-up: frames decoded (good),
frames rejected (bad: checksum, impossible length, malformed payload), losses of sync
(resyncs), bytes that belonged to no frame (skipped) and, for the IMU, samples missing
from its packet counter (counter gaps). Totals, not per-window increments, so a lost
stats record loses nothing; the difference of two records is the rate.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

#: (record prefix, device role) of the links reported
LINK_DEVICES: tuple[tuple[str, str], ...] = (("imu", "imu"), ("lc", "load_cells"))
#: (record suffix, LinkStats attribute)
_COUNTERS: tuple[tuple[str, str], ...] = (
    ("good_total", "good_frames"), ("bad_total", "bad_frames"), ("resyncs_total", "resyncs"),
    ("skipped_bytes_total", "bytes_skipped"), ("counter_gaps_total", "counter_gaps"),
)
#: fields appended to the stats record (``/capstan/stats``), counts since start-up
LINK_STATS_FIELDS: list[tuple[str, str]] = [(f"{p}_{suffix}", "u8") for p, _ in LINK_DEVICES
                                            for suffix, _ in _COUNTERS]


def device_links(devices: Any) -> dict[str, Any]:
    """Role -> the device's ``stats`` (a LinkStats) for the roles that have one."""
    out = {}
    for _, role in LINK_DEVICES:
        st = getattr(getattr(devices, role, None), "stats", None)
        if st is not None:
            out[role] = st
    return out


def fill_link_stats(buf: np.ndarray, links: Mapping[str, Any]) -> None:
    """Write the link counters into the (1,) stats buffer (absent devices: 0)."""
    b = buf[0]
    for prefix, role in LINK_DEVICES:
        st = links.get(role)
        for suffix, attr in _COUNTERS:
            b[f"{prefix}_{suffix}"] = int(getattr(st, attr, 0)) if st is not None else 0


def link_summary(links: Mapping[str, Any]) -> dict[str, dict[str, int]]:
    """Role -> {good_frames, bad_frames, resyncs, bytes_skipped, counter_gaps} (JSON-friendly)."""
    return {role: {attr: int(getattr(st, attr, 0)) for _, attr in _COUNTERS} for role, st in links.items()}


def link_status(links: Mapping[str, Any]) -> str:
    """Short text for the status line, e.g. ``imu 400/0 bad/0 resync/0 B skipped``."""
    parts = []
    for role, st in links.items():
        parts.append(f"{role} {st.good_frames} ok/{st.bad_frames} bad/{st.resyncs} resync/"
                     f"{st.bytes_skipped} B skipped")
    return ", ".join(parts)
