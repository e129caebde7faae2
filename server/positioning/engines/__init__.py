"""Fusion engines: one module per engine, each declaring its ``SPEC``, an ``EngineSpec``;
what they share is in ``shared`` (the spec and its driver, the site's maps, the radio side,
the PDR engines' Kalman state).

An engine module holds its parameters, its state, a handler per kind of item it reads
(``handler(state, item, maps, params, rng) -> (state, fix or None)``) and its ``SPEC``,
which names them: ``handlers=(on(StepEvent, on_step), on(WifiEvent, on_scan), ...)``,
with optional hooks (``prepass``: what the batch becomes first, such as the barometer's
floor changes or the steps found in raw samples; ``rank``: the order at equal times).
``auto``, which runs another engine, declares a ``delegate`` instead of handlers. The one
driver, ``EngineSpec.run`` in ``shared.spec``, walks every engine's batches; ``spec``'s
docstring says how.

``ENGINES`` maps an engine name (as a session names it) to its ``EngineSpec``, seen as
an ``Engine`` (a state of any type, checked at run time); a service calls
``Engine.step`` (``EngineSpec.step`` -> ``EngineSpec.run`` -> the engine's handlers).
"""

from __future__ import annotations

from server.positioning.engines import (
    auto,
    everywhere_ekf,
    fai_ekf,
    map_markov,
    pf_magnetic,
    step_ekf,
    two_stage_ekf,
    wknn,
)
from server.positioning.engines.shared.spec import Engine

ENGINES: dict[str, Engine] = {
    spec.name: spec
    for spec in (
        auto.SPEC,
        everywhere_ekf.SPEC,
        fai_ekf.SPEC,
        map_markov.SPEC,
        pf_magnetic.SPEC,
        step_ekf.SPEC,
        two_stage_ekf.SPEC,
        wknn.SPEC,
    )
}


# engines that read the floors' reference-point graphs (``SiteMaps.graphs``), built for
# their sessions only
NEEDS_GRAPHS = frozenset({map_markov.SPEC.name})


def get_engine(name: str) -> Engine:
    """The registry entry of engine ``name``.

    Raises
    ------
    KeyError
        When no engine has that name; the message lists the known engines.
    """
    try:
        return ENGINES[name]
    except KeyError:
        known = ", ".join(sorted(ENGINES))
        raise KeyError(f"unknown engine {name!r}; known engines: {known}") from None
