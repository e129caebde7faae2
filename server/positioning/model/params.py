"""Engine parameters: frozen dataclasses whose fields declare their own bounds.

A parameter class subclasses :class:`Params` and writes each field's type with its
bounds, from ``annotated_types`` (``Annotated[float, Gt(0)]``, or the aliases below), or
as a ``Literal`` of the allowed choices. :meth:`Params.__post_init__` checks every field
against its declared type in one place (an int is an int and not a bool, a float is
finite, a choice is one of the ``Literal``'s, a bound holds), then calls ``check`` for
rules that tie fields together.

:func:`build` makes a parameter object from its defaults and nested overrides (a
session's JSON ``params``, a site's engine settings, ``evaluate --param a.b=v``); every
error is a :class:`ParamError` that names the dotted field (``particles.n``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from collections.abc import Mapping
from typing import Annotated, Any, Literal, TypeVar

import annotated_types as at

P = TypeVar("P", bound="Params")

Positive = Annotated[float, at.Gt(0)]
NonNegative = Annotated[float, at.Ge(0)]
AtLeastOne = Annotated[int, at.Ge(1)]
NonNegativeInt = Annotated[int, at.Ge(0)]
Share = Annotated[float, at.Ge(0), at.Le(1)]  # a fraction in [0, 1]
OpenShare = Annotated[float, at.Gt(0), at.Lt(1)]  # a fraction in (0, 1)
# no parameter is larger than these: beyond them a number is a mistake (and, for floats,
# near overflow in the arithmetic that uses it)
MAX_ABS_INT = 2**53
MAX_ABS_FLOAT = 1e12


class ParamError(ValueError):
    """A parameter out of its bounds or of the wrong type; ``field`` is its dotted name."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}" if field else message)
        self.field = field
        self.message = message

    def under(self, prefix: str) -> ParamError:
        """The same error with its field named from an enclosing object."""
        return ParamError(f"{prefix}.{self.field}" if self.field else prefix, self.message)


@dataclasses.dataclass(frozen=True)
class _Field:
    name: str
    base: object  # the type without Annotated
    bounds: tuple[object, ...]  # annotated_types markers


_FIELDS: dict[type, tuple[_Field, ...]] = {}


def _fields(cls: type) -> tuple[_Field, ...]:
    """The fields of ``cls`` as the checks read them (made once per class)."""
    known = _FIELDS.get(cls)
    if known is not None:
        return known
    hints = typing.get_type_hints(cls, include_extras=True)
    out = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        bounds: tuple[object, ...] = ()
        if typing.get_origin(hint) is Annotated:
            base, *meta = typing.get_args(hint)
            for m in meta:
                bounds += tuple(m) if isinstance(m, at.GroupedMetadata) else (m,)
        else:
            base = hint
        out.append(_Field(f.name, base, bounds))
    _FIELDS[cls] = fields = tuple(out)
    return fields


def _describe(bound: object) -> tuple[str, float] | None:
    for attr, words in (("gt", "greater than"), ("ge", "at least"), ("lt", "less than")):
        if hasattr(bound, attr):
            return words, getattr(bound, attr)
    if hasattr(bound, "le"):
        return "at most", bound.le
    return None


def _holds(value: float, bound: object) -> bool:
    if isinstance(bound, at.Gt):
        return bool(value > bound.gt)  # type: ignore[operator]
    if isinstance(bound, at.Ge):
        return bool(value >= bound.ge)  # type: ignore[operator]
    if isinstance(bound, at.Lt):
        return bool(value < bound.lt)  # type: ignore[operator]
    if isinstance(bound, at.Le):
        return bool(value <= bound.le)  # type: ignore[operator]
    return True


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _check_value(base: object, bounds: tuple[object, ...], value: object) -> str | None:
    """Why ``value`` is not of type ``base`` within ``bounds``; None when it is."""
    origin = typing.get_origin(base)
    if origin is Literal:
        choices = typing.get_args(base)
        if value not in choices:
            return "must be one of " + ", ".join(repr(c) for c in choices)
        return None
    if origin is tuple:
        args = typing.get_args(base)
        if not isinstance(value, tuple):
            return "must be a list"
        if len(args) == 2 and args[1] is Ellipsis:
            args = (args[0],) * len(value)
        if len(value) != len(args):
            return f"must hold {len(args)} values"
        for arg, item in zip(args, value, strict=True):
            problem = _check_value(arg, bounds, item)
            if problem is not None:
                return f"each value {problem}"
        return None
    if base is bool:
        return None if isinstance(value, bool) else "must be true or false"
    if base is int:
        if not isinstance(value, int) or isinstance(value, bool):
            return "must be an integer"
        if abs(value) > MAX_ABS_INT:
            return f"must be at most {MAX_ABS_INT} in size"
    elif base is float:
        if not _is_number(value):
            return "must be a number"
        if isinstance(value, int) and abs(value) > MAX_ABS_INT:
            return f"must be at most {MAX_ABS_FLOAT:g} in size"
        if not math.isfinite(value):  # type: ignore[arg-type]
            return "must be finite"
        if abs(value) > MAX_ABS_FLOAT:  # type: ignore[arg-type]
            return f"must be at most {MAX_ABS_FLOAT:g} in size"
    elif base is str:
        return None if isinstance(value, str) else "must be a string"
    elif isinstance(base, type):
        return None if isinstance(value, base) else f"must be {base.__name__}"
    else:
        return None
    for bound in bounds:
        if not _holds(value, bound):  # type: ignore[arg-type]
            described = _describe(bound)
            if described is not None:
                return f"must be {described[0]} {described[1]}, got {value!r}"
    return None


class Params:
    """Base of every engine's (and every nested part's) parameters.

    Subclasses are ``@dataclass(frozen=True)``; their fields are checked on creation.
    """

    def __post_init__(self) -> None:
        for f in _fields(type(self)):
            problem = _check_value(f.base, f.bounds, getattr(self, f.name))
            if problem is not None:
                raise ParamError(f.name, problem)
        self.check()

    def check(self) -> None:
        """Rules between fields; raise :class:`ParamError` naming the field."""


def _coerce(base: object, value: object) -> object:
    """A JSON value in the Python type the field declares (ints for floats, lists for
    tuples); anything else is left for the field check to refuse."""
    origin = typing.get_origin(base)
    if origin is Annotated:
        return _coerce(typing.get_args(base)[0], value)
    if base is float and _is_number(value) and abs(value) <= MAX_ABS_INT:  # type: ignore[arg-type]
        return float(value)  # type: ignore[arg-type]
    if origin is tuple and isinstance(value, list | tuple):
        args = typing.get_args(base)
        if len(args) == 2 and args[1] is Ellipsis:
            args = (args[0],) * len(value)
        if len(args) == len(value):
            return tuple(_coerce(a, v) for a, v in zip(args, value, strict=True))
        return tuple(value)
    return value


def _is_params(value: object) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def build(defaults: P, overrides: Mapping[str, object]) -> P:
    """``defaults`` with the (nested) ``overrides`` applied and checked.

    Raises
    ------
    ParamError
        Naming the dotted field that is unknown, of the wrong type or out of bounds.
    """
    fields = {f.name: f for f in _fields(type(defaults))}
    changes: dict[str, object] = {}
    for key, value in overrides.items():
        f = fields.get(key)
        if f is None:
            known = ", ".join(sorted(fields))
            raise ParamError(key, f"unknown parameter; known: {known}")
        current = getattr(defaults, key)
        if _is_params(current):
            if not isinstance(value, Mapping):
                raise ParamError(key, "must be an object of parameters")
            try:
                changes[key] = build(current, value)
            except ParamError as e:
                raise e.under(key) from None
        else:
            changes[key] = _coerce(f.base, value)
    try:
        return dataclasses.replace(defaults, **changes)  # type: ignore[type-var]
    except ParamError:
        raise
    except (TypeError, ValueError) as e:
        raise ParamError("", str(e)) from None


def as_dict(params: object) -> dict[str, Any]:
    """Every field of a parameter object, nested ones as dicts, tuples as lists (JSON)."""

    def plain(value: object) -> object:
        if _is_params(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}  # type: ignore[arg-type]
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        return value

    out = plain(params)
    assert isinstance(out, dict)
    return out


def merge(*layers: Mapping[str, Any]) -> dict[str, Any]:
    """Nested overrides laid over each other, later ones winning field by field."""
    out: dict[str, Any] = {}
    for layer in layers:
        for key, value in layer.items():
            if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
                out[key] = merge(out[key], value)
            else:
                out[key] = dict(value) if isinstance(value, Mapping) else value
    return out


def assignments(items: list[str]) -> dict[str, Any]:
    """``["particles.n=500", "weighting=dtw"]`` as nested overrides; each value is read
    as JSON (``500``, ``true``, ``[1, 2]``) and as a plain string otherwise.

    Raises
    ------
    ParamError
        For an item without ``=`` or with an empty name.
    """
    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition("=")
        path = name.strip().split(".")
        if not sep or not all(path):
            raise ParamError(name.strip(), f"expected name=value (dots for nested), got {item!r}")
        try:
            value: object = json.loads(text)
        except ValueError:
            value = text
        layer: dict[str, Any] = {path[-1]: value}
        for part in reversed(path[:-1]):
            layer = {part: layer}
        out = merge(out, layer)
    return out
