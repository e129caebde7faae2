"""API keys with scopes: who may do what, on which site.

A key holds a set of scopes and belongs to one site or to all (``site_id`` None):

* ``admin``: everything, keys included (the configured ``INDOORPOS_ADMIN_KEY`` is one,
  for every site);
* ``maps:write``: floor plans, radio and magnetic surveys, uploads, map activation;
* ``viewer``: reading sites, buildings, floors, maps, their quality and uploads;
* ``device``: opening positioning sessions and ``/v1/locate``;
* ``contribute``: opening sessions whose walk is offered to the map builder.

``admin`` implies every scope and ``maps:write`` implies ``viewer``; ``contribute`` is
asked for on top of ``device``. Only a key's SHA-256 digest is stored: a key is shown
once, when it is made or rotated.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from sqlalchemy.ext.asyncio import AsyncSession

from server.config import Settings
from server.services.errors import Forbidden, Invalid, NotFound, not_found
from server.storage.models import ApiKey
from server.storage.repositories import api_keys as key_repo
from server.storage.repositories import sites as site_repo
from server.storage.repositories.pages import Key, Page

KEY_PREFIX = "ipk_"
SCOPES = ("admin", "maps:write", "viewer", "device", "contribute")
_IMPLIED = {"admin": frozenset(SCOPES), "maps:write": frozenset({"maps:write", "viewer"})}


def digest(secret: str) -> str:
    return hashlib.sha256(secret.encode()).hexdigest()


def new_secret(prefix: str = "") -> str:
    return prefix + secrets.token_urlsafe(32)


@dataclass(frozen=True)
class Principal:
    """Who a request comes from: the key's id (None for the configured admin key), what it
    may do and on which site (None: every site)."""

    key_id: str | None
    scopes: frozenset[str]
    site_id: str | None

    def allows(self, scope: str) -> bool:
        return any(scope in _IMPLIED.get(held, {held}) for held in self.scopes)

    def sees(self, site_id: str) -> bool:
        return self.site_id in (None, site_id)

    def require(
        self, scope: str, site_id: str | None = None, missing: NotFound | None = None
    ) -> None:
        """Raise Forbidden unless the key holds ``scope``; for a thing of ``site_id`` (when
        given) on a site the key is not for, raise ``missing``, the answer for a thing that
        does not exist (by default: no such site), so that another site's ids cannot be
        told from ids that were never made."""
        if not self.allows(scope):
            raise Forbidden(f"this key lacks the {scope!r} scope", field="authorization")
        if site_id is not None and not self.sees(site_id):
            raise missing or not_found("site", site_id)


def check_scopes(scopes: Iterable[str]) -> frozenset[str]:
    wanted = frozenset(scopes)
    unknown = sorted(wanted - set(SCOPES))
    if unknown:
        raise Invalid(f"unknown scopes {unknown}: choose from {list(SCOPES)}", field="scopes")
    if not wanted:
        raise Invalid("a key needs at least one scope", field="scopes")
    return wanted


async def authenticate(s: AsyncSession, settings: Settings, key: str) -> Principal | None:
    """The principal of a key, or None when it is not a live key."""
    configured = settings.admin_key.get_secret_value() if settings.admin_key else None
    if configured and hmac.compare_digest(configured.encode(), key.encode()):
        return Principal(None, frozenset({"admin"}), None)
    row = await key_repo.find_api_key(s, digest(key))
    if row is None:
        return None
    return Principal(row.id, frozenset(row.scopes.split()), row.site_id)


async def create_key(
    s: AsyncSession, name: str, scopes: Iterable[str] = ("admin",), site_id: str | None = None
) -> tuple[ApiKey, str]:
    """Create a key; returns (row, key). Only the digest is stored: the key is shown once."""
    wanted = check_scopes(scopes)
    if site_id is not None and await site_repo.get_site(s, site_id) is None:
        raise not_found("site", site_id)
    key = new_secret(KEY_PREFIX)
    row = await key_repo.create_api_key(
        s, name, digest(key), " ".join(sorted(wanted)), site_id=site_id
    )
    return row, key


async def list_keys(s: AsyncSession, include_revoked: bool = False) -> Sequence[ApiKey]:
    return await key_repo.list_api_keys(s, include_revoked=include_revoked)


async def key_page(
    s: AsyncSession, include_revoked: bool, after: Key | None, limit: int
) -> Page[ApiKey]:
    """Keys newest first (live ones only unless ``include_revoked``)."""
    return await key_repo.api_key_page(s, include_revoked, after, limit)


async def _live_key(s: AsyncSession, key_id: str) -> ApiKey:
    row = await key_repo.get_api_key(s, key_id)
    if row is None or row.revoked_at is not None:
        raise NotFound(f"no live key {key_id}", field="key_id")
    return row


async def revoke_key(s: AsyncSession, key_id: str) -> ApiKey:
    """Revoke a key: it stops working at once (its row stays, for the record)."""
    row = await _live_key(s, key_id)
    await key_repo.revoke_api_key(s, row)
    return row


async def rotate_key(s: AsyncSession, key_id: str) -> tuple[ApiKey, str]:
    """Give a key a new secret (same id, scopes and site); the old secret stops working."""
    row = await _live_key(s, key_id)
    key = new_secret(KEY_PREFIX)
    await key_repo.rotate_api_key(s, row, digest(key))
    return row, key
