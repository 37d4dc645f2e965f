"""One command-line convention (tools/cli.py's docstring), checked on every subcommand's parser
and on the ``--help`` a user reads; errors are one plain line with exit code 2."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import pytest

from capstan.tools.cli import COMMANDS, build_parser, main

REPO = Path(__file__).resolve().parent.parent
OPTION = re.compile(r"^(-[a-zA-Z]|--[a-z0-9]+(-[a-z0-9]+)*)$")
#: leaves that do not report a result: they print files or the reference as they are
NO_REPORT = {"capstan config"}


def _leaves() -> list[tuple[str, argparse.ArgumentParser]]:
    """(name, parser) of every subcommand, and of every sub-subcommand in place of its parent."""
    out = []
    for name in sorted(COMMANDS):
        parser = build_parser(name)
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out.append((f"capstan {name}", parser))
        for action in subs:
            out += [(f"capstan {name} {sub}", p) for sub, p in action.choices.items()]
    return out


LEAVES = _leaves()


@pytest.mark.parametrize("name,parser", LEAVES, ids=[n for n, _ in LEAVES])
def test_every_subcommand_follows_the_convention(name: str, parser: argparse.ArgumentParser) -> None:
    visible = [a for a in parser._actions if a.option_strings and a.help != argparse.SUPPRESS]
    strings = {s for a in visible for s in a.option_strings}
    assert {"-v", "--verbose"} <= strings, f"{name}: no -v/--verbose"
    if name not in NO_REPORT:
        assert "--json" in strings, f"{name}: reports without --json"
    for a in visible:
        for s in a.option_strings:
            assert OPTION.match(s), f"{name}: {s} is not lower-case words joined by '-'"
            assert "duration" not in s or s.endswith("-s"), f"{name}: {s} has no unit (--duration-s)"
        assert a.help, f"{name}: {a.option_strings[0]} has no help"
        # an option takes one value: nargs '+', '*' or REMAINDER would swallow the positionals
        assert a.nargs not in ("+", "*", argparse.REMAINDER), f"{name}: {a.option_strings[0]} takes a list"
        # an off switch comes with its on switch (--plot / --no-plot), never alone
        for s in a.option_strings:
            if s.startswith("--no-"):
                assert "--" + s[5:] in a.option_strings, f"{name}: {s} without {'--' + s[5:]}"


@pytest.mark.parametrize("argv", [["hil", "--help"], ["experiment", "loop", "--help"], ["close", "--help"]])
def test_help_text_shows_the_convention(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as ex:
        main(argv)
    assert ex.value.code == 0
    text = capsys.readouterr().out
    assert "-v, --verbose" in text and "--json" in text
    assert "--duration " not in text and "--duration\n" not in text


def test_verbose_after_a_sub_subcommand_is_accepted() -> None:
    parser = build_parser("experiment")
    args = parser.parse_args(["loop", "-v"])
    assert args.verbose is True
    assert parser.parse_args(["-v", "loop"]).verbose is True
    assert parser.parse_args(["loop"]).verbose is False


def test_repeated_test_option_keeps_the_training_runs() -> None:
    """``--test`` takes one run per use, so it cannot swallow the training runs after it."""
    args = build_parser("close").parse_args(["--test", "bad.csv", "hil.csv", "--report", "r4"])
    assert args.train == ["hil.csv"] and args.test == ["bad.csv"]
    args = build_parser("close").parse_args(["a.csv", "d.csv", "--test", "b.csv", "--test", "c.csv",
                                             "--report", "r"])
    assert args.train == ["a.csv", "d.csv"] and args.test == ["b.csv", "c.csv"]


def test_plot_switches_are_one_spelling() -> None:
    assert build_parser("simulate").parse_args(["s.yaml", "--out", "o.csv"]).plot is False
    assert build_parser("simulate").parse_args(["s.yaml", "--out", "o.csv", "--plot"]).plot is True
    assert build_parser("replay").parse_args(["l.mcap"]).plot is True
    assert build_parser("replay").parse_args(["l.mcap", "--no-plot"]).plot is False


def test_deprecated_duration_spelling_still_parses() -> None:
    assert build_parser("hil").parse_args(["--duration", "3"]).duration_s == 3.0
    assert build_parser("run").parse_args(["--config", "x.yaml", "--duration-s", "2"]).duration_s == 2.0


def test_error_is_one_plain_line_with_exit_code_2() -> None:
    """A library error: one line naming the command, the file and why; no log record, no traceback."""
    res = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "config", "show", "rig"],
                         capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("capstan config: config file 'rig': not a shipped file; shipped: ")
    assert "ERROR" not in lines[0] and "config key" not in lines[0]


def test_bad_value_is_one_plain_line(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "hil", "--duration-s", "0"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == "capstan hil: --duration-s must be given and > 0, got 0.0"


@pytest.mark.slow
def test_run_that_fails_before_the_first_cycle_leaves_no_log(tmp_path: Path) -> None:
    """A start that fails on its devices (here: an IMU port that does not exist) exits 2 and
    leaves no MCAP file: under systemd every restart would leave another empty one."""
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(
        "controller: {}\n"
        f"motor: {{backend: canopen, interface: capstan_unix, channel: {tmp_path / 'bus'}, max_torque_Nm: 15.0}}\n"
        f"imu: {{backend: xsens, port: {tmp_path / 'no_imu'}}}\n"
        f"load_cells: {{backend: serial, port: {tmp_path / 'no_cells'}}}\n"
        f"logging: {{dir: {tmp_path / 'logs'}}}\n"
        "realtime: {mode: 'off', lock_memory: false}\n")
    res = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "run", "--config", str(cfg),
                          "--duration-s", "1"], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("capstan run: cannot open IMU port")
    assert not list((tmp_path / "logs").glob("*.mcap"))
