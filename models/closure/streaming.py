"""The closure over more data than fits in memory: the pieces a streamed closure is built
from, each computed on one run (one log file, or the head or tail of a split run) at a time.

A streamed closure (:mod:`capstan.tools.offline.closure_stream` runs it, in one process or
as Dask tasks) passes over the runs three times, holding one run at a time:

1. *rest threshold* -- every run's absolute output velocity, sampled (every k-th sample, an
   equal share of ``VELOCITY_SAMPLES`` per run), pooled: the threshold of the dwell signals is the one
   :func:`capstan.models.closure.signals.signals_from_tables` takes from all runs at once
   (exact when the samples hold every sample; else within the 95th percentile's sampling
   noise);
2. *windows* -- each run's signals derived at the full rate with that threshold (derivatives,
   dwell states: as in memory), then cut to contiguous windows
   spread through the run from a phase of its own, each run's share of a fixed budget
   (``TRAIN_SAMPLES`` / ``TEST_SAMPLES`` over all runs). The closure
   (:func:`capstan.models.closure.pipeline.close`, unchanged) runs on the concatenated
   windows: its fits and held-out scores see at most the budget, whatever the total length;
3. *every-sample scores* -- the baseline and the final model simulated through every sample
   of each held-out run: the sums of :class:`ScoreSums` (count, sum of squares, maximum, the
   target's sums) combine exactly, so the final held-out RMSE is that of every sample.

With runs shorter in all than the budget the windows are every sample and the streamed
closure is the closure in memory (same selections, same figures up to float rounding).
Peak memory: one run's signals plus the windows' budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capstan.models.closure import windows
from capstan.models.closure.dynamic.baseline import DynamicFit
from capstan.models.closure.dynamic.in_model import JointFit
from capstan.models.closure.signals import REST_FLOOR_RAD_S, REST_FRACTION, Signals

#: training / held-out samples the closure's fits and scores see in all (over every run)
TRAIN_SAMPLES = 400_000
TEST_SAMPLES = 200_000
#: samples of |dq_out| over all runs for the pooled rest threshold (each run an equal share)
VELOCITY_SAMPLES = 2_000_000


def velocity_sample(sig: Signals, max_samples: int = VELOCITY_SAMPLES) -> np.ndarray:
    """|dq_out| [rad/s] of every k-th sample of ``sig`` (at most ``max_samples``)."""
    k = max(1, int(math.ceil(len(sig) / max_samples)))
    return np.abs(sig.dq_out_rad_s[::k])


def rest_threshold(samples: list[np.ndarray]) -> float:
    """The rest threshold [rad/s] of :func:`~capstan.models.closure.signals.signals_from_tables`
    from the pooled velocity samples of every run (:func:`velocity_sample`).

    :raises ValueError: if there are no samples.
    """
    v = np.concatenate(samples) if samples else np.zeros(0)
    if v.size == 0:
        raise ValueError("rest_threshold: no velocity samples")
    return max(REST_FLOOR_RAD_S, REST_FRACTION * float(np.percentile(v, 95)))


def run_windows(sig: Signals, share: int, window_s: float | None = None, phase: float = 0.0) -> Signals:
    """Contiguous windows of one run's signals, ``share`` samples in all, ``window_s`` long
    (default ``windows.WINDOW_S``), spread evenly through the run from ``phase`` (a fraction of
    the run's length: give each run another, e.g. :func:`run_phase`, so that when the share
    holds few windows they do not all sit at the runs' starts); every sample when the run is
    not longer than ``share``.

    :raises ValueError: if ``share`` or ``window_s`` is not positive.
    """
    window_s = windows.WINDOW_S if window_s is None else window_s
    if share <= 0 or not window_s > 0.0:
        raise ValueError(f"run_windows: share {share} and window_s {window_s} must be > 0")
    n = len(sig)
    if n <= share:
        return sig
    dt = float(np.median(np.diff(sig.t_s)))
    length = max(2, int(round(window_s / max(dt, 1e-9))))
    count = max(1, int(round(share / length)))
    w = max(2, share // count)
    first = np.sort(((phase + np.arange(count) / count) % 1.0 * (n - w)).astype(np.int64))
    return sig.take(np.unique((first[:, None] + np.arange(w)[None, :]).ravel()))


def run_phase(index: int) -> float:
    """The window phase of the ``index``-th run: the golden-ratio sequence (evenly spread for any
    number of runs)."""
    return float((index * 0.6180339887498949) % 1.0)


def concat(parts: list[Signals]) -> Signals:
    """The runs' signals concatenated as :func:`signals_from_tables` concatenates tables: run
    ids renumbered in order, channel metadata of the first part (the parts must share their
    channels and rest threshold).

    :raises ValueError: if ``parts`` is empty or the parts' channels differ.
    """
    if not parts:
        raise ValueError("concat: no parts")
    first = parts[0]
    for p in parts[1:]:
        if (p.q_in_rad is None) != (first.q_in_rad is None) or (p.tension_N is None) != (first.tension_N is None) \
                or sorted(p.extras) != sorted(first.extras) or (p.environment is None) != (first.environment is None):
            raise ValueError(f"concat: the runs carry different channels ({first.names} vs {p.names})")
    run_ids, offset = [], 0
    for p in parts:
        local = np.unique(p.run_id, return_inverse=True)[1] if len(p) else np.zeros(0, np.int64)
        run_ids.append(local.astype(np.int64) + offset)
        offset += int(local.max()) + 1 if len(p) else 0

    def cat(get) -> np.ndarray | None:
        arrs = [get(p) for p in parts]
        return None if arrs[0] is None else np.concatenate(arrs)

    return Signals(cat(lambda p: p.t_s), np.concatenate(run_ids), cat(lambda p: p.tau_in_Nm),
                   cat(lambda p: p.tau_out_Nm), cat(lambda p: p.q_out_rad), cat(lambda p: p.dq_out_rad_s),
                   cat(lambda p: p.ddq_out_rad_s2), cat(lambda p: p.dwell_s), cat(lambda p: p.rest_s),
                   cat(lambda p: p.slide_rad), cat(lambda p: p.q_in_rad), cat(lambda p: p.tension_N),
                   {k: np.concatenate([p.extras[k] for p in parts]) for k in first.extras},
                   [n for p in parts for n in p.names], first.v_rest_rad_s, first.ratio_q,
                   cat(lambda p: p.environment), dict(first.tied_to), all(p.output_link for p in parts),
                   first.tension_sides)


@dataclass
class ScoreSums:
    """Sums of a prediction's error over samples, combined exactly over runs."""

    n: int = 0
    sse_Nm2: float = 0.0
    max_abs_Nm: float = 0.0
    sum_y_Nm: float = 0.0
    sum_y2_Nm2: float = 0.0

    @classmethod
    def of(cls, y_Nm: np.ndarray, pred_Nm: np.ndarray) -> "ScoreSums":
        """The sums of ``y - pred`` and of ``y`` [Nm]."""
        r = y_Nm - pred_Nm
        return cls(int(r.size), float(np.dot(r, r)), float(np.max(np.abs(r))) if r.size else 0.0,
                   float(np.sum(y_Nm)), float(np.dot(y_Nm, y_Nm)))

    def __add__(self, other: "ScoreSums") -> "ScoreSums":
        return ScoreSums(self.n + other.n, self.sse_Nm2 + other.sse_Nm2, max(self.max_abs_Nm, other.max_abs_Nm),
                         self.sum_y_Nm + other.sum_y_Nm, self.sum_y2_Nm2 + other.sum_y2_Nm2)

    @property
    def rmse_Nm(self) -> float:
        return math.sqrt(self.sse_Nm2 / self.n) if self.n else math.nan

    @property
    def std_Nm(self) -> float:
        """Standard deviation of the target [Nm]."""
        if not self.n:
            return math.nan
        m = self.sum_y_Nm / self.n
        return math.sqrt(max(self.sum_y2_Nm2 / self.n - m * m, 0.0))


@dataclass
class FinalModel:
    """What the every-sample pass needs of a finished dynamic closure: the baseline and the
    final model (the baseline refitted with the selected effects)."""

    fit: DynamicFit
    final: JointFit

    def scores(self, sig: Signals) -> tuple[ScoreSums, ScoreSums]:
        """(baseline, final model) sums on every sample of the held-out ``sig``.

        :raises ModelError: if a simulation fails.
        """
        from capstan.models.closure.dynamic.baseline import _predict, _target

        y = _target(sig, self.fit.spec)
        before = self.fit.predict(sig)
        after = _predict(self.fit.spec.form, self.final.base, sig, self.fit.declared_env, self.final.mods(sig))[0]
        return ScoreSums.of(y, before), ScoreSums.of(y, after)
