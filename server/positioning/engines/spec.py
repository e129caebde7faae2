"""What every fusion engine looks like.

An engine is a pure function ``run(state, events, maps, params, rng) -> (state, fixes)``
plus a function making a new session's state from the parameters. Parameters are frozen
dataclasses checked on creation (``server.positioning.model.params``); states are frozen
dataclasses that ``server.positioning.model.state_codec`` turns into named numpy arrays and
back, so the storage layer can write them as typed raw bytes (never pickle, never JSON).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import numpy as np

from server.positioning.model import state_codec
from server.positioning.model.accuracy import EngineParams, calibrated
from server.positioning.model.events import Event, Fix
from server.positioning.model.params import Params, build
from server.positioning.model.site_maps import SiteMaps

S = TypeVar("S")
P = TypeVar("P", bound=EngineParams)

Arrays = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class EngineSpec(Generic[S, P]):
    """The registry entry of one engine: a pure ``run`` over a state of ``state_type``
    with parameters of ``params_type``.

    The typed fields are what an engine module declares and mypy checks it against; the
    methods below are the same engine seen from outside (a session, the harness), where
    a state is an opaque object: they check at run time that what they are handed is the
    engine's own.
    """

    name: str
    params_type: type[P]
    state_type: type[S]
    initial_state: Callable[[P], S]
    run: Callable[[S, Sequence[Event], SiteMaps, P, np.random.Generator], tuple[S, list[Fix]]]
    # event kinds the engine reads; others are accepted but ignored by it
    uses: frozenset[str]

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
