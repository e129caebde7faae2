"""Engine parameters other than their defaults, given as text (``--param NAME=VALUE``)."""

from __future__ import annotations

from collections.abc import Mapping

from server.positioning.engines.registry import get_engine
from server.positioning.model.params import Params, assignments


def engine_params(engine: str, overrides: Mapping[str, str] | None = None) -> Params:
    """The engine's default parameters with some replaced, named with dots for nested
    ones and given as text (``{"k": "8", "particles.n": "500"}``, each value read as JSON
    or else as a word), for trying variants on a validation split.

    Raises
    ------
    KeyError
        For an unknown engine.
    ValueError
        ``params.ParamError`` naming the dotted parameter that does not exist or whose
        value the engine refuses.
    """
    spec = get_engine(engine)
    items = [f"{name}={text}" for name, text in (overrides or {}).items()]
    return spec.params(assignments(items))
