"""Real measured data: the da Vinci cable-tool runs of ``tests/data/davinci-cable-tool``
(MRDLab, ODbL 1.0 / DbCL 1.0) imported through ``config/imports/davinci.yaml`` and closed
with ``capstan close`` on files held out from the fit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from capstan.tools.cli import main
from capstan.tools.offline.run_inputs import load_runs

REPO = Path(__file__).resolve().parent.parent
DATA = REPO / "tests" / "data" / "davinci-cable-tool"
DESC = REPO / "config" / "imports" / "davinci.yaml"
TRAIN = ["Tool_4_Maryland_L2_00.TXT", "Tool_4_Maryland_L2_12.TXT", "Tool_4_Maryland_L2_23.TXT"]
TEST = ["Tool_4_Maryland_L2_33.TXT", "Tool_4_Maryland_L2_43.TXT"]



def test_import_maps_columns_to_si_channels_with_sane_signs() -> None:
    (tab,) = load_runs([str(DATA / TRAIN[0])], str(DESC))
    t = tab.t
    assert t[0] == 0.0 and np.allclose(np.diff(t), 1e-3, atol=1e-6)       # 1 kHz, seconds
    q_in, q_out = tab["q_in"], tab["q_out"]
    # the input follows a 30 deg sine: the spindle angle spans about 60 deg peak to peak
    assert 0.8 < np.ptp(q_in) < 1.3
    # the jaw follows the spindle (positive correlation after the sign of the description)
    assert np.corrcoef(q_in, q_out)[0, 1] > 0.9
    # transmitted torque: output torque rises with input torque
    assert np.corrcoef(tab["tau_in"], tab["tau_out"])[0, 1] > 0.5
    # extra channels stay available to the closure by name
    assert "current_in" in tab.columns and "current_out_cmd" in tab.columns


@pytest.mark.slow
def test_close_on_held_out_files_writes_report_and_improves(tmp_path: Path, capsys) -> None:
    rep = tmp_path / "report"
    args = ["close", *(str(DATA / f) for f in TRAIN), *(a for f in TEST for a in ("--test", str(DATA / f))),
            "--import", str(DESC), "--report", str(rep), "--json", "--no-progress"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {"baseline", "candidates", "selected", "final", "data"}
    assert out["baseline"]["model"] == "reduced" and out["baseline"]["params"]
    assert out["baseline"]["feedforward"]["params"]      # the static map the controller loads
    assert [Path(p).name for p in out["data"]["train"]] == TRAIN
    assert [Path(p).name for p in out["data"]["test"]] == TEST
    words = {"velocity", "acceleration", "position", "dwell", "time", "load", "deflection", "tension",
             "latency", "current_in", "current_out_cmd"}
    for c in out["candidates"]:
        assert set(c["depends_on"]) <= words
        assert {"effect", "rmse_Nm", "improvement", "significant"} <= set(c)
    # the output is held at a constant torque: the dynamic baseline predicts tau_in from
    # q_in and tau_out, and does so well on the held-out files (skill = 1 - RMSE / std)
    b = out["baseline"]
    assert b["target"] == "tau_in" and b["driving"] == ["q_in", "tau_out"]
    assert b["skill"] >= 0.5 and b["rmse_Nm"] < 0.5 * b["target_std_Nm"]
    assert set(b["at_bound"]) <= {"zeta_s", "b_vis_Nms_rad"} and not b["implausible"]
    assert b["params"]["tau_fc_Nm"] > 0.0
    # the drive current and the environment command are second looks at the torques
    excl = {e["signal"]: e["reason"] for e in out["excluded"]}
    assert {"current_in", "current_out_cmd", "load"} <= set(excl)
    assert not any(set(s["depends_on"]) & set(excl) for s in out["selected"])
    assert out["final"]["skill"] >= b["skill"]
    # report, plots, machine-readable summary and the controller fragment
    assert (rep / "report.md").read_text().count("|") > 20
    assert len(list(rep.glob("*.png"))) >= 2
    assert json.loads((rep / "closure.json").read_text())["final"] == out["final"]
    frag = yaml.safe_load((rep / "effects.yaml").read_text())
    assert "effects" in frag["controller"]["feedforward"]
    assert "ODbL" in (rep / "report.md").read_text()          # the data's licence travels with it
