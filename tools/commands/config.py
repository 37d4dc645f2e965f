"""``capstan config list | show NAME | path NAME | reference``: the configuration files shipped
with capstan (rig, HIL, controller and motor sections, scenarios, import descriptions, the
systemd unit), so a plain install has something to start from; ``reference`` prints every key
of a daemon config with its type, unit, range, default and meaning (docs/configuration.md)."""

from __future__ import annotations

import argparse
import sys

from capstan.tools.offline.shipped import config_path, shipped_names

HELP = "list or print the shipped configuration files, or the reference of every key"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``capstan config``."""
    parser.add_argument("action", choices=("list", "show", "path", "reference"),
                        help="list: the shipped names; show: print one; path: where it is installed; "
                             "reference: every key of a daemon config (Markdown, docs/configuration.md)")
    parser.add_argument("name", nargs="?", help="shipped file, e.g. hil.yaml or scenarios/testbed_multisine.yaml")
    parser.add_argument("--controller-example", action="store_true",
                        help="with reference: print the controller section at its defaults (config/controller.yaml)")


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code.

    :raises ConfigError: if ``name`` is not a shipped file.
    """
    if args.action == "list":
        sys.stdout.write("".join(n + "\n" for n in shipped_names()))
        return 0
    if args.action == "reference":
        from capstan.tools.commands.config_reference import controller_example, reference
        sys.stdout.write(controller_example() if args.controller_example else reference())
        return 0
    if not args.name:
        sys.stderr.write(f"capstan config {args.action}: NAME is required (see 'capstan config list')\n")
        return 2
    path = config_path(args.name)
    sys.stdout.write(path.read_text() if args.action == "show" else f"{path}\n")
    return 0
