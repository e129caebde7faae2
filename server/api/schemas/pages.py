"""Pages of a list: ``limit`` and ``cursor`` in, ``{items, count, next_cursor}`` out.

A cursor is opaque to clients: the list's name and the sort key of the last item of the
page it came with (``storage.repositories.pages``), as base64url JSON. A cursor of
another list, or one that does not decode, is refused (422 naming ``cursor``).
"""

from __future__ import annotations

import base64
import binascii
from collections.abc import Sequence
from datetime import datetime
from typing import Annotated, Any

import orjson
from pydantic import Field

DEFAULT_LIMIT = 100
MAX_LIMIT = 1000
MAX_CURSOR_CHARS = 512

NextCursor = Annotated[
    str | None,
    Field(description="pass as `cursor` for the next page; null on the last page"),
]
PageCount = Annotated[int, Field(description="items on this page")]

# the types of a list's sort key: (created_at, id) or (level, id)
CREATED: tuple[type, ...] = (datetime, str)
LEVEL: tuple[type, ...] = (int, str)


def encode_cursor(name: str, key: Sequence[Any]) -> str:
    values = [v.isoformat() if isinstance(v, datetime) else v for v in key]
    return base64.urlsafe_b64encode(orjson.dumps([name, *values])).rstrip(b"=").decode()


def decode_cursor(name: str, types: Sequence[type], cursor: str) -> tuple[Any, ...]:
    """The key a cursor of list ``name`` holds; ValueError saying why when it holds none."""
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        found = orjson.loads(raw)
    except (binascii.Error, ValueError):
        raise ValueError("not a cursor this service gave out") from None
    if not isinstance(found, list) or len(found) != len(types) + 1:
        raise ValueError("not a cursor this service gave out")
    if found[0] != name:
        raise ValueError(f"a cursor of another list ({found[0]!r}), not of {name!r}")
    key: list[Any] = []
    for kind, value in zip(types, found[1:], strict=True):
        if kind is datetime and isinstance(value, str):
            try:
                moment = datetime.fromisoformat(value)
            except ValueError:
                raise ValueError("not a cursor this service gave out") from None
            if moment.tzinfo is None:
                raise ValueError("not a cursor this service gave out")
            key.append(moment)
        elif type(value) is kind and kind in (int, str):
            key.append(value)
        else:
            raise ValueError("not a cursor this service gave out")
    return tuple(key)
