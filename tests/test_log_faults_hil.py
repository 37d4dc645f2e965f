"""Log faults injected from outside a HIL run (``capstan hil``, processes found by parent
PID, files decoded with ``mcap``'s indexed reader and the mcap protobuf decoder):

* the log writer SIGKILLed: a new writer, a new file whose first event names the gap,
  the summary's dropped count equal to the cycles missing from the files;
* the same with ``logging.on_writer_loss: stop``: the run ramps to zero and exits 3;
* daemon and writer SIGKILLed together: the file does not open indexed; ``capstan
  recover`` makes it open with every streamable cycle; the next start-up removes the
  dead process's shared-memory rings.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from capstan.controller.log.ring import remove_stale_rings, shm_dir
from capstan.tools.cli import main
from hil_helpers import hil_argv, host_stalled, shortest_sensor_timeout_s, wait_for_stderr

mcap_reader = pytest.importorskip("mcap.reader")
decoder = pytest.importorskip("mcap_protobuf.decoder")

REPO = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.slow


def _config(tmp_path: Path, **logging_extra: object) -> Path:
    cfg = yaml.safe_load((REPO / "config" / "hil.yaml").read_text())
    cfg["logging"]["dir"] = str(tmp_path / "logs")
    cfg["logging"].update(logging_extra)
    cfg["realtime"]["lock_memory"] = False
    path = tmp_path / "hil.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _children(pid: int) -> dict[int, str]:
    """pid -> command line of the processes whose parent is ``pid``."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


def _writer_pid(pid: int, timeout_s: float = 5.0, must_exist: bool = True) -> int | None:
    """The log writer among ``pid``'s children; None (``must_exist`` False) if ``pid`` has
    already ended (a host stall can fault a run before the writer is killed)."""
    end = time.monotonic() + timeout_s
    while True:
        found = [p for p, cmd in _children(pid).items() if "capstan.controller.log.writer" in cmd]
        if found:
            return found[0]
        if not must_exist and (not Path(f"/proc/{pid}/cmdline").exists() or _zombie(pid)):
            return None
        if time.monotonic() > end:
            raise AssertionError(f"no log writer among the children of {pid}: {_children(pid)}")
        time.sleep(0.05)


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def _decode(logs: Path) -> tuple[list[int], list[dict]]:
    """Cycle numbers and events of every file, with the indexed reader + protobuf decoder."""
    cycles, events = [], []
    for f in sorted(logs.glob("capstan_*.mcap")):
        with open(f, "rb") as fh:
            r = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
            for _, ch, msg, dec in r.iter_decoded_messages(topics=["/capstan/cycle"]):
                cycles.append(dec.cycle)
            fh.seek(0)
            r = mcap_reader.make_reader(fh)
            events += [dict(json.loads(m.data), file=f.name)
                       for _, _, m in r.iter_messages(topics=["/capstan/events"])]
    return cycles, events


def _start(config: Path, duration_s: float) -> subprocess.Popen:
    return subprocess.Popen(hil_argv(config, duration_s, "--json"), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _kill_writer_run(tmp_path: Path, duration_s: float,
                     **logging_extra: object) -> tuple[int, dict, str, float, Path]:
    """A HIL run whose log writer is SIGKILLed 1.5 s after arming; rerun (fresh log
    directory) when the host stalled the run into a sensor fault, as the other HIL tests.
    Returns exit code, summary, stderr, the seconds from the kill to the exit, and the
    directory of the run that counts."""
    for attempt in range(3):
        d = tmp_path / f"try{attempt}"
        d.mkdir()
        config = _config(d, **logging_extra)
        proc = _start(config, duration_s)
        wait_for_stderr(proc, "armed after")
        time.sleep(1.5)
        t_kill = time.monotonic()
        writer = _writer_pid(proc.pid, must_exist=False)
        if writer is not None:
            os.kill(writer, signal.SIGKILL)
        out, err = proc.communicate(timeout=120)
        summary = json.loads(out)
        if not host_stalled(summary, shortest_sensor_timeout_s(config)):
            assert writer is not None, f"the run ended before its writer could be killed: {summary}\n{err[-3000:]}"
            break
    return proc.returncode, summary, err, time.monotonic() - t_kill, d


def test_sigkilled_writer_is_restarted_and_the_gap_counted_exactly(tmp_path: Path) -> None:
    code, summary, err, _, tmp_path = _kill_writer_run(tmp_path, 5.0)
    assert code == 0 and summary["faults"] == [], err[-3000:]
    cycles, events = _decode(tmp_path / "logs")
    assert len(list((tmp_path / "logs").glob("capstan_*.mcap"))) == 2
    assert len(cycles) == len(set(cycles))
    missing = summary["cycles"] - len(cycles)
    assert missing > 0 and summary["dropped_log_records"] == missing
    gap = [e for e in events if e["kind_name"] == "WRITER_RESTARTED"]
    assert len(gap) == 1 and gap[0]["gap_cycles"] == missing
    assert sorted(set(range(summary["cycles"])) - set(cycles)) == \
        list(range(gap[0]["gap_first_cycle"], gap[0]["gap_last_cycle"] + 1))


def test_writer_loss_with_policy_stop_ramps_down_and_exits_3(tmp_path: Path) -> None:
    code, summary, err, after_kill_s, tmp_path = _kill_writer_run(tmp_path, 30.0, on_writer_loss="stop")
    assert code == 3, err[-3000:]
    assert any("log writer lost" in f and "on_writer_loss: stop" in f for f in summary["faults"])
    assert after_kill_s < 15.0                                # stopped, did not run on unlogged
    cycles, _ = _decode(tmp_path / "logs")                    # the cut file was repaired at close
    assert summary["dropped_log_records"] == summary["cycles"] - len(cycles) > 0


def test_daemon_and_writer_killed_together_recover_and_stale_rings(tmp_path: Path, capsys) -> None:
    proc = _start(_config(tmp_path), 60.0)
    wait_for_stderr(proc, "armed after")
    time.sleep(1.5)
    kids = _children(proc.pid)
    writer = _writer_pid(proc.pid)
    rings = [f for f in shm_dir().glob(f"capstan-ring-{proc.pid}-*")]
    assert len(rings) >= 3
    os.kill(writer, signal.SIGKILL)
    os.kill(proc.pid, signal.SIGKILL)
    for pid in kids:                                          # the simulated rig goes too
        if pid != writer:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    proc.wait(timeout=10)
    time.sleep(0.5)
    [log] = sorted((tmp_path / "logs").glob("capstan_*.mcap"))
    with open(log, "rb") as fh:
        with pytest.raises(Exception):
            mcap_reader.make_reader(fh).get_summary().statistics   # no footer: does not open
    streamed = 0
    with open(log, "rb") as fh:
        try:
            for _ in mcap_reader.NonSeekingReader(fh, record_size_limit=None).iter_messages(
                    topics=["/capstan/cycle"], log_time_order=False):
                streamed += 1
        except Exception:
            pass
    assert main(["recover", str(log), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert not res["was_complete"] and res["chunks"] > 0
    cycles, _ = _decode(tmp_path / "logs")
    assert len(cycles) == streamed > 500                     # everything streamable kept
    assert cycles == list(range(len(cycles)))
    # the dead daemon's rings are still in /dev/shm until the next start-up removes them
    assert all(f.exists() for f in rings)
    removed = remove_stale_rings()
    assert set(rings) <= set(removed) and not any(f.exists() for f in rings)
