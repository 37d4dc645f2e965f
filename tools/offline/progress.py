"""A minimal progress bar on stderr for the offline log tools (replay, export).

Shown only when enabled (long logs); redraws at most ten times a second.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``label [#####.....]  45%`` on one stderr line.

    :param label: text before the bar.
    :param enabled: draw nothing if False (short logs, ``--json`` pipelines may keep it).
    :param stream: where to draw (stderr).
    """

    def __init__(self, label: str, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.label = label
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self._last = 0.0
        self._drawn = False

    def update(self, done: int, total: int) -> None:
        """Report ``done`` of ``total`` units."""
        if not self.enabled or total <= 0:
            return
        now = time.monotonic()
        if now - self._last < 0.1 and done < total:
            return
        self._last = now
        frac = min(1.0, done / total)
        bar = "#" * int(30 * frac)
        self.stream.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%")
        self.stream.flush()
        self._drawn = True

    def done(self) -> None:
        """Finish the line."""
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False
