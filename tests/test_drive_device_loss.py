"""Device death named as such: the simulated rig process killed under ``capstan hil`` is reported
as device loss (DEVICE_LOST, "device loss: drive 1 is gone") with exit code 4, and the disable of
the drive that is gone gives up within one heartbeat timeout. The log's fault event is read with
mcap's own reader (not capstan's)."""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader

from hil_helpers import hil_argv

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent


def test_killed_rig_is_device_loss_with_exit_code_4(tmp_path: Path) -> None:
    cfg = yaml.safe_load((REPO / "config" / "hil.yaml").read_text())
    cfg["logging"]["dir"] = str(tmp_path / "logs")
    cfg["realtime"]["lock_memory"] = False
    config = tmp_path / "hil.yaml"
    config.write_text(yaml.safe_dump(cfg))
    proc = subprocess.Popen(hil_argv(config, 60.0, "--json"), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        lines: list[str] = []
        end = time.monotonic() + 90
        while not any("armed after" in ln for ln in lines) and time.monotonic() < end:
            if select.select([proc.stderr], [], [], 1.0)[0]:
                lines.append(proc.stderr.readline())
        assert any("armed after" in ln for ln in lines), "".join(lines[-20:])
        time.sleep(0.5)
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
        rig = [int(p) for p in children if b"capstan.tools.hil.plant" in Path(f"/proc/{p}/cmdline").read_bytes()]
        assert len(rig) == 1
        os.kill(rig[0], signal.SIGKILL)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 4, err[-3000:]
    summary = json.loads(out)
    fault = summary["faults"][0]
    assert "DEVICE_LOST" in fault and "device loss: drive 1 is gone" in fault, fault
    assert "device loss: the simulated rig process is gone" in err
    # the disable gave up within one heartbeat timeout (3 x 10 ms) of trying, not after 3 x 0.5 s:
    # measured as the age of the drive's last heartbeat when the master gave up
    age_ms, window_ms = map(int, re.search(r"no heartbeat for (\d+) ms, none during (\d+) ms", fault).groups())
    assert window_ms == 30 and age_ms < 200, fault
    with open(summary["log_path"], "rb") as fh:
        events = [json.loads(m.data) for _, ch, m in make_reader(fh).iter_messages(topics=["/capstan/events"])]
    faults = [e for e in events if "DEVICE_LOST" in json.dumps(e)]
    assert faults and "device loss" in json.dumps(faults[0])

