"""The allowed import directions (README "Architecture", ``[tool.importlinter]`` in
pyproject.toml) hold on the installed tree, and each contract breaks when a forbidden
import is planted."""

from __future__ import annotations

import ast
import copy
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    tomllib = pytest.importorskip("tomli")

grimp = pytest.importorskip("grimp")
pytest.importorskip("importlinter")
from importlinter import configuration  # noqa: E402
from importlinter.contracts.forbidden import ForbiddenContract  # noqa: E402
from importlinter.contracts.layers import LayersContract  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
CONFIG = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
TYPES = {"layers": LayersContract, "forbidden": ForbiddenContract}
#: the repository folders; their names are not importable packages of their own
OLD_TOP_LEVEL = {"controller", "drivers", "models", "tools"}


@pytest.fixture(scope="module")
def graph():
    configuration.configure()      # import-linter's settings (timer, rendering), as its CLI does
    return grimp.build_graph(*CONFIG["root_packages"], include_external_packages=False, cache_dir=None)


def _contracts():
    session = {k: v for k, v in CONFIG.items() if k != "contracts"}
    return [TYPES[c["type"]](c["name"], session, {k: v for k, v in c.items() if k not in ("name", "type")})
            for c in CONFIG["contracts"]]


def _broken(graph) -> list[str]:
    out = []
    for contract in _contracts():
        check = contract.check(graph, verbose=False)
        if not check.kept:
            out.append(f"{contract.name}: {contract.render_broken_contract(check) or check.metadata}")
    return out


def test_the_tree_keeps_every_import_contract(graph):
    assert _broken(graph) == []


@pytest.mark.parametrize("importer, imported", [
    ("capstan.models.common.errors", "capstan.tools.cli"),                   # physics -> command line
    ("capstan.models.plant.excitation", "capstan.tools.offline.run_inputs"),
    ("capstan.drivers.serial.xsens", "capstan.controller.runtime.daemon"),   # driver -> daemon
    ("capstan.controller.law.step", "capstan.drivers.canopen.motor"),        # pure law -> device
    ("capstan.controller.law.core", "capstan.controller.runtime.daemon"),
    ("capstan.controller.log.writer", "capstan.controller.law.records"),     # log and law independent
    ("capstan.drivers.serial.xsens", "capstan.drivers.canopen.emcy"),        # serial | canopen
    ("capstan.drivers.canopen.motor", "capstan.drivers.sim.drive"),          # driver -> simulator
    ("capstan.models.transmission.reduced", "capstan.models.distributed.model"),
    ("capstan.models.closure.pipeline", "capstan.models.plant.rig"),         # a fit must not know the simulator
    ("capstan.tools.offline.replay", "capstan.tools.commands.replay"),
    ("capstan.tools.bench.step", "capstan.tools.experiments.interaction"),
])
def test_a_planted_forbidden_import_breaks_a_contract(graph, importer, imported):
    planted = copy.deepcopy(graph)
    planted.add_import(importer=importer, imported=imported, line_number=1, line_contents=f"import {imported}")
    assert _broken(planted), f"{importer} -> {imported} is not forbidden by any contract"


def test_no_module_imports_the_folder_names():
    """``import controller`` would load a second copy of the repository folder when run from
    the checkout (the working directory is on sys.path): every import names ``capstan``."""
    bad = []
    for folder in [REPO / n for n in sorted(OLD_TOP_LEVEL)] + [REPO / "tests"]:
        for path in folder.rglob("*.py"):
            tree = ast.parse(path.read_text(), str(path))
            for node in ast.walk(tree):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                bad += [f"{path.relative_to(REPO)}:{node.lineno}: {n}" for n in names
                        if n.split(".")[0] in OLD_TOP_LEVEL]
    assert bad == []
