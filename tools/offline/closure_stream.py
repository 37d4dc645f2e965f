"""The streamed closure (:mod:`capstan.models.closure.streaming`) over many runs: each run (a
log file, or the head or tail of a single split run) is one task of each pass, run in this
process one after another, or on a Dask cluster (``dask.distributed``: a local cluster of
worker processes, or an existing scheduler) -- Dask schedules, retries the tasks of a worker
that died, and moves the results; this module only states the tasks.

Memory: a task holds one run; the driver holds the windows' budget and the closure on it.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Protocol, Sequence

import numpy as np

from capstan.models.closure import windows
from capstan.models.closure.identification import ModelKind
from capstan.models.closure.pipeline import ClosureResult, Progress, close, split_single
from capstan.models.closure.signals import Signals, signals_from_tables
from capstan.models.closure.streaming import (TEST_SAMPLES, TRAIN_SAMPLES, VELOCITY_SAMPLES, FinalModel, ScoreSums, concat,
                                              rest_threshold, run_phase, run_windows, velocity_sample)
from capstan.models.common.errors import DataFormatError, UsageError
from capstan.models.common.measurement_table import MeasurementTable

#: times Dask runs a task again after its worker died or it raised (then the job fails with the reason)
RETRIES = 2


class RunSource(Protocol):
    """Where one run comes from (picklable: it is sent to the workers)."""

    def table(self) -> MeasurementTable: ...


@dataclass(frozen=True)
class LogFile:
    """A run on disk (``.csv``, ``.mcap``, or a layout of ``import_path``)."""

    path: str
    import_path: str | None = None

    def table(self) -> MeasurementTable:
        """:raises DataFormatError: if the file cannot be read or mapped."""
        from capstan.tools.offline.importer import ImportDescription
        from capstan.tools.offline.run_inputs import load_run

        return load_run(self.path, ImportDescription.load(self.import_path) if self.import_path else None)


@dataclass(frozen=True)
class Piece:
    """A run, or its contiguous training head / held-out tail (``part``: all, head, tail)."""

    source: RunSource
    part: str = "all"
    train_fraction: float = 0.7

    def signals(self, v_rest_rad_s: float | None = None) -> Signals:
        """The piece's signals, derived on the whole run (then split).

        :raises DataFormatError: if the run cannot be read or lacks a required channel.
        """
        sig = signals_from_tables([self.source.table()], v_rest_rad_s)
        if self.part == "all":
            return sig
        head, tail = split_single(sig, self.train_fraction)
        return head if self.part == "head" else tail


# -- the tasks (module-level functions: Dask pickles them by name) ---------------------------

def task_velocity(piece: Piece, max_samples: int) -> tuple[np.ndarray, int, str | None]:
    """(|dq_out| of at most ``max_samples``, samples of the whole run, the run's attribution or None)."""
    tb = piece.source.table()
    sig = signals_from_tables([tb])
    att = tb.meta.get("attribution")
    return velocity_sample(sig, max_samples), len(sig), None if att is None else str(att)


def task_windows(piece: Piece, v_rest_rad_s: float, share: int, window_s: float,
                 phase: float) -> tuple[Signals, int, str]:
    """(the piece's windows of ``window_s`` [s] from ``phase``, ``share`` samples in all; its
    samples; its name)."""
    sig = piece.signals(v_rest_rad_s)
    name = sig.names[0] if sig.names else str(piece.source)
    if piece.part != "all":
        name = f"{name} [{piece.part}, t {sig.t_s[0]:.3f}-{sig.t_s[-1]:.3f} s]"
    return run_windows(sig, share, window_s, phase), len(sig), name


def task_scores(piece: Piece, v_rest_rad_s: float, model: FinalModel) -> tuple[ScoreSums, ScoreSums]:
    """(baseline, final model) sums on every sample of the held-out piece."""
    return model.scores(piece.signals(v_rest_rad_s))


# -- how the tasks run -----------------------------------------------------------------------

Mapper = Callable[[Callable[..., Any], Sequence[tuple]], list]


def in_process(fn: Callable[..., Any], args: Sequence[tuple]) -> list:
    """Run the tasks here, one after another (one run in memory at a time)."""
    return [fn(*a) for a in args]


class DaskMapper:
    """Run the tasks on a Dask cluster: ``workers`` local worker processes
    (``distributed.LocalCluster``, one thread each), or the scheduler at ``address``.

    :raises UsageError: if the scheduler cannot be reached.
    """

    def __init__(self, workers: int | None = None, address: str | None = None, timeout_s: float = 30.0) -> None:
        from dask.distributed import Client, LocalCluster

        self.cluster = None
        if address:
            try:
                self.client = Client(address, timeout=timeout_s)
            except OSError as exc:
                raise UsageError(f"--scheduler {address}: no Dask scheduler answered within {timeout_s:g} s "
                                 f"({exc})") from exc
        else:
            self.cluster = LocalCluster(n_workers=max(1, workers or 1), threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.WARNING)
            self.client = Client(self.cluster)

    def __call__(self, fn: Callable[..., Any], args: Sequence[tuple]) -> list:
        big = {}
        futs = []
        for a in args:
            call = []
            for x in a:     # a model shared by every task is sent once
                if isinstance(x, FinalModel):
                    if id(x) not in big:
                        big[id(x)] = self.client.scatter(x, broadcast=True)
                    x = big[id(x)]
                call.append(x)
            futs.append(self.client.submit(fn, *call, pure=False, retries=RETRIES))
        return self.client.gather(futs)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


@dataclass
class StreamedClosure:
    """A streamed closure's result: the closure on the windows, and the every-sample scores."""

    result: ClosureResult
    train_names: list[str]
    test_names: list[str]
    attributions: list[str]
    v_rest_rad_s: float
    samples: dict[str, int]
    #: samples of the windows the closure ran on (before its own decimation of the static fits)
    window_samples: dict[str, int]
    #: (baseline, final model) sums on every held-out sample; None with the static baseline
    every_sample: tuple[ScoreSums, ScoreSums] | None
    #: wall time of each pass [s]: velocity, windows, closure (on the windows), scores
    timings_s: dict[str, float] = field(default_factory=dict)

    def summary_keys(self) -> dict[str, Any]:
        """The ``streamed`` entry of the closure's JSON summary."""
        d: dict[str, Any] = {"v_rest_rad_s": self.v_rest_rad_s, "samples": self.samples,
                             "window_samples": dict(self.window_samples)}
        if self.every_sample is not None:
            b, f = self.every_sample
            d["every_sample"] = {"held_out_samples": f.n, "baseline_rmse_Nm": b.rmse_Nm, "baseline_max_err_Nm":
                                 b.max_abs_Nm, "final_rmse_Nm": f.rmse_Nm, "final_max_err_Nm": f.max_abs_Nm,
                                 "target_std_Nm": f.std_Nm}
        return d


def pieces(train: list[str], test: list[str], import_path: str | None,
           train_fraction: float) -> tuple[list[Piece], list[Piece]]:
    """The training and held-out pieces of ``capstan close``'s runs (one run and no ``--test``:
    its head and tail).

    :raises DataFormatError: if several runs are given without held-out runs.
    """
    if test:
        return ([Piece(LogFile(p, import_path)) for p in train], [Piece(LogFile(p, import_path)) for p in test])
    if len(train) != 1:
        raise DataFormatError("without --test give exactly one run (it is split into contiguous blocks), "
                              "or name held-out runs with --test")
    src = LogFile(train[0], import_path)
    return [Piece(src, "head", train_fraction)], [Piece(src, "tail", train_fraction)]


def close_streamed(train: list[Piece], test: list[Piece], mapper: Mapper = in_process,
                   kind: ModelKind = ModelKind.REDUCED, dynamic: bool = True, train_samples: int = TRAIN_SAMPLES,
                   test_samples: int = TEST_SAMPLES, window_s: float | None = None,
                   progress: Progress | None = None) -> StreamedClosure:
    """The closure of ``train`` / ``test`` in three passes over the runs
    (:mod:`capstan.models.closure.streaming`), each run a task of ``mapper``; each piece's
    windows ``window_s`` long (default ``windows.WINDOW_S``), a share of ``train_samples`` /
    ``test_samples``.

    :raises DataFormatError: if a run cannot be read or lacks a required channel.
    :raises ModelError: if the baseline cannot be fitted.
    """
    if not train or not test:
        raise DataFormatError("the streamed closure needs training and held-out runs")
    runs: dict[RunSource, Piece] = {}
    for p in train + test:
        runs.setdefault(p.source, Piece(p.source))
    t0 = time.perf_counter()
    vel = mapper(task_velocity, [(p, max(1000, VELOCITY_SAMPLES // len(runs))) for p in runs.values()])
    t1 = time.perf_counter()
    v_rest = rest_threshold([v for v, _, _ in vel])
    attributions = sorted({a for _, _, a in vel if a is not None})
    share_tr = max(2, train_samples // len(train))
    share_te = max(2, test_samples // len(test))
    w_s = windows.WINDOW_S if window_s is None else window_s
    wins = mapper(task_windows, [(p, v_rest, share_tr, w_s, run_phase(i)) for i, p in enumerate(train)]
                  + [(p, v_rest, share_te, w_s, run_phase(i)) for i, p in enumerate(test)])
    tr, te = wins[:len(train)], wins[len(train):]
    t2 = time.perf_counter()
    res = close(concat([w for w, _, _ in tr]), concat([w for w, _, _ in te]), kind, progress=progress,
                dynamic=dynamic)
    t3 = time.perf_counter()
    every = None
    ds = res.dynamic
    if ds is not None and ds.final is not None:
        model = FinalModel(replace(ds.fit, pred_train_Nm=None), ds.final)
        sums = mapper(task_scores, [(p, v_rest, model) for p in test])
        every = (sum((b for b, _ in sums), ScoreSums()), sum((f for _, f in sums), ScoreSums()))
    return StreamedClosure(res, [n for _, _, n in tr], [n for _, _, n in te], attributions, v_rest,
                           {"train": sum(n for _, n, _ in tr), "test": sum(n for _, n, _ in te)},
                           {"train": sum(len(w) for w, _, _ in tr), "test": sum(len(w) for w, _, _ in te)}, every,
                           {"velocity": t1 - t0, "windows": t2 - t1, "closure": t3 - t2,
                            "scores": time.perf_counter() - t3})


@contextmanager
def replace_files(outdir: Path) -> Iterator[Path]:
    """A temporary directory beside ``outdir`` to write into; on success each of its files
    replaces its namesake in ``outdir`` (``os.replace``: never a half-written file there)."""
    outdir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=outdir.parent, prefix=f".{outdir.name}."))
    try:
        yield tmp
        for f in sorted(tmp.iterdir()):
            os.replace(f, outdir / f.name)
    finally:
        for f in tmp.iterdir():
            f.unlink()
        tmp.rmdir()
