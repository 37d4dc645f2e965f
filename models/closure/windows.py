"""Contiguous windows of long runs, where the closure's output-error fits start.

On long runs (more than ``WARM_START_SAMPLES`` training samples, e.g. an hour at 1 kHz) a
fit is first solved on a few contiguous windows spread through every run (``WINDOW_S``
long, ``WINDOW_SAMPLES`` in all), then finished on every sample from there
(:mod:`capstan.models.common.projected_lm`); what is reported is the fit on every sample.
Windows keep their run's id, so each run's time and dwell signals stay those of the run;
the simulation restarts from the measured state at each window (a gap in time inside a
run: ``dynamic.baseline.RESTART_GAP_S``), as at the start of a run.
"""

from __future__ import annotations

import numpy as np

from capstan.models.closure.signals import Signals

#: above this many training samples the fits start on windows
WARM_START_SAMPLES = 100_000
#: samples of all windows together
WINDOW_SAMPLES = 40_000
#: length of one window [s]
WINDOW_S = 10.0
#: samples and window length of the in-model candidates' screen (dynamic.long_run)
SCREEN_SAMPLES = 40_000
SCREEN_WINDOW_S = 10.0


def window_index(sig: Signals, max_samples: int | None = None, window_s: float | None = None) -> np.ndarray:
    """Indices of contiguous windows spread evenly through every run of ``sig``: at most
    about ``max_samples`` (default ``WINDOW_SAMPLES``) in all, each run's share proportional
    to its length, windows ``window_s`` (default ``WINDOW_S``) long, the first at the run's
    start. All indices when ``sig`` is not longer than ``max_samples``.

    :raises ValueError: if ``max_samples`` or ``window_s`` is not positive.
    """
    max_samples = WINDOW_SAMPLES if max_samples is None else max_samples
    window_s = WINDOW_S if window_s is None else window_s
    if max_samples <= 0 or not window_s > 0.0:
        raise ValueError(f"window_index: max_samples {max_samples} and window_s {window_s} must be > 0")
    n = len(sig)
    if n <= max_samples:
        return np.arange(n)
    dt = float(np.median(np.diff(sig.t_s))) if n > 1 else 1.0
    length = max(2, int(round(window_s / max(dt, 1e-9))))
    parts = []
    for a, b in sig.segments():
        m = b - a
        share = max(2, int(round(max_samples * m / n)))
        if share >= m:
            parts.append(np.arange(a, b))
            continue
        count = max(1, int(round(share / length)))
        w = max(2, share // count)
        first = a + (np.arange(count) * (m - w)) // max(count - 1, 1)
        parts.append((first[:, None] + np.arange(w)[None, :]).ravel())
    return np.unique(np.concatenate(parts))
