"""Engine states as flat named arrays and back, read off the states' dataclass fields.

Every engine state (and every part nested in one) is a frozen dataclass whose fields are
``int``, ``float``, ``bool``, numpy arrays typed ``NDArray[<dtype>]`` (optionally with a
fixed shape declared by ``field(metadata=shape(4, 4))``, ``-1`` for any length), or
another such dataclass, possibly ``| None``. :func:`to_arrays` turns a state into
``{name: ndarray}`` (scalars as 0-d arrays, nested parts under ``"<field>."``), which the
storage layer writes as dtype + shape + raw bytes; :func:`from_arrays` inverts it exactly
and refuses, with :class:`StateError`, arrays that are missing, unknown, or of another
dtype or shape (an int field must hold an integer, a bool 0 or 1). A state class may
define ``check_decoded(self)`` for what its fields cannot say (a cloud's positions are
finite); it runs after decoding.

``LAYOUT`` numbers this encoding: states written under another number are not decoded
(the session layer starts them afresh). Bump it when a state's fields change: a state of
other fields is refused rather than read wrongly.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

LAYOUT = 2  # 1: hand-written per-class encodings with "trk."/"pf." prefixes

T = TypeVar("T")

_SHAPE = "state_shape"


class StateError(ValueError):
    """Arrays that are not a state of the class asked for."""


def shape(*dims: int) -> dict[str, tuple[int, ...]]:
    """Field metadata fixing an array field's shape (``-1``: any length on that axis)."""
    return {_SHAPE: dims}


@dataclasses.dataclass(frozen=True)
class _Field:
    name: str
    kind: str  # "int" | "float" | "bool" | "array" | "part"
    dtype: np.dtype[Any] | None = None
    dims: tuple[int, ...] | None = None
    part: type | None = None
    optional: bool = False


def _array_dtype(hint: object) -> np.dtype[Any]:
    """The dtype of an ``NDArray[<dtype>]`` hint."""
    args = typing.get_args(hint)
    if len(args) == 2:
        inner = typing.get_args(args[1])
        if inner:
            dtype: np.dtype[Any] = np.dtype(inner[0])
            return dtype
    raise TypeError(f"array field hint {hint!r} does not name a dtype")


_FIELDS: dict[type, tuple[_Field, ...]] = {}


def _fields(cls: type) -> tuple[_Field, ...]:
    """The fields of ``cls`` as the checks read them (made once per class)."""
    known = _FIELDS.get(cls)
    if known is not None:
        return known
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        optional = False
        if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
            args = [a for a in typing.get_args(hint) if a is not type(None)]
            optional = len(args) < len(typing.get_args(hint))
            if len(args) != 1:
                raise TypeError(f"{cls.__name__}.{f.name}: a union the codec cannot carry")
            hint = args[0]
        if hint in (int, float, bool):
            out.append(_Field(f.name, hint.__name__))
        elif typing.get_origin(hint) is np.ndarray:
            dims = f.metadata.get(_SHAPE)
            out.append(_Field(f.name, "array", _array_dtype(hint), dims))
        elif isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out.append(_Field(f.name, "part", part=hint, optional=optional))
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: the codec cannot carry {hint!r}")
    _FIELDS[cls] = fields = tuple(out)
    return fields


_SCALAR_DTYPES = {"int": np.int64, "float": np.float64, "bool": np.int8}


def to_arrays(state: object, prefix: str = "") -> dict[str, np.ndarray]:
    """The state's fields as named arrays (see the module docstring)."""
    out: dict[str, np.ndarray] = {}
    for f in _fields(type(state)):
        value = getattr(state, f.name)
        key = prefix + f.name
        if f.kind == "part":
            if value is not None:
                out.update(to_arrays(value, key + "."))
        elif f.kind == "array":
            out[key] = np.array(value, dtype=f.dtype)
        else:
            out[key] = np.array(value, dtype=_SCALAR_DTYPES[f.kind])
    return out


def from_arrays(cls: type[T], arrays: Mapping[str, np.ndarray]) -> T:
    """The state of class ``cls`` that ``to_arrays`` turned into ``arrays``.

    Raises
    ------
    StateError
        When an array is missing, unknown, of another dtype kind or shape than its field
        declares, or the state refuses the values.
    """
    used: set[str] = set()
    state = _decode(cls, arrays, "", used)
    unknown = sorted(set(arrays) - used)
    if unknown:
        raise StateError(f"{cls.__name__} state has unknown arrays: {', '.join(unknown[:5])}")
    return state


_SCALAR_KINDS = {"int": "iub", "bool": "iub", "float": "f"}


def _decode(cls: type[T], arrays: Mapping[str, np.ndarray], prefix: str, used: set[str]) -> T:
    values: dict[str, object] = {}
    for f in _fields(cls):
        key = prefix + f.name
        if f.kind == "part":
            assert f.part is not None
            present = any(k.startswith(key + ".") for k in arrays)
            if f.optional and not present:
                values[f.name] = None
            else:
                values[f.name] = _decode(f.part, arrays, key + ".", used)
            continue
        if key not in arrays:
            raise StateError(f"{cls.__name__} state lacks {key!r}")
        used.add(key)
        array = np.asarray(arrays[key])
        if f.kind == "array":
            if array.dtype != f.dtype:
                raise StateError(f"{key} must be {f.dtype}, got {array.dtype}")
            value = np.array(array)
            if f.dims is not None and (
                value.ndim != len(f.dims)
                or any(d not in (-1, n) for d, n in zip(f.dims, value.shape, strict=True))
            ):
                raise StateError(f"{key} must have shape {f.dims}, got {value.shape}")
            values[f.name] = value
            continue
        if array.shape != () or array.dtype.kind not in _SCALAR_KINDS[f.kind]:
            raise StateError(f"{key} must be one {f.kind}, got {array.dtype} of {array.shape}")
        if f.kind == "int":
            values[f.name] = int(array)
        elif f.kind == "float":
            values[f.name] = float(array)
        elif int(array) in (0, 1):
            values[f.name] = bool(array)
        else:
            raise StateError(f"{key} must be 0 or 1, got {int(array)}")
    try:
        state = cls(**values)
        check = getattr(state, "check_decoded", None)
        if check is not None:
            check()
    except StateError:
        raise
    except (TypeError, ValueError) as e:
        raise StateError(f"{cls.__name__} state refused: {e}") from None
    return state
