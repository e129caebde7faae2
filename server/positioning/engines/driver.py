"""One way for an engine to walk a batch: its items in time order, each to its handler.

An engine names a handler per item type (``on(StepEvent, handle_step)``); ``walk`` sends
each item to the first route that takes it, threads the state through, and collects the
fixes the handlers return. Items of no route are skipped (an engine ignores the event
kinds it does not use).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from server.positioning.model.events import Fix

S = TypeVar("S")
E = TypeVar("E")


class Timed(Protocol):
    @property
    def t_ms(self) -> int: ...


T = TypeVar("T", bound=Timed)


@dataclass(frozen=True)
class Route(Generic[S]):
    kind: type
    handle: Callable[[S, object], tuple[S, Fix | None]]


def on(kind: type[E], handler: Callable[[S, E], tuple[S, Fix | None]]) -> Route[S]:
    """A route sending items of type ``kind`` to ``handler(state, item)``."""

    def handle(state: S, item: object) -> tuple[S, Fix | None]:
        assert isinstance(item, kind)
        return handler(state, item)

    return Route(kind, handle)


def in_time_order(items: Iterable[T], rank: Callable[[T], int] | None = None) -> list[T]:
    """The items sorted by ``t_ms``, stably; at equal times by ``rank`` (lower first)."""
    if rank is None:
        return sorted(items, key=lambda item: item.t_ms)
    return sorted(items, key=lambda item: (item.t_ms, rank(item)))


def walk(state: S, items: Iterable[object], routes: Sequence[Route[S]]) -> tuple[S, list[Fix]]:
    """Every item, in the order given, through the route of its type."""
    fixes: list[Fix] = []
    for item in items:
        for route in routes:
            if isinstance(item, route.kind):
                state, fix = route.handle(state, item)
                if fix is not None:
                    fixes.append(fix)
                break
    return state, fixes
