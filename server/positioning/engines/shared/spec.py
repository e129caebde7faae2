"""What every fusion engine shares: how it is declared (``EngineSpec``), its handlers and
the one driver that walks a batch through them.

An engine module declares its ``SPEC``::

    SPEC = EngineSpec(
        name="step_ekf",
        params_type=StepEkfParams,   # frozen dataclass, checked on creation (model.params)
        state_type=StepEkfState,     # frozen dataclass, stored by model.state_codec
        initial_state=initial_state, # params -> a new session's state
        uses=frozenset({"step", "wifi", "ble", "pressure"}),  # event kinds it reads
        handlers=(                   # one handler per item type, first match wins
            on(StepEvent, on_step),
            on(WifiEvent, on_scan),
            on(BleEvent, on_scan),
            on(FloorChange, scan_fixes.on_floor_change),
        ),
        prepass=with_floor_changes,  # optional: what the batch becomes first
    )

Every handler has one signature, ``handler(state, item, maps, params, rng) -> (state,
fix or None)``: it takes the state after the previous item and returns the next one,
and the fix the item gave, if any (handlers of deterministic engines ``del rng``).

A service calls ``Engine.step`` (``EngineSpec.step``), which checks the state and
parameters are the engine's own and calibrates the fixes (``accuracy.calibrated``);
``EngineSpec.run`` is the driver:

1. ``prepass(state, events, maps, params) -> (state, items)`` takes a look at the whole
   batch first: ``with_floor_changes`` advances the barometer over the batch's pressure
   rows and adds the floor changes it settles on to the events; ``with_found_steps``
   also turns raw IMU blocks into steps (``step_tracker``); the default,
   ``events_as_given``, hands the events on as they are;
2. the items are put in time order, stably (``in_time_order``), at equal times by the
   engine's ``rank`` if it has one;
3. ``walk`` sends each item to the handler of the first route whose type it is, threads
   the state through and collects the fixes. Items of no route are skipped (an engine
   ignores the event kinds it does not use).

An engine that runs other engines (``auto``) has no handlers: its ``delegate`` is the
whole batch, and its fixes are calibrated by the engines that made them.

Parameters are frozen dataclasses checked on creation (``server.positioning.model.params``);
states are frozen dataclasses that ``server.positioning.model.state_codec`` turns into
named numpy arrays and back, so the storage layer can write them as typed raw bytes (never
pickle, never JSON).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Generic, Protocol, Self, TypeVar

import numpy as np

from server.positioning.engines.shared.scan_fixes import BarometerParams, floor_changes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model import state_codec
from server.positioning.model.accuracy import EngineParams, calibrated
from server.positioning.model.events import BleEvent, Event, Fix, MagEvent, WifiEvent
from server.positioning.model.params import Params, build
from server.positioning.motion.barometer import BaroState
from server.positioning.motion.step_tracker import TrackerParams, TrackerState, timeline

S = TypeVar("S")
P = TypeVar("P", bound=EngineParams)
E = TypeVar("E")
# a route's handler that takes any parameters takes those of every engine
P_contra = TypeVar("P_contra", bound=EngineParams, contravariant=True)

Arrays = Mapping[str, np.ndarray]

# what a handler gets: the state, one item of the batch, the site's maps, the engine's
# parameters and the batch's random numbers; what it gives: the state and the item's fix
Handler = Callable[[S, E, SiteMaps, P, np.random.Generator], tuple[S, Fix | None]]
# what a batch becomes before the handlers see it: the state after a pass over the whole
# batch, and the items to walk (any order: the driver sorts them)
Prepass = Callable[[S, Sequence[Event], SiteMaps, P], tuple[S, list[Any]]]
# a whole batch: the state after it and its fixes
Run = Callable[[S, Sequence[Event], SiteMaps, P, np.random.Generator], tuple[S, list[Fix]]]


@dataclass(frozen=True)
class Route(Generic[S, P_contra]):
    """Items of type ``kind`` go to ``handler`` (build it with ``on``, which checks the
    handler takes that type)."""

    kind: type
    handler: Handler[S, Any, P_contra]


def on(kind: type[E], handler: Handler[S, E, P]) -> Route[S, P]:
    """A route sending the items of type ``kind`` to ``handler``."""
    return Route(kind, handler)


def on_scans(handler: Handler[S, WifiEvent | BleEvent, P]) -> tuple[Route[S, P], Route[S, P]]:
    """Routes sending WiFi and BLE scans alike to ``handler``."""
    return on(WifiEvent, handler), on(BleEvent, handler)


class KeepsField(Protocol):
    """An engine state that keeps the magnetometer's field strength for its steps."""

    def with_field(self, t_ms: int, strength_ut: float) -> Self:
        """The state after a reading at ``t_ms`` of strength ``strength_ut`` (NaN: the
        reading has none)."""
        ...


M = TypeVar("M", bound=KeepsField)


def on_mag(
    state: M, event: MagEvent, maps: SiteMaps, params: EngineParams, rng: np.random.Generator
) -> tuple[M, Fix | None]:
    """The handler of a magnetometer reading for a state that keeps its field strength
    (``KeepsField.with_field``); it makes no fix."""
    del maps, params, rng  # the reading alone
    return state.with_field(event.t_ms, event.strength_ut), None


def events_as_given(
    state: S, events: Sequence[Event], maps: SiteMaps, params: EngineParams
) -> tuple[S, list[Any]]:
    """The default pre-pass: the batch's events, the state unchanged."""
    del maps, params
    return state, list(events)


@dataclass(frozen=True)
class EngineSpec(Generic[S, P]):
    """The registry entry of one engine: its handlers over a state of ``state_type``,
    with parameters of ``params_type``, driven by ``run`` (module docstring).

    The typed fields are what an engine module declares and mypy checks it against; the
    methods ``params`` to ``decode`` are the same engine seen from outside (a session,
    the harness), where a state is an opaque object: they check at run time that what
    they are handed is the engine's own.
    """

    name: str
    params_type: type[P]
    state_type: type[S]
    initial_state: Callable[[P], S]
    # event kinds the engine reads; others are accepted but ignored by it
    uses: frozenset[str]
    handlers: tuple[Route[S, P], ...]
    prepass: Prepass[S, P] = events_as_given
    # order of the items at equal times, lower first (None: as the pre-pass gave them)
    rank: Callable[[Any], int] | None = None
    # an engine that runs other engines: the whole batch, its fixes calibrated by the
    # engines that made them (then there are no handlers)
    delegate: Run[S, P] | None = None

    def __post_init__(self) -> None:
        if bool(self.handlers) == (self.delegate is not None):
            raise ValueError(f"{self.name}: give handlers or a delegate, not both or neither")

    def run(
        self, state: S, events: Sequence[Event], maps: SiteMaps, params: P, rng: np.random.Generator
    ) -> tuple[S, list[Fix]]:
        """A batch of events: the pre-pass, then its items in time order through the
        handlers (``walk``), or the ``delegate``; the fixes as the engine made them
        (``step`` calibrates them)."""
        if self.delegate is not None:
            return self.delegate(state, events, maps, params, rng)
        state, items = self.prepass(state, events, maps, params)
        return self.walk(state, in_time_order(items, self.rank), maps, params, rng)

    def walk(
        self, state: S, items: Iterable[object], maps: SiteMaps, params: P, rng: np.random.Generator
    ) -> tuple[S, list[Fix]]:
        """Every item, in the order given, through the handler of its type."""
        fixes: list[Fix] = []
        for item in items:
            for route in self.handlers:
                if isinstance(item, route.kind):
                    state, fix = route.handler(state, item, maps, params, rng)
                    if fix is not None:
                        fixes.append(fix)
                    break
        return state, fixes

    def params(self, overrides: Mapping[str, object] | None = None) -> P:
        """The engine's defaults with (nested) ``overrides``; ``params.ParamError`` names
        the dotted field of any bad one."""
        defaults = self.params_type()
        return build(defaults, overrides) if overrides else defaults

    def start(self, params: Params) -> object:
        """A new session's state."""
        return self.initial_state(self._own_params(params))

    def step(
        self,
        state: object,
        events: Sequence[Event],
        maps: SiteMaps,
        params: Params,
        rng: np.random.Generator,
    ) -> tuple[object, list[Fix]]:
        """``run`` for a state and parameters held as opaque objects, its fixes with the
        radii that hold 68 % and 95 % of the errors (``accuracy.calibrated``)."""
        if not isinstance(state, self.state_type):
            raise TypeError(f"{self.name} runs on {self.state_type.__name__} states")
        own = self._own_params(params)
        new, fixes = self.run(state, events, maps, own, rng)
        if self.delegate is not None:  # calibrated by the engines that made them
            return new, fixes
        return new, [calibrated(f, own.accuracy, maps.fix_error.error_68_m) for f in fixes]

    def encode(self, state: object) -> dict[str, np.ndarray]:
        """The state as named arrays (``state_codec``)."""
        if not isinstance(state, self.state_type):
            raise TypeError(f"{self.name} encodes {self.state_type.__name__} states")
        return state_codec.to_arrays(state)

    def decode(self, arrays: Arrays) -> object:
        """The state ``encode`` gave ``arrays`` for; ``state_codec.StateError`` if not one."""
        return state_codec.from_arrays(self.state_type, arrays)

    def _own_params(self, params: Params) -> P:
        if not isinstance(params, self.params_type):
            raise TypeError(f"{self.name} takes {self.params_type.__name__}")
        return params


class Engine(Protocol):
    """An engine as the registry hands it out: ``EngineSpec`` of any state and params."""

    @property
    def name(self) -> str: ...
    @property
    def uses(self) -> frozenset[str]: ...
    @property
    def params_type(self) -> type[EngineParams]: ...
    def params(self, overrides: Mapping[str, object] | None = None) -> EngineParams: ...
    def start(self, params: Params) -> object: ...
    def step(
        self,
        state: object,
        events: Sequence[Event],
        maps: SiteMaps,
        params: Params,
        rng: np.random.Generator,
    ) -> tuple[object, list[Fix]]: ...
    def encode(self, state: object) -> dict[str, np.ndarray]: ...
    def decode(self, arrays: Arrays) -> object: ...


# ---------------------------------------------------------------- ordering and pre-passes


class Timed(Protocol):
    @property
    def t_ms(self) -> int: ...


T = TypeVar("T", bound=Timed)


def in_time_order(items: Iterable[T], rank: Callable[[T], int] | None = None) -> list[T]:
    """The items sorted by ``t_ms``, stably; at equal times by ``rank`` (lower first)."""
    if rank is None:
        return sorted(items, key=lambda item: item.t_ms)
    return sorted(items, key=lambda item: (item.t_ms, rank(item)))


class Barometric(Protocol):
    """An engine state with a barometer."""

    @property
    def baro(self) -> BaroState: ...


B = TypeVar("B", bound=Barometric)


def with_floor_changes(
    state: B, events: Sequence[Event], maps: SiteMaps, params: BarometerParams
) -> tuple[B, list[Any]]:
    """The pre-pass of an engine with a barometer: the barometer advanced over the
    batch's pressure rows, and the events with the floor changes it settled on
    (``scan_fixes.floor_changes``)."""
    baro, changes = floor_changes(state.baro, events, maps, params)
    new: B = replace(state, baro=baro)  # type: ignore[type-var]
    return new, [*events, *changes]


class Tracking(Barometric, Protocol):
    """An engine state with a barometer and a step tracker."""

    @property
    def tracker(self) -> TrackerState: ...


class FindsSteps(BarometerParams, Protocol):
    """The parameters of an engine that finds its own steps: the barometer's and the
    step tracker's."""

    @property
    def tracker(self) -> TrackerParams: ...


K = TypeVar("K", bound=Tracking)


def with_found_steps(
    state: K, events: Sequence[Event], maps: SiteMaps, params: FindsSteps
) -> tuple[K, list[Any]]:
    """The pre-pass of an engine that finds its own steps: raw IMU blocks become steps
    (``step_tracker.timeline``: steps and scans in the tracker's order; step events the
    phone sent are not among them), and the floor changes the barometer settles on join
    them (as in ``with_floor_changes``)."""
    tracker, items = timeline(state.tracker, events, params.tracker)
    baro, changes = floor_changes(state.baro, events, maps, params)
    new: K = replace(state, tracker=tracker, baro=baro)  # type: ignore[type-var]
    return new, [*items, *changes]
