"""``auto``: the engine a new session gets when it names none; it picks, per session, the
engine the recorded figures say is best for what the phone sends, and runs it.

Rules (``choose``), from the test-split tables of ``bench/accuracy.md`` (ILC site2, 482
points; IPIN 2023 logs, 296 points; mean / P75):

* the phone sends steps (a step detector of its own) -> ``step_ekf``: the best engine on
  ILC (12.5 / 14.6 m against 12.8-14.4 / 15.4-18.0 m), and within 0.4 % (mean) and 2.5 %
  (P75) of the best one on IPIN (18.2 / 20.6 m against 18.2 / 20.1 m);
* raw motion samples only -> ``everywhere_ekf``: the best of the
  engines that find their own steps (ILC 12.8 / 15.4 m, IPIN 18.2 / 20.7 m, against
  ``two_stage_ekf`` 13.5 / 16.0 and 18.6 / 21.6 m);
* scans only -> ``wknn``: without motion the filters have nothing to add.

The floor's maps choose nothing yet: every candidate needs a radio map, and no measured
floor favours ``pf_magnetic``, ``map_markov`` or ``fai_ekf`` (magnetic map, plan graph,
accuracy indicators) over ``step_ekf`` on both venues, so no rule picks them (on the
IPIN floors, which have no plan, ``map_markov`` led the test split by 3 % and tied on
the validation split: one venue is not a rule).

A session starts undecided; the first batch that carries steps, raw samples or scans
decides. A ``wknn`` session whose phone starts sending steps or samples moves up to the
filter (starting it afresh: ``wknn`` carries no memory worth keeping); a filter is never
swapped for another, and a floor change is left to the chosen engine. The chosen
engine's own parameters are nested in ``AutoParams`` (``step_ekf``, ``everywhere_ekf``,
``wknn``), so a site's settings reach it; each fix is calibrated by the engine that made
it (``AutoParams.accuracy`` is not read). Fixes carry ``diagnostics["auto_engine"]``: the
index of the engine in ``CANDIDATES``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from server.positioning.engines import everywhere_ekf, step_ekf, wknn
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec
from server.positioning.model.accuracy import EngineParams
from server.positioning.model.events import BleEvent, Event, Fix, ImuEvent, StepEvent, WifiEvent
from server.positioning.model.params import Params
from server.positioning.model.state_codec import StateError

CANDIDATES: tuple[EngineSpec, ...] = (wknn.SPEC, step_ekf.SPEC, everywhere_ekf.SPEC)  # type: ignore[type-arg]
WKNN, STEPS, SAMPLES = 0, 1, 2
UNDECIDED = -1


@dataclass(frozen=True)
class AutoParams(EngineParams):
    """The parameters of each engine ``auto`` may run (their own defaults)."""

    wknn: wknn.WknnParams = field(default_factory=wknn.WknnParams)
    step_ekf: step_ekf.StepEkfParams = field(default_factory=step_ekf.StepEkfParams)
    everywhere_ekf: everywhere_ekf.EverywhereParams = field(
        default_factory=everywhere_ekf.EverywhereParams
    )

    def of(self, choice: int) -> Params:
        return getattr(self, CANDIDATES[choice].name)  # type: ignore[no-any-return]


@dataclass(frozen=True)
class AutoState:
    """The chosen engine (index into ``CANDIDATES``, ``UNDECIDED`` before) and its state,
    in the field named after it (the others None)."""

    choice: int = UNDECIDED
    wknn: wknn.WknnState | None = None
    step_ekf: step_ekf.StepEkfState | None = None
    everywhere_ekf: everywhere_ekf.EverywhereState | None = None

    @property
    def inner(self) -> object | None:
        return getattr(self, CANDIDATES[self.choice].name) if self.choice >= 0 else None

    def check_decoded(self) -> None:
        if not UNDECIDED <= self.choice < len(CANDIDATES):
            raise StateError(f"choice: {self.choice} is not an engine")
        held = [c.name for c in CANDIDATES if getattr(self, c.name) is not None]
        mine = [CANDIDATES[self.choice].name] if self.choice >= 0 else []
        if held != mine:
            raise StateError(f"choice: {self.choice} with the states of {held}")


def choose(events: Sequence[Event], current: int) -> int:
    """The engine for a session that has run ``current`` and now gets ``events``
    (module docstring)."""
    if current in (STEPS, SAMPLES):
        return current
    if any(isinstance(e, StepEvent) for e in events):
        return STEPS
    if any(isinstance(e, ImuEvent) and e.has_motion for e in events):
        return SAMPLES  # motion samples: blocks of pressure alone come with phone steps
    if current == WKNN or any(isinstance(e, WifiEvent | BleEvent) for e in events):
        return WKNN
    return UNDECIDED


def initial_state(params: AutoParams) -> AutoState:
    """An undecided session."""
    del params  # the chosen engine starts from its own, when chosen
    return AutoState()


def run(
    state: AutoState,
    events: Sequence[Event],
    maps: SiteMaps,
    params: AutoParams,
    rng: np.random.Generator,
) -> tuple[AutoState, list[Fix]]:
    """The chosen engine's ``step`` over the batch (choosing first when it changes): its
    fixes calibrated by it, tagged with its index."""
    choice = choose(events, state.choice)
    if choice == UNDECIDED:
        return state, []
    spec = CANDIDATES[choice]
    inner = state.inner if choice == state.choice else spec.start(params.of(choice))
    new, fixes = spec.step(inner, events, maps, params.of(choice), rng)
    held: dict[str, Any] = {c.name: None for c in CANDIDATES} | {spec.name: new}
    tagged = [
        replace(f, diagnostics={**f.diagnostics, "auto_engine": float(choice)}) for f in fixes
    ]
    return AutoState(choice, **held), tagged


# its state holds another engine's: no handlers of its own, the whole batch goes to ``run``
SPEC = EngineSpec(
    name="auto",
    params_type=AutoParams,
    state_type=AutoState,
    initial_state=initial_state,
    uses=frozenset().union(*(c.uses for c in CANDIDATES)),
    handlers=(),
    delegate=run,
)
