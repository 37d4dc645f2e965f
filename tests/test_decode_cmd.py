"""``capstan decode``: JSON lines from raw captures, counts, joint/tension mapping."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from capstan.drivers.serial.loadcell_protocol import build_frame
from capstan.drivers.sim.serial_devices import SimXsens
from capstan.drivers.serial.xsens_protocol import Mid, build_message
from capstan.tools.cli import main

GOLDEN = yaml.safe_load((Path(__file__).parent / "data" / "xsens_mti300_golden.yaml").read_text())


class _Sink:
    """Collects what SimXsens writes (stands in for the pty endpoint)."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.in_waiting = 0

    def write(self, b: bytes) -> int:
        self.data += b
        return len(b)

    def read(self, n: int) -> bytes:
        return b""


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    rc = main(argv)
    return rc, capsys.readouterr().out.splitlines()


def test_decode_xsens_capture_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pkt = GOLDEN["packets"][0]
    blob = bytearray(build_message(Mid.GO_TO_CONFIG_ACK))
    blob += build_message(Mid.ERROR, b"\x04")
    blob += b"\x00\x13garbage\xfa"
    golden = build_message(Mid.MT_DATA2, bytes.fromhex(pkt["data_hex"]))
    blob += golden
    blob += golden[:-1] + bytes((golden[-1] ^ 1,))  # bad checksum
    blob += build_message(Mid.MT_DATA2, bytes.fromhex(GOLDEN["packets"][1]["data_hex"]))  # counter 42577
    cap = tmp_path / "imu.bin"
    cap.write_bytes(bytes(blob))
    rc, lines = _run(["decode", "xsens", str(cap), "--json"], capsys)
    recs = [json.loads(x) for x in lines]
    assert rc == 0
    assert recs[0] == {"frame": 1, "mid": "GO_TO_CONFIG_ACK"}
    assert recs[1]["error"] == "INVALID_MESSAGE" and recs[1]["error_code"] == 4
    assert recs[2]["packet_counter"] == 42581 and recs[2]["sample_time_fine"] == 5719854
    assert recs[2]["quaternion"] == pytest.approx(pkt["quaternion"], abs=5.1e-9)
    assert recs[2]["status_word"] == 0x00400003
    assert recs[2]["other"]["BARO_PRESSURE"] == 100062
    summary = recs[-1]
    assert summary["summary"] is True
    assert summary["good_frames"] == 4 and summary["bad_frames"] >= 1
    assert summary["resyncs"] >= 2
    assert summary["bytes"] == len(blob)


def test_decode_xsens_with_joint_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sink = _Sink()
    sim = SimXsens(sink, joint_axis="y", sign=-1.0, offset_rad=0.2)
    for k in range(5):
        if k == 3:
            sim.packet_counter += 2  # two samples lost on the line
        sim.emit(k / 400, 0.1 * k, -0.5 * k)
    cap = tmp_path / "imu.bin"
    cap.write_bytes(bytes(sink.data))
    cfg = tmp_path / "dev.yaml"
    cfg.write_text("imu:\n  port: /dev/ttyUSB0\n  joint_axis: y\n  sign: -1\n  offset_rad: 0.2\n")
    rc, lines = _run(["decode", "xsens", str(cap), "--json", "--config", str(cfg)], capsys)
    recs = [json.loads(x) for x in lines]
    assert [r["q_out_rad"] for r in recs[:-1]] == pytest.approx([0.1 * k for k in range(5)], abs=1e-6)
    assert [r["dq_out_rad_s"] for r in recs[:-1]] == pytest.approx([-0.5 * k for k in range(5)], abs=1e-6)
    assert recs[3]["counter_gap"] == 2
    assert recs[-1]["counter_gaps"] == 2 and recs[-1]["bad_frames"] == 0


def test_decode_loadcell_capture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = [build_frame((0.5, 0.6, 0.7, 0.8)), build_frame((0.25, 0.5, 1.0, 2.0))]
    blob = frames[0][5:] + frames[0] + b"\xaa\x01\x02" + frames[1] + frames[1][:-1] + b"\x00"
    cap = tmp_path / "lc.bin"
    cap.write_bytes(blob)
    cfg = tmp_path / "dev.yaml"
    cfg.write_text("load_cells:\n  port: /dev/ttyUSB1\n  scale_N_per_mV_V: [100, 200, 300, 400]\n"
                   "  offset_N: [1, 1, 1, 1]\n  tare_N: [0, 0, 0, 1]\n")
    rc, lines = _run(["decode", "loadcell", str(cap), "--json", "--config", str(cfg)], capsys)
    recs = [json.loads(x) for x in lines]
    assert rc == 0
    assert recs[0]["raw_mV_V"] == [0.5, 0.6000000238418579, 0.699999988079071, 0.800000011920929]
    assert recs[1]["tensions_N"] == pytest.approx([26.0, 101.0, 301.0, 800.0])
    s = recs[-1]
    assert (s["good_frames"], s["bad_frames"], s["resyncs"]) == (2, 2, 2)


def test_decode_text_output_and_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cap = tmp_path / "lc.bin"
    cap.write_bytes(build_frame((1.0, 2.0, 3.0, 4.0)))
    rc, lines = _run(["decode", "loadcell", str(cap)], capsys)
    assert rc == 0 and lines[0] == "#1 raw_mV_V=(1, 2, 3, 4)"
    assert lines[-1].startswith("summary: ") and "good_frames=1" in lines[-1]
    assert main(["decode", "xsens", str(tmp_path / "nope.bin")]) == 2
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert main(["decode", "xsens", str(empty), "--json"]) == 1


def test_console_script(tmp_path: Path) -> None:
    cap = tmp_path / "imu.bin"
    cap.write_bytes(bytes.fromhex("FA FF 31 00 D0"))
    exe = Path(sys.executable).parent / "capstan"
    out = subprocess.run([str(exe), "decode", "xsens", str(cap), "--json"], capture_output=True, text=True,
                         timeout=60, check=True).stdout.splitlines()
    assert json.loads(out[0]) == {"frame": 1, "mid": "GO_TO_CONFIG_ACK"}
    assert json.loads(out[-1])["good_frames"] == 1


CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


@pytest.mark.parametrize("config", ["serial_devices.yaml", "hil.yaml"])
def test_decode_accepts_the_shipped_configs(config: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """The command serial_devices.yaml tells the user to run works on it (and on hil.yaml):
    ``backend`` selects the driver and is dropped, as drivers/registry.py does."""
    sink = _Sink()
    sim = SimXsens(sink)  # the shipped configs: z axis, sign 1, offset 0
    for k in range(3):
        sim.emit(k / 400, 0.2 * k, 0.3)
    cap = tmp_path / "imu.bin"
    cap.write_bytes(bytes(sink.data))
    rc, lines = _run(["decode", "xsens", str(cap), "--json", "--config", str(CONFIG_DIR / config)], capsys)
    recs = [json.loads(x) for x in lines]
    assert rc == 0
    assert [r["q_out_rad"] for r in recs[:-1]] == pytest.approx([0.0, 0.2, 0.4], abs=1e-6)
    assert all(r["coord_sys"] == "ENU" for r in recs[:-1])
    lc = tmp_path / "lc.bin"
    lc.write_bytes(build_frame((0.5, 0.5, 0.5, 0.5)) * 2)
    rc, lines = _run(["decode", "loadcell", str(lc), "--json", "--config", str(CONFIG_DIR / config)], capsys)
    recs = [json.loads(x) for x in lines]
    assert rc == 0 and recs[0]["tensions_N"] == pytest.approx([125.0] * 4)  # 250 N per mV/V


def test_decode_reports_coord_sys_of_the_orientation_item(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    from capstan.drivers.serial.xsens_protocol import build_mtdata2_item, encode_values

    blob = b"".join(build_message(Mid.MT_DATA2, build_mtdata2_item(0x2010 | coord, encode_values((1, 0, 0, 0), 0)))
                    for coord in (0x0, 0x4, 0x8))
    cap = tmp_path / "imu.bin"
    cap.write_bytes(blob)
    rc, lines = _run(["decode", "xsens", str(cap), "--json"], capsys)
    assert [json.loads(x).get("coord_sys") for x in lines[:-1]] == ["ENU", "NED", "NWU"]


def test_decode_refuses_a_config_of_another_backend(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    cap = tmp_path / "imu.bin"
    cap.write_bytes(build_message(Mid.GO_TO_CONFIG_ACK))
    cfg = tmp_path / "dev.yaml"
    cfg.write_text("imu:\n  backend: vectornav\n  port: /dev/ttyUSB0\n")
    assert main(["decode", "xsens", str(cap), "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "'imu.backend'" in err and "vectornav" in err
