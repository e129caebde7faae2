"""Fixtures of the API tests that more than one module uses."""

from __future__ import annotations

import httpx
import pytest
from fastapi import FastAPI

from tests.support.quality_floor import survey_floor


@pytest.fixture
async def surveyed(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> tuple[str, str]:
    """The toy floor of ``tests.support.quality_floor``, surveyed: the floor ids of its
    levels 0 and 1."""
    return await survey_floor(client, admin, app)
