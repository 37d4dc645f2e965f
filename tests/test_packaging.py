"""The distribution installs one import name, ``capstan``, with the shipped configs and the
drive's EDS; the package list in pyproject.toml covers every folder with an ``__init__``."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    tomllib = pytest.importorskip("tomli")

REPO = Path(__file__).resolve().parent.parent
SETUP = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_package_list_covers_every_package_folder():
    folders = {"capstan." + p.parent.relative_to(REPO).as_posix().replace("/", ".")
               for top in ("controller", "drivers", "models", "tools")
               for p in (REPO / top).rglob("__init__.py")}
    listed = set(SETUP["packages"]) - {"capstan.config"}
    assert listed == folders


def test_every_package_says_what_lives_there_and_what_it_may_import():
    for top in ("controller", "drivers", "models", "tools"):
        for init in (REPO / top).rglob("__init__.py"):
            doc = init.read_text()
            assert doc.lstrip().startswith('"""'), f"{init.relative_to(REPO)} has no docstring"


def test_no_folder_holds_more_than_fifteen_modules():
    for top in ("controller", "drivers", "models", "tools"):
        for folder in [REPO / top, *(p.parent for p in (REPO / top).rglob("*/__init__.py"))]:
            modules = [p for p in folder.glob("*.py") if p.name != "__init__.py"]
            assert len(modules) <= 15, f"{folder.relative_to(REPO)}: {len(modules)} modules"


def test_shipped_configs_resolve_through_the_installed_package():
    from capstan.tools.offline.shipped import config_path, shipped_names

    names = shipped_names()
    for must in ("hil.yaml", "rig.yaml", "controller.yaml", "motor.yaml", "systemd/capstan.service",
                 "foxglove/capstan.json"):
        assert must in names
    assert config_path("hil.yaml").read_text() == (REPO / "config" / "hil.yaml").read_text()
    from capstan.drivers.canopen.config import DATA_DIR
    assert (DATA_DIR / "capstan_drive.eds").is_file()


@pytest.mark.slow
def test_built_wheel_has_one_top_level_name_and_carries_the_data(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path), str(REPO)],
                         capture_output=True, text=True, timeout=600)
    if res.returncode != 0 and "No matching distribution" in res.stderr:
        pytest.skip("no package index for the build requirements")
    assert res.returncode == 0, res.stderr[-2000:]
    (wheel,) = tmp_path.glob("capstan-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {"capstan", wheel.name.split("-")[0] + "-" + wheel.name.split("-")[1]
                                                + ".dist-info"}
    for must in ("capstan/config/hil.yaml", "capstan/config/rig.yaml", "capstan/config/controller.yaml",
                 "capstan/drivers/canopen/data/capstan_drive.eds", "capstan/tools/cli.py",
                 "capstan/config/foxglove/capstan.json"):
        assert must in names
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "capstan = capstan.tools.cli:main" in entry
    assert "capstan_unix = capstan.drivers.can_unix:UnixSocketBus" in entry
