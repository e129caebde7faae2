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

``registry.ENGINES`` maps an engine name (as a session names it) to its ``EngineSpec``,
seen as an ``Engine`` (a state of any type, checked at run time); a service calls
``Engine.step`` (``EngineSpec.step`` -> ``EngineSpec.run`` -> the engine's handlers).
This package's own module loads nothing, so that what the engines share (``shared``, e.g.
``SiteMaps``, which the map builder makes) can be imported without every engine.
"""
