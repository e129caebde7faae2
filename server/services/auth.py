"""Admin API keys: the configured key, or keys created with ``indoorpos keys create``."""

from __future__ import annotations

import hashlib
import hmac
import secrets

from sqlalchemy.ext.asyncio import AsyncSession

from server.config import Settings
from server.storage import repositories as repo

KEY_PREFIX = "ipk_"


def digest(secret: str) -> str:
    return hashlib.sha256(secret.encode()).hexdigest()


def new_secret(prefix: str = "") -> str:
    return prefix + secrets.token_urlsafe(32)


async def is_admin_key(s: AsyncSession, settings: Settings, key: str) -> bool:
    configured = settings.admin_key.get_secret_value() if settings.admin_key else None
    if configured and hmac.compare_digest(configured.encode(), key.encode()):
        return True
    return await repo.find_api_key(s, digest(key)) is not None


async def create_admin_key(s: AsyncSession, name: str) -> tuple[str, str]:
    """Create a key; returns (id, key). Only the digest is stored: the key is shown once."""
    key = new_secret(KEY_PREFIX)
    row = await repo.create_api_key(s, name, digest(key))
    return row.id, key
