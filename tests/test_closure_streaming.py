"""The streamed closure (models/closure/streaming.py, tools/offline/closure_stream.py): on runs
that fit in the windows' budget it is the closure in memory (same selections, same figures up to
float rounding); its pieces combine exactly; on a real Dask cluster -- a ``dask scheduler`` and a
``dask worker`` started as separate processes -- it gives what the single process gives.

The runs are the closure benchmark's testbed plant (tools/bench/closure.py: a friction that grows
along the output angle), written as CSV tables and read back through ``load_run``; the in-memory
reference is ``capstan close``'s own path (signals_from_tables of every run, pipeline.close).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from capstan.models.closure.pipeline import close, split_single
from capstan.models.closure.signals import signals_from_tables
from capstan.models.closure.streaming import ScoreSums, concat, rest_threshold, run_windows, velocity_sample
from capstan.models.common.measurement_table import write_table
from capstan.tools.bench.closure import synthetic_run
from capstan.tools.offline.closure_stream import (DaskMapper, close_streamed, in_process, pieces,
                                                  replace_files)
from capstan.tools.offline.run_inputs import load_runs


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """Three 15 s runs of the testbed plant (seeds 0-2) as CSV tables."""
    d = tmp_path_factory.mktemp("runs")
    return [str(write_table(synthetic_run(0.25, seed=s, position_gain=0.3), d / f"run{s}.csv")) for s in range(3)]


def _selected(res) -> list[str]:
    return [c.effect for t in res.targets.values() for c in t.selected]


def test_pieces_combine_exactly(runs: list[str]) -> None:
    """Windows of a run are its samples at the window indices; the rest threshold from the pooled
    velocity samples is the in-memory one when the samples hold every sample; the score sums of
    the pieces are those of the concatenation (RMSE to float rounding, maximum exactly)."""
    tabs = load_runs(runs)
    whole = signals_from_tables(tabs)
    parts = [signals_from_tables([t], whole.v_rest_rad_s) for t in tabs]
    assert rest_threshold([velocity_sample(p, 10 ** 9) for p in parts]) == pytest.approx(whole.v_rest_rad_s,
                                                                                         rel=1e-12)
    cat = concat(parts)
    np.testing.assert_array_equal(cat.run_id, whole.run_id)
    np.testing.assert_array_equal(cat.dwell_s, whole.dwell_s)     # dwell states derived per run, as in memory
    w = run_windows(parts[0], 4000, 2.0)
    assert 3000 <= len(w) <= 4000 and len(w) < len(parts[0])
    assert np.all(np.isin(w.t_s, parts[0].t_s))
    assert len(run_windows(parts[0], 10 ** 9)) == len(parts[0])
    one = run_windows(parts[0], 2000, 2.0, phase=0.5)      # one window, half-way through the run
    assert len(one) == 2000 and one.t_s[0] == pytest.approx(0.5 * (parts[0].t_s[-1] - 2.0), abs=0.01)
    rng = np.random.default_rng(1)
    pred = [p.tau_out_Nm + 0.1 * rng.standard_normal(len(p)) for p in parts]
    total = sum((ScoreSums.of(p.tau_out_Nm, q) for p, q in zip(parts, pred)), ScoreSums())
    r = whole.tau_out_Nm - np.concatenate(pred)
    assert total.n == len(whole)
    assert total.rmse_Nm == pytest.approx(float(np.sqrt(np.mean(r ** 2))), rel=1e-12)
    assert total.max_abs_Nm == float(np.max(np.abs(r)))
    assert total.std_Nm == pytest.approx(float(np.std(whole.tau_out_Nm)), rel=1e-9)


@pytest.mark.slow
def test_streamed_equals_in_memory_within_the_budget(runs: list[str], long_path: None) -> None:
    """One run split 70/30, shorter than the windows' budget: the streamed closure (runs read one
    at a time) selects what the closure in memory selects, with the same held-out RMSE, and its
    every-sample pass (the final model simulated again on the held-out run) reproduces it."""
    sig = signals_from_tables(load_runs(runs[:1]))
    ref = close(*split_single(sig))
    train, test = pieces(runs[:1], [], None, 0.7)
    out = close_streamed(train, test, in_process)
    assert _selected(ref), "the plant's position friction should be selected"
    assert _selected(out.result) == _selected(ref)
    main_ref, main = next(iter(ref.targets.values())), next(iter(out.result.targets.values()))
    assert main.rmse_after_Nm == pytest.approx(main_ref.rmse_after_Nm, rel=1e-9)
    assert out.v_rest_rad_s == pytest.approx(sig.v_rest_rad_s, rel=1e-12)
    b, f = out.every_sample
    assert f.n == len(split_single(sig)[1])
    assert f.rmse_Nm == pytest.approx(main_ref.rmse_after_Nm, rel=1e-9)
    assert b.rmse_Nm == pytest.approx(main_ref.rmse_before_Nm, rel=1e-9)


def test_outputs_replace_whole_files(tmp_path: Path) -> None:
    """Outputs appear in the report directory only when the block ends without error; an earlier
    file is replaced, never truncated."""
    out = tmp_path / "rep"
    out.mkdir()
    (out / "closure.json").write_text("old")
    with pytest.raises(RuntimeError):
        with replace_files(out) as tmp:
            (tmp / "closure.json").write_text("half")
            raise RuntimeError("a task failed")
    assert (out / "closure.json").read_text() == "old"
    with replace_files(out) as tmp:
        (tmp / "closure.json").write_text("new")
    assert (out / "closure.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]       # no temporary left


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def dask_cluster(tmp_path: Path):
    """A ``dask scheduler`` and one ``dask worker`` (one process, one thread) on 127.0.0.1, as
    separate processes; stopped afterwards."""
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    exe = str(Path(sys.executable).parent / "dask")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), MPLBACKEND="Agg")
    log = open(tmp_path / "dask.log", "w")
    procs = [subprocess.Popen([exe, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=log, stderr=subprocess.STDOUT, env=env)]
    procs.append(subprocess.Popen([exe, "worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
                                   "--host", "127.0.0.1"], stdout=log, stderr=subprocess.STDOUT, env=env))
    try:
        from dask.distributed import Client

        with Client(addr, timeout=60) as c:
            c.wait_for_workers(1, timeout=60)
        yield addr
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        log.close()


@pytest.mark.slow
def test_a_real_dask_cluster_gives_the_single_process_result(runs: list[str], dask_cluster: str,
                                                             long_path: None, tmp_path: Path) -> None:
    """Two training runs and a held-out run, each a task on a scheduler and a worker started as
    separate processes, through ``capstan close --scheduler``: the same selections and every-sample
    figures as ``capstan close --stream`` in this process (windows of a budget smaller than the runs,
    so the windows are cut on the worker)."""
    from capstan.tools.cli import main

    args = [runs[0], runs[1], "--test", runs[2], "--no-progress", "--train-samples", "12000",
            "--test-samples", "8000"]
    t0 = time.perf_counter()
    assert main(["close", *args, "--report", str(tmp_path / "one"), "--stream"]) == 0
    assert main(["close", *args, "--report", str(tmp_path / "dask"), "--scheduler", dask_cluster]) == 0
    one = json.loads((tmp_path / "one" / "closure.json").read_text())
    dsk = json.loads((tmp_path / "dask" / "closure.json").read_text())
    print(f"two closures in {time.perf_counter() - t0:.1f} s")
    assert one["streamed"]["window_samples"]["train"] < one["streamed"]["samples"]["train"]
    assert [s["effect"] for s in dsk["selected"]] == [s["effect"] for s in one["selected"]]
    # the same model simulated on another process: equal up to float rounding (BLAS sums
    # depend on the arrays' alignment), the claim is float rounding, the tolerance 1e-12
    for key in ("v_rest_rad_s", "samples", "window_samples"):
        assert dsk["streamed"][key] == one["streamed"][key]
    assert dsk["streamed"]["every_sample"] == pytest.approx(one["streamed"]["every_sample"], rel=1e-12)
    assert dsk["final"] == pytest.approx(one["final"], rel=1e-12)
    assert dsk["streamed"]["every_sample"]["held_out_samples"] == 15000


@pytest.mark.slow
def test_a_worker_killed_mid_job_is_replaced_and_the_result_is_right(runs: list[str], dask_cluster: str,
                                                                     long_path: None) -> None:
    """The worker process is killed (SIGKILL) while the job's first pass is running: its nanny
    starts a new one, Dask runs the lost tasks again, and the closure is that of the single
    process."""
    import signal
    import threading

    from dask.distributed import Client

    train, test = pieces(runs[:2], runs[2:], None, 0.7)
    ref = close_streamed(train, test, in_process, train_samples=12000, test_samples=8000)
    mapper = DaskMapper(address=dask_cluster)
    out: dict = {}
    job = threading.Thread(target=lambda: out.update(r=close_streamed(train, test, mapper, train_samples=12000,
                                                                      test_samples=8000)))
    try:
        with Client(dask_cluster, timeout=30) as watch:
            pid = next(iter(watch.run(os.getpid).values()))
            job.start()
            deadline = time.monotonic() + 60
            while not any(watch.processing().values()) and time.monotonic() < deadline:
                time.sleep(0.005)
            assert job.is_alive(), "the job ended before a task ran on the worker"
            os.kill(pid, signal.SIGKILL)
        job.join(timeout=600)
        assert not job.is_alive()
    finally:
        mapper.close()
    res = out["r"]
    assert _selected(res.result) == _selected(ref.result)
    assert res.every_sample[1].rmse_Nm == pytest.approx(ref.every_sample[1].rmse_Nm, rel=1e-12)
