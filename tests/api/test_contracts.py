"""Contracts: the committed OpenAPI document and the migrations match the code."""

from __future__ import annotations

import json
from pathlib import Path

from alembic import command
from fastapi import FastAPI

from server.config import Settings
from server.storage import db

OPENAPI = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"


def test_openapi_document_is_current(app: FastAPI) -> None:
    committed = json.loads(OPENAPI.read_text())
    assert app.openapi() == committed, "run `indoorpos openapi` and commit openapi/openapi.json"


def test_migrations_match_the_models(settings: Settings) -> None:
    # raises when the models hold something no migration creates
    command.check(db.alembic_config(settings.resolved_database_url))
