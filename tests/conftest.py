"""Shared pytest configuration: hardware tests run only with --hardware; the closure's long-run
path with its thresholds lowered (``long_path``)."""

from __future__ import annotations

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--hardware", action="store_true", default=False,
                     help="run tests marked 'hardware' against real devices (rig only)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--hardware"):
        return
    skip = pytest.mark.skip(reason="needs real hardware; run with --hardware on the rig")
    for item in items:
        if "hardware" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def long_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """The closure's long-run path taken by 15 s runs: 15 000 training samples make two 5 s windows
    of 10 000 samples (the shipped figures: an hour's 2.5 M training samples, four 10 s windows of
    40 000)."""
    from capstan.models.closure import windows
    monkeypatch.setattr(windows, "WARM_START_SAMPLES", 5_000)
    monkeypatch.setattr(windows, "WINDOW_SAMPLES", 10_000)
    monkeypatch.setattr(windows, "WINDOW_S", 5.0)
    monkeypatch.setattr(windows, "SCREEN_SAMPLES", 10_000)
    monkeypatch.setattr(windows, "SCREEN_WINDOW_S", 5.0)
