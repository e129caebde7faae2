"""The array container: exact round trips, and malformed bytes refused with CodecError."""

from __future__ import annotations

import contextlib
import pickle  # noqa: TID251 - the tests prove the codec never calls it
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from server.storage.codec import (
    ALLOWED_DTYPES,
    MAGIC,
    CodecError,
    array_to_str,
    compress_arrays,
    decode_arrays,
    decompress_arrays,
    encode_arrays,
    str_to_array,
)

dtypes = (
    hnp.boolean_dtypes()
    | hnp.integer_dtypes(endianness="?")
    | hnp.unsigned_integer_dtypes(endianness="?")
    | hnp.floating_dtypes(sizes=(32, 64), endianness="?")
)
any_array = dtypes.flatmap(
    lambda dtype: hnp.arrays(
        dtype, hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=4)
    )
)
named_arrays = st.dictionaries(st.text(max_size=12), any_array, max_size=5)


def sample() -> dict[str, np.ndarray]:
    return {
        "x": np.arange(6, dtype=np.float64).reshape(2, 3),
        "flag": np.array(True),
        "empty": np.zeros((0, 3), dtype=np.int16),
    }


def assert_same(decoded: np.ndarray, original: np.ndarray) -> None:
    assert decoded.shape == original.shape
    assert decoded.dtype == original.dtype.newbyteorder("=")
    assert decoded.tobytes() == original.astype(decoded.dtype).tobytes()  # NaN payloads, -0.0


@given(named_arrays)
def test_round_trip_is_exact(arrays: dict[str, np.ndarray]) -> None:
    decoded = decode_arrays(encode_arrays(arrays))
    assert list(decoded) == list(arrays)
    for name, original in arrays.items():
        assert_same(decoded[name], original)
        assert decoded[name].flags.writeable
        assert decoded[name].flags.c_contiguous


@given(named_arrays)
@settings(max_examples=30)
def test_compressed_round_trip(arrays: dict[str, np.ndarray]) -> None:
    decoded = decompress_arrays(compress_arrays(arrays))
    assert list(decoded) == list(arrays)
    for name, original in arrays.items():
        assert_same(decoded[name], original)


def test_zero_d_and_empty_round_trip() -> None:
    arrays = {
        "scalar": np.array(-1.5),
        "none": np.array([], dtype=np.uint8),
        "": np.array(7, dtype=np.int64),
    }
    decoded = decode_arrays(encode_arrays(arrays))
    assert decoded["scalar"].shape == ()
    assert float(decoded["scalar"]) == -1.5
    assert decoded["none"].shape == (0,)
    assert decoded["none"].dtype == np.uint8
    assert int(decoded[""]) == 7
    assert decode_arrays(encode_arrays({})) == {}


def test_non_contiguous_and_big_endian_input() -> None:
    base = np.arange(24, dtype=">i4").reshape(4, 6)
    view = base[::2, ::-3]
    decoded = decode_arrays(encode_arrays({"v": view}))["v"]
    np.testing.assert_array_equal(decoded, view)
    assert decoded.dtype == np.dtype(np.int32)


def test_decoded_arrays_do_not_alias_the_input() -> None:
    data = bytearray(encode_arrays({"x": np.zeros(4)}))
    decoded = decode_arrays(bytes(data))["x"]
    decoded[0] = 1.0
    assert decode_arrays(bytes(data))["x"][0] == 0.0


@pytest.mark.parametrize(
    "value",
    [
        np.array(["text"]),
        np.array([1 + 2j]),
        np.array([1.0], dtype=np.float16),
        np.array([None], dtype=object),
        np.array(["2024-01-01"], dtype="datetime64[D]"),
        np.zeros(2, dtype=[("a", "<f8")]),
    ],
)
def test_unsupported_dtypes_are_refused(value: np.ndarray) -> None:
    with pytest.raises(CodecError, match="cannot be encoded"):
        encode_arrays({"v": value})


def test_pickle_is_never_used(monkeypatch: pytest.MonkeyPatch) -> None:
    def forbidden(*args: object, **kwargs: object) -> None:
        raise AssertionError("pickle used")

    for name in ("dumps", "loads", "dump", "load"):
        monkeypatch.setattr(pickle, name, forbidden)
    arrays = sample()
    decoded = decompress_arrays(compress_arrays(arrays))
    for name, original in arrays.items():
        assert_same(decoded[name], original)
    # a pickled object array is refused, not loaded
    with pytest.raises(CodecError):
        encode_arrays({"o": np.array([{"a": 1}], dtype=object)})


def test_every_truncation_is_refused() -> None:
    data = encode_arrays(sample())
    for end in range(len(data)):
        with pytest.raises(CodecError):
            decode_arrays(data[:end])


def test_wrong_magic() -> None:
    data = encode_arrays(sample())
    with pytest.raises(CodecError, match="magic"):
        decode_arrays(b"XXXX" + data[len(MAGIC) :])
    with pytest.raises(CodecError, match="magic"):
        decode_arrays(pickle.dumps({"x": 1}))


def test_unknown_version() -> None:
    data = bytearray(encode_arrays(sample()))
    data[len(MAGIC)] = 99
    with pytest.raises(CodecError, match="version 99"):
        decode_arrays(bytes(data))


@pytest.mark.parametrize("dtype", [b">f8", b"<c8", b"<f2", b"|O8", b"<M8", b"\xff\xfe\x00"])
def test_bad_dtype(dtype: bytes) -> None:
    data = encode_arrays({"x": np.zeros(1)})
    assert dtype not in {d.encode() for d in ALLOWED_DTYPES}
    bad = data.replace(b"\x03<f8", bytes([len(dtype)]) + dtype)
    with pytest.raises(CodecError, match="dtype"):
        decode_arrays(bad)


def test_trailing_bytes() -> None:
    with pytest.raises(CodecError, match="1 trailing bytes"):
        decode_arrays(encode_arrays(sample()) + b"\x00")


def test_array_count_larger_than_content() -> None:
    data = bytearray(encode_arrays(sample()))
    struct.pack_into("<I", data, len(MAGIC) + 1, 4)
    with pytest.raises(CodecError, match="truncated"):
        decode_arrays(bytes(data))


def test_duplicate_names() -> None:
    one = encode_arrays({"x": np.zeros(2)})
    body = one[len(MAGIC) + 5 :]
    header = MAGIC + struct.pack("<BI", 1, 2)
    with pytest.raises(CodecError, match="twice"):
        decode_arrays(header + body + body)


def test_name_not_utf8() -> None:
    data = encode_arrays({"ab": np.zeros(1)})
    with pytest.raises(CodecError, match="utf-8"):
        decode_arrays(data.replace(b"\x02\x00ab", b"\x02\x00\xff\xfe"))


def test_boolean_bytes_other_than_zero_or_one() -> None:
    data = encode_arrays({"b": np.array([True, False])})
    assert data.endswith(b"\x01\x00")
    with pytest.raises(CodecError, match="boolean"):
        decode_arrays(data[:-2] + b"\x02\x00")


def test_shapes_that_do_not_add_up() -> None:
    data = encode_arrays({"x": np.zeros((0, 2))})
    shape_at = data.index(b"<f8") + 3 + 1  # after dtype and ndim
    huge = data[:shape_at] + struct.pack("<QQ", 2**40, 2**40) + data[shape_at + 16 :]
    with pytest.raises(CodecError, match="truncated"):
        decode_arrays(huge)
    absurd = data[:shape_at] + struct.pack("<QQ", 0, 2**64 - 1) + data[shape_at + 16 :]
    with pytest.raises(CodecError, match="shape"):
        decode_arrays(absurd)
    too_many_dims = data[: shape_at - 1] + b"\x41" + data[shape_at:]
    with pytest.raises(CodecError, match="ndim"):
        decode_arrays(too_many_dims)


@given(st.binary(max_size=200))
def test_arbitrary_bytes_decode_or_raise_codec_error(data: bytes) -> None:
    with contextlib.suppress(CodecError):
        decode_arrays(MAGIC + data)


@given(st.data())
def test_corrupted_containers_decode_or_raise_codec_error(data: st.DataObject) -> None:
    blob = bytearray(encode_arrays(sample()))
    index = data.draw(st.integers(0, len(blob) - 1))
    blob[index] = data.draw(st.integers(0, 255))
    with contextlib.suppress(CodecError):
        decode_arrays(bytes(blob))


def test_corrupt_compressed_data() -> None:
    with pytest.raises(CodecError, match="corrupt"):
        decompress_arrays(b"not zlib")
    with pytest.raises(CodecError, match="magic"):
        decompress_arrays(zlib.compress(b"plain text"))


@given(st.text())
def test_text_round_trip(text: str) -> None:
    array = str_to_array(text)
    assert array.dtype == np.uint8
    assert array.ndim == 1
    assert array_to_str(decode_arrays(encode_arrays({"t": array}))["t"]) == text


def test_text_from_a_wrong_array() -> None:
    with pytest.raises(CodecError, match="uint8"):
        array_to_str(np.zeros(3, dtype=np.int32))
    with pytest.raises(CodecError, match="utf-8"):
        array_to_str(np.array([0xFF], dtype=np.uint8))
