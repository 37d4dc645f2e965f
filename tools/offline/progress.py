"""The progress bar of the offline log tools (replay, export), drawn by ``rich`` on stderr.

Shown only when enabled (long logs). Redrawn from :meth:`Progress.update` at most ten
times a second (no refresh thread).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from rich.console import Console
from rich.progress import BarColumn, TaskProgressColumn, TextColumn, TimeElapsedColumn
from rich.progress import Progress as _RichProgress


class Progress:
    """``label ━━━━━━━━━╺━━━━━━━  45% 0:00:01`` on stderr.

    :param label: text before the bar.
    :param enabled: draw nothing if False (short logs).
    :param stream: where to draw (stderr).
    """

    def __init__(self, label: str, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.label = label
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self._bar: _RichProgress | None = None
        self._task = 0
        self._last = 0.0

    def update(self, done: int, total: int) -> None:
        """Report ``done`` of ``total`` units."""
        if not self.enabled or total <= 0:
            return
        if self._bar is None:
            console = Console(file=self.stream, highlight=False)
            self._bar = _RichProgress(TextColumn(self.label), BarColumn(), TaskProgressColumn(),
                                      TimeElapsedColumn(), console=console, auto_refresh=False)
            self._bar.start()
            self._task = self._bar.add_task(self.label, total=total)
        self._bar.update(self._task, completed=min(done, total), total=total)
        now = time.monotonic()
        if now - self._last >= 0.1 or done >= total:
            self._last = now
            self._bar.refresh()

    def done(self) -> None:
        """Finish the bar (its last state stays on the line)."""
        if self._bar is not None:
            self._bar.refresh()
            self._bar.stop()
            self._bar = None
