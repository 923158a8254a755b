"""The step-output container: exact round trips, deterministic bytes, no objects, garbage refused."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from assetpipe.cache.serialize import MAGIC, pack, pack_chunks, unpack

DTYPES = ["<f4", ">f4", "<f8", "<f2", "<u4", ">u4", "<i8", "<u2", "u1", "i1", "?", "<c8", "<c16", "<U3",
          "S5", "<M8[s]", "<m8[ms]"]


def _sample(dtype: str, shape: tuple) -> np.ndarray:
    n = int(np.prod(shape))
    dt = np.dtype(dtype)
    if dt.kind in "US":
        a = np.array([f"s{i}" for i in range(n)], dtype=dt)
    elif dt.kind == "M":
        a = (np.datetime64("2024-01-01", "s") + np.arange(n)).astype(dt)
    else:
        a = (np.arange(n) * 3 + 1).astype(dt)
    return a.reshape(shape)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(7,), (3, 5), (2, 3, 4), (0,), (0, 3), (4, 0), ()])
def test_round_trip(dtype, shape):
    a = _sample(dtype, shape)
    meta, arrays = unpack(pack({"k": 1}, {"a": a}))
    b = arrays["a"]
    assert meta == {"k": 1}
    assert b.shape == a.shape
    assert b.dtype == a.dtype.newbyteorder("<") or b.dtype == a.dtype
    assert b.dtype.byteorder in "<|=" or (b.dtype.byteorder == "=" and np.little_endian)
    np.testing.assert_array_equal(b, a)


def test_many_arrays_with_awkward_sizes_are_aligned_and_exact():
    rng = np.random.default_rng(0)
    arrays = {"b": rng.integers(0, 255, 7, dtype=np.uint8), "a": rng.normal(size=(5, 3)),
              "c": np.array(3.5), "d": np.zeros((0, 3), np.uint32), "e": rng.normal(size=11).astype(np.float16),
              "f.indices": rng.integers(0, 1 << 32, (4, 3), dtype=np.uint64).astype(np.uint32)}
    data = pack({"meshes": [{"name": "x"}]}, arrays)
    meta, out = unpack(data)
    assert meta == {"meshes": [{"name": "x"}]}
    assert sorted(out) == sorted(arrays)
    for k, a in arrays.items():
        np.testing.assert_array_equal(out[k], a)
        assert out[k].dtype == a.dtype and out[k].shape == a.shape
    (hlen,) = struct.unpack_from("<I", data, 4)
    header = json.loads(data[8:8 + hlen])
    assert [e["name"] for e in header["arrays"]] == sorted(arrays)
    assert all(e["offset"] % 16 == 0 for e in header["arrays"])


def test_non_contiguous_and_fortran_inputs():
    a = np.arange(24, dtype=np.float64).reshape(4, 6)
    for v in (a[:, ::2], a.T, np.asfortranarray(a)):
        _, out = unpack(pack({}, {"v": v}))
        np.testing.assert_array_equal(out["v"], v)


def test_nan_and_negative_zero_bits_survive():
    a = np.array([np.nan, -0.0, np.inf, -np.inf, 1e-45], np.float32)
    _, out = unpack(pack({}, {"a": a}))
    assert out["a"].tobytes() == a.tobytes()


def test_deterministic_bytes():
    def build():
        return pack({"z": 1, "a": [1, 2, {"y": 0.1, "b": None}]},
                    {"y": np.arange(5, dtype=np.float32), "x": np.ones((2, 2), ">f8")})
    one = build()
    assert one == build()
    assert one.startswith(MAGIC)
    # key order of meta and of the array dict does not matter
    other = pack({"a": [1, 2, {"b": None, "y": 0.1}], "z": 1},
                 {"x": np.ones((2, 2), "<f8"), "y": np.arange(5, dtype=np.float32)})
    assert other == one


def test_empty_pack():
    meta, arrays = unpack(pack({}, {}))
    assert meta == {} and arrays == {}


def test_object_dtype_refused():
    with pytest.raises(TypeError, match="object dtype"):
        pack({}, {"o": np.array([{"a": 1}, None], dtype=object)})
    with pytest.raises(TypeError, match="object dtype"):
        pack({}, {"s": np.zeros(2, dtype=[("a", "<f4"), ("b", "O")])})


def test_structured_dtype_refused():
    # its dtype.str is an anonymous "|V6": the fields would silently come back as raw bytes
    a = np.zeros(3, dtype=[("x", "<f4"), ("n", "<u2")])
    with pytest.raises(TypeError, match="structured"):
        pack({}, {"s": a})
    with pytest.raises(TypeError, match="structured"):
        pack({}, {"s": np.zeros(2, dtype=[("v", "<f4", (3,))])})


def test_non_finite_meta_refused():
    with pytest.raises(ValueError, match='Out of range float values are not JSON compliant'):
        pack({"x": float("nan")}, {})


def _valid() -> bytes:
    return pack({"m": 1}, {"a": np.arange(10, dtype=np.float64)})


def _with_header(header: dict | list | str, tail: bytes = b"") -> bytes:
    h = json.dumps(header).encode()
    return MAGIC + struct.pack("<I", len(h)) + h + tail


@pytest.mark.parametrize("data", [
    b"", b"APK", b"APK1", b"APK1\x00\x00", b"PK\x03\x04 a zip file", b"APK2" + _valid()[4:],
    _valid()[:12],  # header cut short
    _valid()[:-8],  # last array cut short
    MAGIC + struct.pack("<I", 1 << 30) + b"{}",  # header length beyond the data
    _with_header("not a dict"),
    _with_header({"meta": {}}),  # no array table
    _with_header({"meta": {}, "arrays": [{"name": "a", "dtype": "|O", "shape": [2], "offset": 0, "size": 16}]},
                 b"\0" * 16),  # object dtype from the cache: never
    _with_header({"meta": {}, "arrays": [{"name": "a", "dtype": "<f8", "shape": [-1], "offset": 0, "size": 8}]},
                 b"\0" * 8),
    _with_header({"meta": {}, "arrays": [{"name": "a", "dtype": "nonsense", "shape": [1], "offset": 0,
                                          "size": 8}]}, b"\0" * 8),
    _with_header({"meta": {}, "arrays": [{"name": "a", "dtype": "<f8", "shape": [1], "offset": -8, "size": 8}]},
                 b"\0" * 8),
])
def test_garbage_refused_with_value_error(data):
    # every refusal of unpack() names what is wrong with the pack (cache/serialize.py)
    with pytest.raises(ValueError, match="not an assetpipe pack|assetpipe pack: |bad array entry"):
        unpack(data)


def test_equal_arrays_are_stored_once_and_each_entry_reads_them():
    """The placements of one mesh have equal index buffers: stored once, every entry reads its
    own copy back, with its own dtype and shape (equal bytes of another type share them too)."""
    idx = np.arange(3000, dtype=np.uint32).reshape(-1, 3)
    other = np.arange(3000, dtype=np.uint32)[::-1].reshape(-1, 3).copy()
    arrays = {f"{i}.lod0": idx.copy() for i in range(5)}
    arrays["5.lod0"] = other
    arrays["bits"] = idx.view(np.float32).reshape(-1)  # the same bytes as float32, flat
    data = pack({"n": 6}, arrays)
    alone = pack({"n": 6}, {"0.lod0": idx, "5.lod0": other})
    assert len(data) - len(alone) < 1000  # five equal buffers and their reinterpretation: one copy
    meta, back = unpack(data)
    assert meta == {"n": 6}
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype and back[name].shape == a.shape
        assert back[name].tobytes() == a.tobytes()
    assert pack({"n": 6}, arrays) == data


def test_small_equal_arrays_are_stored_each():
    small = np.zeros(8, np.uint8)  # below SHARE_MIN_BYTES
    data = pack({}, {"a": small, "b": small.copy()})
    _, back = unpack(data)
    assert np.array_equal(back["a"], small) and np.array_equal(back["b"], small)
    header_offsets = {e["offset"] for e in json.loads(data[8:8 + struct.unpack_from("<I", data, 4)[0]])["arrays"]}
    assert len(header_offsets) == 2


def test_chunks_join_to_the_pack_and_are_the_arrays_own_memory():
    big = np.arange(300_000, dtype="<f4").reshape(-1, 3)
    arrays = {"big": big, "small": np.arange(5, dtype="<u2"), "same": big.copy(), "empty": np.zeros((0, 3))}
    pieces = pack_chunks({"k": 1}, arrays)
    assert b"".join(pieces) == pack({"k": 1}, arrays)
    # the large array is written from its own buffer, not from a copy (the shared copy
    # "same" is stored once: its entry reads big's bytes)
    assert any(isinstance(p, memoryview) and np.shares_memory(np.frombuffer(p, np.uint8), big) for p in pieces)
    assert sum(len(p) if isinstance(p, bytes) else p.nbytes for p in pieces) == len(pack({"k": 1}, arrays))
