"""Decoded session records kept per process, by session and version.

A batch reads its session's record from the store, decodes it (about 0.3 ms for a
3,000-particle cloud, most of it per-array overhead), runs the engine and writes the new
state back. The process that wrote version ``v + 1`` still holds what it wrote, decoded;
when the next batch of that session comes to the same process, the store only confirms
the version (``SessionStore.get_changed``) and neither the state's bytes nor its decoding
are needed. Another process's write changes the version, so a stale entry is never used.

Entries are stored on every full read and every write of this process. They are
immutable: engines never change the state they are given, they return a new one (a state
an engine failed on is dropped all the same). The least recently used entries go first
once ``size`` are kept.

An entry this process wrote is, as long as the session's batches keep coming here, the
store's current version: a batch may start from it without asking the store at all
(``current``). Should another process have written since, the batch notices: its seq
does not follow the entry's last one (the device sends them in order), or, for two
copies of one batch applied at once, the compare-and-set refuses the stale version.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any, Generic, TypeVar

M = TypeVar("M")
S = TypeVar("S")


class SessionCache(Generic[M, S]):
    """``session_id -> (version, meta, state)``, at most ``size`` entries."""

    def __init__(self, size: int) -> None:
        if size < 0:
            raise ValueError("size must not be negative")
        self._size = size
        self._entries: OrderedDict[str, tuple[int, M, S]] = OrderedDict()
        self._written: set[str] = set()  # entries this process wrote

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, session_id: str) -> tuple[int, M, S] | None:
        entry = self._entries.get(session_id)
        if entry is not None:
            self._entries.move_to_end(session_id)
        return entry

    def current(self, session_id: str) -> tuple[int, M, S] | None:
        """The entry when this process wrote it: most likely the store's version still
        (module docstring)."""
        if session_id not in self._written:
            return None
        return self.get(session_id)

    def put(self, session_id: str, version: int, meta: M, state: S, written: bool = False) -> None:
        """Keep an entry: read from the store, or ``written`` by this process."""
        if self._size == 0:
            return
        self._entries[session_id] = (version, meta, state)
        self._entries.move_to_end(session_id)
        if written:
            self._written.add(session_id)
        else:
            self._written.discard(session_id)
        while len(self._entries) > self._size:
            gone, _ = self._entries.popitem(last=False)
            self._written.discard(gone)

    def drop(self, session_id: str) -> None:
        self._entries.pop(session_id, None)
        self._written.discard(session_id)


AnySessionCache = SessionCache[Any, Any]
