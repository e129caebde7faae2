"""A session's record in the session store: its immutable meta, its state snapshot, the
log of the batches applied since, and the digest and wire form of the batch replies it
keeps.

All are named-array containers (``storage.codec``). The snapshot holds the engine state
under ``engine/`` (``state_codec``, layout ``state_codec.LAYOUT``), the last applied
``seq``, the replies of the last few batches and the last fix. An engine state written
under another layout is not decoded: :class:`StaleEngineState` says so, and the session
goes on from a fresh engine state (``services.batches``). A log entry
(:class:`LogEntry`) holds one applied batch: its ``seq``, digest and events
(``storage.event_codec``) and the answer it got. The state after it is the state before
it :meth:`SessionState.applied` with it: the bookkeeping at once, the engine's step left
``pending`` for whoever steps the engine next, with the session's maps and random stream
(the engines are deterministic given both, so the state comes out as it was).

A session's SQL row says when it was last active (``SessionRecord.last_active_at``, lagging
the last batch by up to half an idle timeout); :func:`active_since` is how far back that
may be for the session to be live still.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import numpy as np
import orjson

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.engines.shared.spec import Engine
from server.positioning.model import state_codec
from server.positioning.model.events import Event, Fix, ImuEvent
from server.positioning.model.geo import heading_from_north_deg, to_world
from server.positioning.model.state_codec import StateError
from server.positioning.plan.zone_presence import (
    NOTHING,
    AfterFix,
    FixPlace,
    Presence,
    ZoneEvent,
)
from server.storage.codec import (
    CodecError,
    array_to_str,
    decode_arrays,
    encode_arrays,
    str_to_array,
)
from server.storage.event_codec import event_arrays, events_from_arrays
from server.storage.models import utcnow

ENGINE_PREFIX = "engine/"
EVENTS_PREFIX = "events/"
# a row's last_active_at lags the last batch by up to half an idle timeout: a session is
# live (and rebuilt, should the store lose it) only if that is at most 1.5 idle timeouts
# ago (never taking a live one for gone)
REBUILD_IDLE_FACTOR = 1.5


def active_since(idle_s: float) -> datetime:
    """The oldest ``last_active_at`` of a session row that may still be live."""
    return utcnow() - timedelta(seconds=REBUILD_IDLE_FACTOR * idle_s)


class StaleEngineState(ValueError):
    """An engine state of another layout than this server writes."""


@dataclass(frozen=True)
class SessionMeta:
    site_id: str
    engine: str
    token_digest: str
    entropy: int
    contribute: bool = False  # the device offered the walk for map building
    device_model: str = ""
    params: bytes = b"{}"  # engine parameter overrides, JSON (services.engine_settings)

    def to_bytes(self) -> bytes:
        return encode_arrays(
            {
                "site_id": str_to_array(self.site_id),
                "engine": str_to_array(self.engine),
                "token_digest": str_to_array(self.token_digest),
                "entropy": np.frombuffer(self.entropy.to_bytes(16, "little"), dtype=np.uint8),
                "contribute": np.array([self.contribute], dtype=np.bool_),
                "device_model": str_to_array(self.device_model),
                "params": np.frombuffer(self.params, dtype=np.uint8),
            }
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> SessionMeta:
        a = decode_arrays(data)
        return cls(
            site_id=array_to_str(a["site_id"]),
            engine=array_to_str(a["engine"]),
            token_digest=array_to_str(a["token_digest"]),
            entropy=int.from_bytes(a["entropy"].tobytes(), "little"),
            # sessions created before these fields existed
            contribute=bool(a["contribute"][0]) if "contribute" in a else False,
            device_model=array_to_str(a["device_model"]) if "device_model" in a else "",
            params=a["params"].tobytes() if "params" in a else b"{}",
        )


@dataclass(frozen=True)
class Reply:
    seq: int
    digest: bytes
    body: bytes  # JSON list of fixes as sent on the wire


@dataclass(frozen=True)
class LogEntry:
    """One applied batch, as the session's log keeps it."""

    seq: int
    digest: bytes
    events: tuple[Event, ...]
    body: bytes  # the answer's fixes, as the reply keeps them
    last_fix: bytes  # the newest fix of the batch, b"" for none
    touched_ms: int  # the session's touched_ms after the batch
    zones: bytes = b""  # the session's zone presence after the batch (presence_to_bytes)
    navigation: bytes = b""  # the session's navigation after the batch (navigation_state)

    def to_bytes(self) -> bytes:
        arrays: dict[str, np.ndarray] = {
            "seq": np.array(self.seq, dtype=np.int64),
            "digest": np.frombuffer(self.digest, dtype=np.uint8),
            "body": np.frombuffer(self.body, dtype=np.uint8),
            "last_fix": np.frombuffer(self.last_fix, dtype=np.uint8),
            "touched_ms": np.array(self.touched_ms, dtype=np.int64),
            "zones": np.frombuffer(self.zones, dtype=np.uint8),
            "navigation": np.frombuffer(self.navigation, dtype=np.uint8),
        }
        for name, value in event_arrays(self.events).items():
            arrays[EVENTS_PREFIX + name] = value
        return encode_arrays(arrays)

    @classmethod
    def from_bytes(cls, data: bytes) -> LogEntry:
        """Raises ``CodecError`` for bytes that are not an entry."""
        a = decode_arrays(data)
        try:
            events = events_from_arrays(
                {k[len(EVENTS_PREFIX) :]: v for k, v in a.items() if k.startswith(EVENTS_PREFIX)}
            )
            return cls(
                seq=int(a["seq"]),
                digest=a["digest"].tobytes(),
                events=tuple(events),
                body=a["body"].tobytes(),
                last_fix=a["last_fix"].tobytes(),
                touched_ms=int(a["touched_ms"]),
                zones=a["zones"].tobytes() if "zones" in a else b"",
                navigation=a["navigation"].tobytes() if "navigation" in a else b"",
            )
        except (KeyError, TypeError, ValueError) as e:
            raise CodecError(f"not a log entry: {e!r}") from None


def event_end_ms(event: Event) -> int:
    """The time of an event's last reading (a block of samples runs past its ``t``)."""
    return event.t_end_ms if isinstance(event, ImuEvent) else event.t_ms


@dataclass(frozen=True)
class SessionState:
    last_seq: int  # -1: rebuilt after the store lost it; the next seq is taken as it comes
    engine_state: object
    replies: tuple[Reply, ...]
    last_fix: bytes  # JSON of the newest fix, b"" before the first
    rebuilt_seq: int = 0  # the first seq applied after a rebuild (0: never rebuilt)
    touched_ms: int = 0  # wall clock of the last refresh of the SQL row's last_active_at
    last_event_ms: int = 0  # the newest event time of the batches applied (0: none yet)
    # batches applied after ``engine_state``: their engine steps are still to be taken
    pending: tuple[LogEntry, ...] = ()
    zones: bytes = b""  # the session's zone presence (presence_to_bytes)
    navigation: bytes = b""  # where the session is navigating to (navigation_state)

    def applied(
        self, entry: LogEntry, replay_window: int, engine_state: object | None = None
    ) -> SessionState:
        """The state after the batch ``entry`` records: with the engine's state after it,
        or, without ``engine_state``, the engine's step left pending."""
        if engine_state is not None and self.pending:
            raise ValueError("the pending engine steps come first")
        return SessionState(
            last_seq=entry.seq,
            engine_state=self.engine_state if engine_state is None else engine_state,
            replies=(*self.replies, Reply(entry.seq, entry.digest, entry.body))[-replay_window:],
            last_fix=entry.last_fix or self.last_fix,
            rebuilt_seq=entry.seq if self.last_seq < 0 else self.rebuilt_seq,
            touched_ms=entry.touched_ms,
            last_event_ms=max([self.last_event_ms, *map(event_end_ms, entry.events)]),
            pending=(*self.pending, entry) if engine_state is None else (),
            zones=entry.zones,
            navigation=navigation_after(self.navigation, entry.navigation),
        )

    def to_bytes(self, engine: Engine) -> bytes:
        if self.pending:
            raise ValueError("a snapshot holds no pending engine steps")
        arrays: dict[str, np.ndarray] = {
            "engine_layout": np.array(state_codec.LAYOUT, dtype=np.int64),
            "last_seq": np.array(self.last_seq, dtype=np.int64),
            "rebuilt_seq": np.array(self.rebuilt_seq, dtype=np.int64),
            "touched_ms": np.array(self.touched_ms, dtype=np.int64),
            "last_event_ms": np.array(self.last_event_ms, dtype=np.int64),
            "last_fix": np.frombuffer(self.last_fix, dtype=np.uint8),
            "zones": np.frombuffer(self.zones, dtype=np.uint8),
            "navigation": np.frombuffer(self.navigation, dtype=np.uint8),
            "replies/seq": np.array([r.seq for r in self.replies], dtype=np.int64),
            "replies/digest": np.frombuffer(
                b"".join(r.digest for r in self.replies), dtype=np.uint8
            ),
            "replies/offsets": np.cumsum([0] + [len(r.body) for r in self.replies]).astype(
                np.int64
            ),
            "replies/body": np.frombuffer(b"".join(r.body for r in self.replies), dtype=np.uint8),
        }
        for name, value in engine.encode(self.engine_state).items():
            arrays[ENGINE_PREFIX + name] = value
        return encode_arrays(arrays)

    @classmethod
    def from_bytes(cls, data: bytes, engine: Engine) -> SessionState:
        """Raises :class:`StaleEngineState` for an engine state of another layout or one
        the engine's state class refuses (``state_codec.StateError``)."""
        a = decode_arrays(data)
        offsets = a["replies/offsets"].tolist()
        body = a["replies/body"].tobytes()
        digests = a["replies/digest"].tobytes()
        replies = tuple(
            Reply(
                seq=int(seq),
                digest=digests[32 * i : 32 * (i + 1)],
                body=body[offsets[i] : offsets[i + 1]],
            )
            for i, seq in enumerate(a["replies/seq"].tolist())
        )
        engine_arrays = {
            k[len(ENGINE_PREFIX) :]: v for k, v in a.items() if k.startswith(ENGINE_PREFIX)
        }
        layout = int(a["engine_layout"]) if "engine_layout" in a else 1
        if layout != state_codec.LAYOUT:
            raise StaleEngineState(f"engine state of layout {layout}, not {state_codec.LAYOUT}")
        try:
            engine_state = engine.decode(engine_arrays)
        except StateError as e:
            raise StaleEngineState(str(e)) from None
        return cls(
            last_seq=int(a["last_seq"]),
            engine_state=engine_state,
            replies=replies,
            last_fix=a["last_fix"].tobytes(),
            rebuilt_seq=int(a["rebuilt_seq"]) if "rebuilt_seq" in a else 0,
            touched_ms=int(a["touched_ms"]) if "touched_ms" in a else 0,
            last_event_ms=int(a["last_event_ms"]) if "last_event_ms" in a else 0,
            zones=a["zones"].tobytes() if "zones" in a else b"",
            navigation=a["navigation"].tobytes() if "navigation" in a else b"",
        )


def events_digest(events: Sequence[Event]) -> bytes:
    """A fingerprint of a batch's content, to tell a true retry from a reused ``seq``.

    Sample arrays go in as raw bytes: their ``repr`` elides the middle of long arrays
    and is slow. A batch without raw samples keeps the digest it always had, so a retry
    across an upgrade still finds its stored reply.
    """
    if not any(isinstance(e, ImuEvent) for e in events):
        return hashlib.sha256(repr(tuple(events)).encode()).digest()
    h = hashlib.sha256()
    for event in events:
        if isinstance(event, ImuEvent):
            h.update(repr(("imu", event.t_ms, event.magnetic_calibrated)).encode())
            for samples in event.sensors().values():
                h.update(repr(samples.shape).encode())
                h.update(np.ascontiguousarray(samples, dtype=np.float64).tobytes())
        else:
            h.update(repr(event).encode())
    return h.digest()


_PROGRESS = b',"progress":'
_SAME_COURSE = b'{"layout":1,"course":null'  # layout 1 of navigation_state


def navigation_delta(previous: bytes, current: bytes) -> bytes:
    """What a log entry keeps of the session's navigation after its batch: the whole of
    it (``navigation_state``) when its course changed, else only its progress (the
    course is the one before). Byte work on the encoding (``{"layout", "course",
    "progress"}``; a course is a JSON string, in which ``,"progress":`` cannot occur
    unescaped): a navigating batch writes a few hundred bytes, not its route."""
    if not previous or not current:
        return current
    cut, was = current.find(_PROGRESS), previous.find(_PROGRESS)
    if cut < 0 or was < 0 or current[:cut] != previous[:was]:
        return current
    return _SAME_COURSE + current[cut:]


def navigation_after(previous: bytes, entry: bytes) -> bytes:
    """The session's navigation after a log entry's (``navigation_delta``)."""
    if not entry.startswith(_SAME_COURSE + _PROGRESS):
        return entry
    was = previous.find(_PROGRESS)
    if was < 0:  # no course to go on with: the navigation ends
        return b""
    return previous[:was] + entry[len(_SAME_COURSE) :]


def presence_to_bytes(presence: Mapping[str, Presence]) -> bytes:
    """A session's zone presence as its state keeps it (b"" for none)."""
    if not presence:
        return b""
    return orjson.dumps(
        {key: [p.inside, p.since_ms, p.pending_ms, p.pending_n] for key, p in presence.items()}
    )


def presence_from_bytes(data: bytes) -> dict[str, Presence]:
    if not data:
        return {}
    return {
        key: Presence(bool(inside), int(since), int(pending), int(n))
        for key, (inside, since, pending, n) in orjson.loads(data).items()
    }


def fix_places(fixes: Sequence[Fix]) -> list[FixPlace]:
    return [FixPlace(f.t_ms, f.floor, f.x_m, f.y_m) for f in fixes]


def zone_event_to_wire(event: ZoneEvent, maps: SiteMaps, reason: str = "crossed") -> dict[str, Any]:
    """A zone event as fixes, the socket and webhooks carry it; ``reason``: ``crossed``
    (its fixes crossed the border) or ``session_ended`` (the session ended inside)."""
    zone = event.zone
    return {
        "type": event.kind,
        "zone_id": zone.id,
        "zone_name": zone.name,
        "floor_id": zone.floor_id,
        "level": maps.floors[zone.floor].level,
        "t": event.t_ms,
        "since": event.since_ms,
        "dwell_s": event.dwell_s,
        "reason": reason,
    }


def exits_at_end(state: SessionState, maps: SiteMaps, t_ms: int) -> list[dict[str, Any]]:
    """The exits of a session that ends at ``t_ms`` inside zones (wire form), so that
    whoever counts who is in a zone sees it leave."""
    exits = []
    for key, presence in presence_from_bytes(state.zones).items():
        zone = maps.zones.by_key.get(key)
        if zone is not None and presence.inside:
            dwell_s = max(0.0, (t_ms - presence.since_ms) / 1000.0)
            event = ZoneEvent("exit", zone, t_ms, t_ms, dwell_s)
            exits.append(zone_event_to_wire(event, maps, "session_ended"))
    return exits


def fix_to_wire(fix: Fix, maps: SiteMaps, engine: str, zones: AfterFix = NOTHING) -> dict[str, Any]:
    """A fix as the wire carries it (``FixOut``), with the zones the session is in after it
    and the zone events it confirmed (``zone_presence``)."""
    ref = maps.floors[fix.floor] if 0 <= fix.floor < len(maps.floors) else None
    return {
        "t": fix.t_ms,
        "x_m": fix.x_m,
        "y_m": fix.y_m,
        "floor": ref.level if ref else None,
        "building_id": ref.building_id if ref else None,
        "floor_id": ref.floor_id if ref else None,
        "heading_rad": fix.heading_rad,
        "cov_m2": list(fix.cov),
        "uncertainty_m": fix.uncertainty_m,
        "accuracy_68_m": _finite(fix.accuracy_68_m),
        "accuracy_95_m": _finite(fix.accuracy_95_m),
        "floor_prob": _finite(fix.floor_prob),
        "source": fix.source,
        "engine": engine,
        "diagnostics": fix.diagnostics,
        **world_fields(fix.x_m, fix.y_m, fix.heading_rad, fix.accuracy_68_m, ref),
        "zones": [z.id for z in zones.inside],
        "zone_events": [zone_event_to_wire(e, maps) for e in zones.events],
        "navigation": None,  # set by the batch while the session navigates
    }


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def world_fields(
    x_m: float, y_m: float, heading_rad: float | None, accuracy_68_m: float, ref: FloorRef | None
) -> dict[str, Any]:
    """A fix as a phone app or a web map reads one: WGS84 ``lat``/``lon`` (degrees; null
    where the building has no geo-reference), the floor's ``level``, ``accuracy_m`` (the
    68 % radius, as Android's accuracy) and ``heading_deg`` clockwise from north, by the
    building's rotation (``model.geo``)."""
    geo = ref.geo if ref is not None else None
    lat, lon = to_world(x_m, y_m, geo) if geo is not None else (None, None)
    heading = (
        heading_from_north_deg(heading_rad, ref.rotation_rad)
        if ref is not None and heading_rad is not None and math.isfinite(heading_rad)
        else None
    )
    return {
        "lat": lat,
        "lon": lon,
        "level": ref.level if ref is not None else None,
        "accuracy_m": _finite(accuracy_68_m),
        "heading_deg": heading,
    }
