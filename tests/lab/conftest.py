"""Fixtures of the lab's tests."""

from __future__ import annotations

from dataclasses import replace

import pytest

from server.positioning.engines import step_ekf
from server.positioning.engines.registry import ENGINES


@pytest.fixture
def imu_engine(monkeypatch: pytest.MonkeyPatch) -> str:
    """An engine that declares it reads raw IMU samples (step_ekf's code under it)."""
    spec = replace(step_ekf.SPEC, name="imu_probe", uses=frozenset({"imu", "wifi"}))
    monkeypatch.setitem(ENGINES, spec.name, spec)
    return spec.name
