"""Array codecs: numpy arrays as bytes that cross process boundaries (Redis, SQL blobs).

A container holds named arrays as dtype + shape header + raw bytes; nothing is pickled and
nothing is evaluated, so decoding untrusted bytes can at worst raise :class:`CodecError`.

Layout (all integers little-endian)::

    magic    4 bytes  b"IPAR"
    version  u8       1
    count    u32      number of arrays
    count times:
      name_len  u16, name   utf-8, unique within the container
      dtype_len u8,  dtype  numpy dtype string, little-endian: |b1 |i1 <i2 <i4 <i8 |u1 <u2
                            <u4 <u8 <f4 <f8
      ndim      u8 (<= 64), shape  ndim x u64
      data      prod(shape) * itemsize bytes, C order

The container ends exactly after the last array. Decoded arrays are fresh, writable,
C-contiguous copies in native byte order.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Mapping

import numpy as np

MAGIC = b"IPAR"
FORMAT_VERSION = 1
MAX_NDIM = 64  # numpy's own limit
ZLIB_LEVEL = 6

ALLOWED_DTYPES = frozenset(
    {"|b1", "|i1", "<i2", "<i4", "<i8", "|u1", "<u2", "<u4", "<u8", "<f4", "<f8"}
)

_HEADER = struct.Struct("<4sBI")
_U8 = struct.Struct("<B")
_U16 = struct.Struct("<H")
_U64 = struct.Struct("<Q")


class CodecError(ValueError):
    """Bytes that are not a valid array container, or an array the codec cannot carry."""


def _wire_dtype(dtype: np.dtype) -> np.dtype:
    """The little-endian form of ``dtype``, or :class:`CodecError` if its kind is not allowed."""
    wire = dtype.newbyteorder("<") if dtype.byteorder in "=>" else dtype
    if wire.str not in ALLOWED_DTYPES:
        allowed = ", ".join(sorted(ALLOWED_DTYPES))
        raise CodecError(f"dtype {dtype.str!r} cannot be encoded; allowed: {allowed}")
    return wire


def encode_arrays(arrays: Mapping[str, np.ndarray]) -> bytes:
    """Pack named arrays into one container (see the module docstring for the layout)."""
    parts = [_HEADER.pack(MAGIC, FORMAT_VERSION, len(arrays))]
    for name, value in arrays.items():
        array = np.asarray(value)
        wire = _wire_dtype(array.dtype)
        name_bytes = name.encode("utf-8")
        if len(name_bytes) > 0xFFFF:
            raise CodecError(f"array name longer than 65535 bytes: {name[:40]!r}...")
        dtype_bytes = wire.str.encode("ascii")
        parts += [
            _U16.pack(len(name_bytes)),
            name_bytes,
            _U8.pack(len(dtype_bytes)),
            dtype_bytes,
            _U8.pack(array.ndim),
            *(_U64.pack(n) for n in array.shape),
            array.astype(wire, copy=False).tobytes(order="C"),
        ]
    return b"".join(parts)


class _Reader:
    """Bounds-checked cursor over the container bytes. ``what.format(*args)`` names the
    field in the error message; the text is only built when something is wrong."""

    def __init__(self, data: bytes) -> None:
        self.view = memoryview(data)
        self.size = len(self.view)
        self.pos = 0

    def take(self, n: int, what: str, *args: object) -> memoryview:
        end = self.pos + n
        if end > self.size:
            raise CodecError(
                f"truncated array container: {what.format(*args)} needs {n} bytes at offset "
                f"{self.pos}, "
                f"only {self.size - self.pos} left"
            )
        chunk = self.view[self.pos : end]
        self.pos = end
        return chunk

    def unpack(self, fmt: struct.Struct, what: str, *args: object) -> int:
        if self.pos + fmt.size > self.size:
            self.take(fmt.size, what, *args)  # raises
        value: int = fmt.unpack_from(self.view, self.pos)[0]
        self.pos += fmt.size
        return value


# wire dtype string -> (wire dtype, the same in native byte order)
_DTYPES = {name: (np.dtype(name), np.dtype(name).newbyteorder("=")) for name in ALLOWED_DTYPES}


def decode_arrays(data: bytes) -> dict[str, np.ndarray]:
    """Unpack a container made by :func:`encode_arrays`, validating every field.

    Raises
    ------
    CodecError
        On a wrong magic or version, an unknown dtype, a bad name, sizes that do not add
        up, or trailing bytes.
    """
    reader = _Reader(data)
    magic, version, count = _HEADER.unpack(reader.take(_HEADER.size, "header"))
    if magic != MAGIC:
        raise CodecError(f"not an array container: magic {bytes(magic)!r}, expected {MAGIC!r}")
    if version != FORMAT_VERSION:
        raise CodecError(f"unsupported array container version {version}")
    arrays: dict[str, np.ndarray] = {}
    for index in range(count):
        name_len = reader.unpack(_U16, "array {} name length", index)
        name_raw = reader.take(name_len, "array {} name", index)
        try:
            name = str(name_raw, "utf-8")
        except UnicodeDecodeError as exc:
            raise CodecError(f"array {index}: name is not valid utf-8") from exc
        if name in arrays:
            raise CodecError(f"array {name!r} appears twice")
        dtype_len = reader.unpack(_U8, "array {!r} dtype length", name)
        dtype_str = str(reader.take(dtype_len, "array {!r}", name), "ascii", "replace")
        dtypes = _DTYPES.get(dtype_str)
        if dtypes is None:
            raise CodecError(f"array {name!r}: unknown or unsupported dtype {dtype_str!r}")
        dtype, native = dtypes
        ndim = reader.unpack(_U8, "array {!r} ndim", name)
        if ndim > MAX_NDIM:
            raise CodecError(f"array {name!r}: ndim {ndim} exceeds {MAX_NDIM}")
        shape = tuple(reader.unpack(_U64, "array {!r} shape", name) for _ in range(ndim))
        raw = reader.take(
            math.prod(shape) * dtype.itemsize, "array {!r} data of shape {}", name, shape
        )
        flat = np.frombuffer(raw, dtype=dtype)
        if dtype.kind == "b" and flat.view(np.uint8).max(initial=0) > 1:
            raise CodecError(f"array {name!r}: boolean data holds bytes other than 0 and 1")
        try:
            arrays[name] = flat.astype(native, copy=True).reshape(shape)
        except ValueError as exc:  # e.g. a zero-sized shape with a dimension numpy cannot index
            raise CodecError(f"array {name!r}: shape {shape} is not a valid numpy shape") from exc
    if reader.pos != len(data):
        raise CodecError(f"{len(data) - reader.pos} trailing bytes after the last array")
    return arrays


def str_to_array(s: str) -> np.ndarray:
    """A text value as a 1-d ``uint8`` array of its utf-8 bytes."""
    return np.frombuffer(s.encode("utf-8"), dtype=np.uint8).copy()


def array_to_str(a: np.ndarray) -> str:
    """The inverse of :func:`str_to_array`."""
    if a.dtype != np.uint8 or a.ndim != 1:
        raise CodecError(f"text must be a 1-d uint8 array, got {a.dtype} with shape {a.shape}")
    try:
        return a.tobytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CodecError("text array is not valid utf-8") from exc


def compress_arrays(arrays: Mapping[str, np.ndarray]) -> bytes:
    """:func:`encode_arrays`, then zlib at level 6 (for large grids stored as SQL blobs)."""
    return zlib.compress(encode_arrays(arrays), ZLIB_LEVEL)


def decompress_arrays(data: bytes) -> dict[str, np.ndarray]:
    """The inverse of :func:`compress_arrays`."""
    try:
        raw = zlib.decompress(data)
    except zlib.error as exc:
        raise CodecError(f"compressed array container is corrupt: {exc}") from exc
    return decode_arrays(raw)
