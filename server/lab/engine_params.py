"""Engine parameters other than their defaults, given as text (``--param NAME=VALUE``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from server.positioning.engines import get_engine


def engine_params(engine: str, overrides: Mapping[str, str] | None = None) -> Any:
    """The engine's default parameters with some scalar ones replaced, the values given
    as text (``{"k": "8"}``), for trying variants on a validation split.

    Raises
    ------
    ValueError
        Naming the parameter, when it does not exist, is not a number or flag, or its
        value does not parse or is refused by the engine.
    """
    params = get_engine(engine).params_type()
    changes: dict[str, Any] = {}
    for name, text in (overrides or {}).items():
        if name.startswith("_") or not hasattr(params, name):
            raise ValueError(f"{engine} has no parameter {name!r}")
        kind = type(getattr(params, name))
        if kind not in (int, float, bool, str):
            raise ValueError(f"parameter {name!r} of {engine} is not a number, flag or word")
        try:
            changes[name] = text.lower() in ("1", "true", "yes") if kind is bool else kind(text)
        except ValueError:
            raise ValueError(f"parameter {name!r}: {text!r} is not a {kind.__name__}") from None
    try:
        return replace(params, **changes)
    except ValueError as e:
        raise ValueError(f"parameters of {engine}: {e}") from None
