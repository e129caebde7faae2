"""Which zones a walker is in, from its fixes, without flapping on a border.

A fix's position (the centre of its 68 % circle) is either in a zone or not. The walker's
presence changes only when its fixes have said the contrary without a break for
:attr:`Dwell.seconds`, or, after two fixes or more, once a fix of the run lies
:attr:`Dwell.metres` beyond the border (inside it to enter, outside to leave): a fix
wobbling across a border, back before either is reached, changes nothing (the run starts
again), and neither does one fix that jumps far. Entering is confirmed at the fix that
completes its run; the event names when the run began (``since_ms``). Leaving likewise,
with how long the walker was in (``dwell_s``: from the start of the entering run to the
start of the leaving one). A fix on another floor is outside every zone of this one (and
only the time confirms it).

Presence is a plain mapping (zone key → :class:`Presence`) that the service keeps with the
session's state; zones that are gone from the site are dropped from it without an event.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

from server.positioning.plan.zones import Zone, ZoneIndex

DWELL_S = 3.0
DWELL_M = 3.0


@dataclass(frozen=True)
class Dwell:
    """How long, or how far, fixes must say the contrary before presence changes."""

    seconds: float = DWELL_S
    metres: float = DWELL_M


@dataclass(frozen=True)
class Presence:
    """A walker's standing with one zone: ``inside`` since ``since_ms`` (the start of the
    run that confirmed it); ``pending_ms`` (-1: none) the first fix of a contrary run,
    ``pending_n`` the fixes of that run so far."""

    inside: bool
    since_ms: int
    pending_ms: int = -1
    pending_n: int = 0


@dataclass(frozen=True)
class ZoneEvent:
    kind: Literal["enter", "exit"]
    zone: Zone
    t_ms: int  # the fix that confirmed it
    since_ms: int  # when its run began
    dwell_s: float | None = None  # exit: how long the walker was in


@dataclass(frozen=True)
class FixPlace:
    """Where one fix was: its time, floor index (-1: unknown) and floor metres."""

    t_ms: int
    floor: int
    x_m: float
    y_m: float


@dataclass(frozen=True)
class AfterFix:
    """The zones the walker is in after a fix (confirmed presence, ordered by key), and
    the events the fix confirmed."""

    inside: tuple[Zone, ...]
    events: tuple[ZoneEvent, ...]


NOTHING = AfterFix((), ())


def follow(
    presence: Mapping[str, Presence],
    fixes: Sequence[FixPlace],
    zones: ZoneIndex,
    dwell: Dwell = Dwell(),
) -> tuple[dict[str, Presence], list[AfterFix]]:
    """The presence after ``fixes`` and, per fix, what it says (module docstring)."""
    state = {k: p for k, p in presence.items() if k in zones.by_key}
    if not zones or not fixes:
        return state, [NOTHING] * len(fixes)
    out = []
    hits = zones.at_many([f.floor for f in fixes], [f.x_m for f in fixes], [f.y_m for f in fixes])
    for fix, hit in zip(fixes, hits, strict=True):
        here = {z.key for z in hit} if fix.floor >= 0 else set()
        events = []
        for key in sorted(here | state.keys()):
            was = state.get(key, Presence(False, fix.t_ms))
            now, event = _step(was, key in here, fix, dwell, zones.by_key[key])
            if now.inside or now.pending_ms >= 0:
                state[key] = now
            else:
                state.pop(key, None)
            if event is not None:
                events.append(event)
        inside = tuple(zones.by_key[k] for k in sorted(state) if state[k].inside)
        out.append(AfterFix(inside, tuple(events)))
    return state, out


def _step(
    was: Presence, raw: bool, fix: FixPlace, dwell: Dwell, zone: Zone
) -> tuple[Presence, ZoneEvent | None]:
    if raw == was.inside:
        return Presence(was.inside, was.since_ms), None  # a contrary run, if any, is over
    start = fix.t_ms if was.pending_ms < 0 else was.pending_ms
    run = Presence(was.inside, was.since_ms, start, was.pending_n + 1)
    held = (fix.t_ms - start) / 1000.0 >= dwell.seconds
    beyond = (
        run.pending_n >= 2
        and fix.floor == zone.floor
        and zone.border_distance_m(fix.x_m, fix.y_m) >= dwell.metres
    )
    if not (held or beyond):
        return run, None
    if raw:
        return Presence(True, start), ZoneEvent("enter", zone, fix.t_ms, start)
    dwell_s = max(0.0, (start - was.since_ms) / 1000.0)
    return Presence(False, start), ZoneEvent("exit", zone, fix.t_ms, start, dwell_s)
