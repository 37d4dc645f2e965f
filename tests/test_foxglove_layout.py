"""The shipped Foxglove layout (config/foxglove/capstan.json) names only message paths
that exist in a real log: a HIL run of the daemon, decoded with the mcap protobuf
decoder (what Foxglove does with the file's own schema), not with this project's reader.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from capstan.tools.offline.shipped import config_path
from hil_helpers import run_hil

mcap_reader = pytest.importorskip("mcap.reader")
decoder = pytest.importorskip("mcap_protobuf.decoder")

REPO = Path(__file__).resolve().parent.parent
LAYOUT = config_path("foxglove/capstan.json")


def _paths(layout: dict) -> list[str]:
    """Every message path of the layout's panels (plot series, x axes, raw-message topics)."""
    out = []
    for panel in layout["configById"].values():
        out += [p["value"] for p in panel.get("paths", [])]
        if "xAxisPath" in panel:
            out.append(panel["xAxisPath"]["value"])
        if "topicPath" in panel:
            out.append(panel["topicPath"])
    return out


def _panels_in_tree(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict) and node["direction"] in ("row", "column")
    return _panels_in_tree(node["first"]) + _panels_in_tree(node["second"])


def test_layout_is_well_formed_and_every_panel_is_placed() -> None:
    layout = json.loads(LAYOUT.read_text())
    assert sorted(_panels_in_tree(layout["layout"])) == sorted(layout["configById"])
    titles = " ".join(p.get("title", "") for p in layout["configById"].values())
    for must in ("tau_in", "d_hat", "tau_fc", "tensions", "command", "timing", "faults"):
        assert must in titles


@pytest.mark.slow
def test_every_layout_path_resolves_in_a_hil_log(tmp_path: Path) -> None:
    cfg = yaml.safe_load((REPO / "config" / "hil.yaml").read_text())
    cfg["logging"]["dir"] = str(tmp_path / "logs")
    cfg["realtime"]["lock_memory"] = False
    path = tmp_path / "hil.yaml"
    path.write_text(yaml.safe_dump(cfg))
    res, out = run_hil(path, 2.5, REPO)
    assert res.returncode == 0, res.stderr[-3000:]
    last: dict[str, object] = {}
    with open(out["log_path"], "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        topics = {c.topic: c for c in reader.get_summary().channels.values()}
        for _, ch, _, msg in reader.iter_decoded_messages(topics=["/capstan/cycle", "/capstan/stats"]):
            last[ch.topic] = msg
    paths = _paths(json.loads(LAYOUT.read_text()))
    assert len(paths) >= 20
    for p in paths:
        topic, _, field = p.partition(".")
        assert topic in topics, f"{p}: no topic {topic} in the log"
        if field:
            msg = last[topic]
            assert field in {f.name for f in msg.DESCRIPTOR.fields}, f"{p}: no field {field}"
            assert isinstance(getattr(msg, field), (int, float)), f"{p}: not a plottable number"
