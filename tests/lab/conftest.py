"""Fixtures of the lab's tests."""

from __future__ import annotations

from dataclasses import replace

import pytest

from server.positioning.engines import ENGINES, get_engine


@pytest.fixture
def imu_engine(monkeypatch: pytest.MonkeyPatch) -> str:
    """An engine that declares it reads raw IMU samples (step_ekf's code under it)."""
    spec = replace(get_engine("step_ekf"), name="imu_probe", uses=frozenset({"imu", "wifi"}))
    monkeypatch.setitem(ENGINES, spec.name, spec)
    return spec.name
