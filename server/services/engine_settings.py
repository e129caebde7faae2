"""Engine parameters a site or a session chooses: overrides of an engine's defaults.

Three layers, later ones winning field by field (``params.merge``): the engine's defaults
(the papers' values and the choices recorded in bench/accuracy.md), the site's settings
(``PUT /v1/sites/{id}/engines/{name}``, kept in SQL), and the ``params`` of
``POST /v1/sessions``. A session keeps the overrides it started with, so a later change
of the site's settings reaches new sessions only. Every layer is checked against the
engine's parameter model (``server.positioning.model.params``): a bad field is a 422 naming it
(``params.particles.n``).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import orjson
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.engines.registry import ENGINES, get_engine
from server.positioning.engines.shared.spec import Engine
from server.positioning.model.params import ParamError, Params, as_dict, merge
from server.services.errors import Invalid, NotFound
from server.services.sites import get_site
from server.storage.repositories import engine_settings as repo

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class EngineSettings:
    site_id: str
    engine: str
    overrides: dict[str, Any]  # what the site set
    effective: dict[str, Any]  # every parameter a new session of the site starts with
    # why the stored overrides are not used (a newer server's parameters refuse them)
    problem: str | None = None


def engine_of(name: str, field: str = "engine") -> Engine:
    """The registered engine ``name``; 422 (404 for a path) naming the known ones."""
    if name not in ENGINES:
        known = ", ".join(sorted(ENGINES))
        message = f"unknown engine {name!r}; known engines: {known}"
        raise (NotFound(message, field=field) if field == "name" else Invalid(message, field=field))
    return get_engine(name)


def checked(engine: Engine, overrides: Mapping[str, Any], field: str = "params") -> Params:
    """The engine's parameters with ``overrides``; 422 naming the dotted field."""
    try:
        return engine.params(overrides)
    except ParamError as e:
        raise Invalid(e.message, field=f"{field}.{e.field}" if e.field else field) from None


@functools.lru_cache(maxsize=512)
def _parsed(engine: str, overrides_json: bytes) -> Params:
    spec = get_engine(engine)
    try:
        return spec.params(orjson.loads(overrides_json))
    except ParamError as e:
        # valid when the session started; a newer server's parameters refuse them
        logger.warning("%s parameters %s no longer valid (%s): defaults", engine, overrides_json, e)
        return spec.params()


def canonical(overrides: Mapping[str, Any]) -> bytes:
    """The overrides as the JSON a session keeps (keys sorted, so equal ones share a
    cache entry)."""
    return orjson.dumps(overrides, option=orjson.OPT_SORT_KEYS)


def session_params(engine: str, overrides_json: bytes) -> Params:
    """A running session's parameters from the overrides it keeps (parsed once per
    process and set of overrides)."""
    return _parsed(engine, overrides_json or b"{}")


async def site_overrides(s: AsyncSession, site_id: str, engine: str) -> dict[str, Any]:
    """The site's overrides for ``engine``; none when it set none or when what it set is
    no longer valid (a newer server's parameters refuse it: logged, and ``GET`` of the
    settings says why)."""
    row = await repo.get_engine_setting(s, site_id, engine)
    if row is None:
        return {}
    try:
        get_engine(engine).params(row.params)
    except (KeyError, ParamError) as e:
        logger.warning("site %s: %s settings no longer valid (%s), not used", site_id, engine, e)
        return {}
    return dict(row.params)


async def for_new_session(
    s: AsyncSession, site_id: str, engine: str, overrides: Mapping[str, Any] | None
) -> bytes:
    """The overrides a new session starts with (site's, then its own), checked; as
    ``canonical`` JSON."""
    spec = engine_of(engine)
    merged = merge(await site_overrides(s, site_id, engine), overrides or {})
    checked(spec, merged)
    return canonical(merged)


def _settings(site_id: str, engine: str, stored: dict[str, Any]) -> EngineSettings:
    spec = get_engine(engine)
    try:
        return EngineSettings(site_id, engine, stored, as_dict(spec.params(stored)))
    except ParamError as e:
        return EngineSettings(site_id, engine, stored, defaults(engine), problem=str(e))


async def get_settings(s: AsyncSession, site_id: str, engine: str) -> EngineSettings:
    await get_site(s, site_id)
    engine_of(engine, field="name")
    row = await repo.get_engine_setting(s, site_id, engine)
    return _settings(site_id, engine, dict(row.params) if row is not None else {})


async def list_settings(s: AsyncSession, site_id: str) -> list[EngineSettings]:
    """Every registered engine with the site's overrides (empty where it set none)."""
    await get_site(s, site_id)
    rows = {row.engine: dict(row.params) for row in await repo.list_engine_settings(s, site_id)}
    return [_settings(site_id, name, rows.get(name, {})) for name in sorted(ENGINES)]


async def put_settings(
    s: AsyncSession, site_id: str, engine: str, overrides: Mapping[str, Any]
) -> EngineSettings:
    """Replace the site's overrides for ``engine`` (checked first)."""
    await get_site(s, site_id)
    spec = engine_of(engine, field="name")
    params = checked(spec, overrides)
    await repo.put_engine_setting(s, site_id, engine, dict(overrides))
    return EngineSettings(site_id, engine, dict(overrides), as_dict(params))


async def delete_settings(s: AsyncSession, site_id: str, engine: str) -> None:
    """Back to the engine's defaults for the site's new sessions."""
    await get_site(s, site_id)
    engine_of(engine, field="name")
    await repo.delete_engine_setting(s, site_id, engine)


def defaults(engine: str) -> dict[str, Any]:
    return as_dict(get_engine(engine).params())
