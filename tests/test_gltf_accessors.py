"""AccessorReader: component types, normalization, strides, offsets, sparse, buffers, meshopt."""

from __future__ import annotations

import json

import base64
import struct
from pathlib import Path

import numpy as np
import pytest

from assetpipe.core.errors import AssetError, MissingFileError
from assetpipe.pipelines.gltf_accessors import AccessorReader, data_uri_mime, decode_data_uri
from assetpipe.pipelines.import_gltf import _parse
from gltf_builder import GltfBuilder

INT_DTYPES = [np.int8, np.uint8, np.int16, np.uint16, np.uint32]


def reader_for(b: GltfBuilder, tmp_path: Path, *, glb: bool = False, embed: bool = False) -> AccessorReader:
    path = b.write_glb(tmp_path / "m.glb") if glb else b.write_gltf(tmp_path / "m.gltf", embed=embed)
    gltf, blob = _parse(path)
    return AccessorReader(gltf, path, blob)


# -- component types and normalization --------------------------------------------------------

@pytest.mark.parametrize("dtype", INT_DTYPES + [np.float32])
def test_every_component_type_raw_and_float(tmp_path, dtype):
    info = np.iinfo(dtype) if dtype != np.float32 else None
    if info is not None:
        values = np.array([[info.min, 0], [1, info.max], [info.max // 3, info.min // 2 + 7]], dtype=dtype)
    else:
        values = np.array([[-1.5, 0.0], [3.25, 1e30], [-1e-30, 7.0]], dtype=np.float32)
    b = GltfBuilder()
    acc = b.add_accessor(values)
    r = reader_for(b, tmp_path)
    raw = r.accessor(acc, as_float=False)
    assert raw.dtype == np.dtype(dtype) and raw.shape == (3, 2)
    np.testing.assert_array_equal(raw, values)
    as_float = r.accessor(acc)
    assert as_float.dtype == np.float64
    np.testing.assert_array_equal(as_float, values.astype(np.float64))


def test_scalar_accessor_is_one_dimensional(tmp_path):
    b = GltfBuilder()
    acc = b.add_accessor(np.array([5, 6, 7], np.uint16))
    out = reader_for(b, tmp_path).accessor(acc, as_float=False)
    assert out.shape == (3,)
    np.testing.assert_array_equal(out, [5, 6, 7])


@pytest.mark.parametrize("dtype, raw, expected", [
    (np.int8, [-128, -127, 0, 64, 127], [-1.0, -1.0, 0.0, 64 / 127, 1.0]),
    (np.uint8, [0, 1, 128, 255], [0.0, 1 / 255, 128 / 255, 1.0]),
    (np.int16, [-32768, -32767, -1, 16384, 32767], [-1.0, -1.0, -1 / 32767, 16384 / 32767, 1.0]),
    (np.uint16, [0, 1, 32768, 65535], [0.0, 1 / 65535, 32768 / 65535, 1.0]),
])
def test_normalized_integers(tmp_path, dtype, raw, expected):
    b = GltfBuilder()
    acc = b.add_accessor(np.array(raw, dtype), normalized=True)
    r = reader_for(b, tmp_path)
    np.testing.assert_allclose(r.accessor(acc), expected, rtol=0, atol=1e-12)
    # the raw integers stay available for indices / joints
    np.testing.assert_array_equal(r.accessor(acc, as_float=False), raw)


def test_normalized_vec4_colors(tmp_path):
    colors = np.array([[255, 0, 51, 255], [0, 255, 102, 0]], np.uint8)
    b = GltfBuilder()
    acc = b.add_accessor(colors, normalized=True)
    np.testing.assert_allclose(reader_for(b, tmp_path).accessor(acc), colors / 255.0, atol=1e-12)


# -- offsets and strides ---------------------------------------------------------------------

def test_interleaved_buffer_view_with_stride(tmp_path):
    pos = np.arange(12, dtype=np.float32).reshape(4, 3) * 1.5
    uv = np.arange(8, dtype=np.float32).reshape(4, 2) / 8
    col = np.array([[10, 20, 30, 40], [50, 60, 70, 80], [90, 100, 110, 120], [130, 140, 150, 255]], np.uint8)
    # one vertex = 3 f32 + 2 f32 + 4 u8 = 24 bytes
    rec = np.dtype([("p", "<f4", 3), ("t", "<f4", 2), ("c", "u1", 4)])
    inter = np.zeros(4, rec)
    inter["p"], inter["t"], inter["c"] = pos, uv, col
    assert rec.itemsize == 24
    b = GltfBuilder()
    view = b.add_view(inter.tobytes(), stride=24, target=34962)
    a_pos = b.add_accessor(view=view, component_type=5126, type="VEC3", count=4)
    a_uv = b.add_accessor(view=view, byte_offset=12, component_type=5126, type="VEC2", count=4)
    a_col = b.add_accessor(view=view, byte_offset=20, component_type=5121, type="VEC4", count=4, normalized=True)
    r = reader_for(b, tmp_path)
    np.testing.assert_array_equal(r.accessor(a_pos), pos)
    np.testing.assert_array_equal(r.accessor(a_uv), uv)
    np.testing.assert_allclose(r.accessor(a_col), col / 255.0, atol=1e-12)


def test_byte_offset_in_tightly_packed_view(tmp_path):
    data = np.arange(10, dtype=np.uint16)
    b = GltfBuilder()
    view = b.add_view(data.tobytes())
    acc = b.add_accessor(view=view, byte_offset=6, component_type=5123, type="SCALAR", count=4)
    np.testing.assert_array_equal(reader_for(b, tmp_path).accessor(acc, as_float=False), [3, 4, 5, 6])


def test_view_byte_offset_into_buffer(tmp_path):
    b = GltfBuilder()
    b.add_bytes(b"\xff" * 16)  # junk before the view
    acc = b.add_accessor(np.array([[1.0, 2.0], [3.0, 4.0]], np.float32))
    assert b.doc["bufferViews"][0]["byteOffset"] == 16
    np.testing.assert_array_equal(reader_for(b, tmp_path).accessor(acc), [[1, 2], [3, 4]])


def test_accessor_past_the_end_of_its_view_is_an_asset_error(tmp_path):
    b = GltfBuilder()
    view = b.add_view(np.zeros(5, np.float32).tobytes())
    acc = b.add_accessor(view=view, byte_offset=4, component_type=5126, type="VEC2", count=3)
    with pytest.raises(AssetError, match=f"accessor {acc}"):
        reader_for(b, tmp_path).accessor(acc)


def test_view_past_the_end_of_its_buffer_is_an_asset_error(tmp_path):
    b = GltfBuilder()
    acc = b.add_accessor(np.zeros((2, 3), np.float32))
    b.doc["bufferViews"][0]["byteLength"] = 1000
    with pytest.raises(AssetError, match="bufferView 0"):
        reader_for(b, tmp_path).accessor(acc)


def test_stride_smaller_than_element_is_an_asset_error(tmp_path):
    b = GltfBuilder()
    view = b.add_view(np.zeros(12, np.float32).tobytes(), stride=8)
    acc = b.add_accessor(view=view, component_type=5126, type="VEC3", count=2)
    with pytest.raises(AssetError, match="byteStride"):
        reader_for(b, tmp_path).accessor(acc)


# -- accessors without bufferView, sparse -----------------------------------------------------

def test_accessor_without_buffer_view_is_zeros(tmp_path):
    b = GltfBuilder()
    b.add_bytes(b"\0" * 4)
    acc = b.add_accessor(component_type=5126, type="VEC3", count=4)
    out = reader_for(b, tmp_path).accessor(acc)
    assert out.shape == (4, 3)
    assert not out.any()


def _sparse(b: GltfBuilder, idx, values, idx_dtype=np.uint16) -> dict:
    return {"count": len(idx),
            "indices": {"bufferView": b.add_view(np.asarray(idx, idx_dtype).tobytes()),
                        "componentType": {np.uint8: 5121, np.uint16: 5123, np.uint32: 5125}[idx_dtype]},
            "values": {"bufferView": b.add_view(np.ascontiguousarray(values).tobytes())}}


@pytest.mark.parametrize("idx_dtype", [np.uint8, np.uint16, np.uint32])
def test_sparse_accessor_over_a_buffer_view(tmp_path, idx_dtype):
    base = np.arange(18, dtype=np.float32).reshape(6, 3)
    new = np.array([[-1, -2, -3], [9, 9, 9]], np.float32)
    b = GltfBuilder()
    view = b.add_view(base.tobytes())
    acc = b.add_accessor(view=view, component_type=5126, type="VEC3", count=6,
                         sparse=_sparse(b, [4, 1], new, idx_dtype))
    expected = base.astype(np.float64)
    expected[4], expected[1] = new[0], new[1]
    np.testing.assert_array_equal(reader_for(b, tmp_path).accessor(acc), expected)


def test_sparse_accessor_without_buffer_view_starts_from_zeros(tmp_path):
    b = GltfBuilder()
    acc = b.add_accessor(component_type=5123, type="SCALAR", count=5, normalized=True,
                         sparse=_sparse(b, [0, 3], np.array([65535, 13107], np.uint16)))
    np.testing.assert_allclose(reader_for(b, tmp_path).accessor(acc), [1.0, 0, 0, 0.2, 0], atol=1e-12)


def test_sparse_index_out_of_range_is_an_asset_error(tmp_path):
    b = GltfBuilder()
    acc = b.add_accessor(component_type=5126, type="SCALAR", count=3,
                         sparse=_sparse(b, [3], np.array([1.0], np.float32)))
    with pytest.raises(AssetError, match="sparse index 3"):
        reader_for(b, tmp_path).accessor(acc)


def test_sparse_on_corpus_simple_sparse_accessor(corpus):
    path = corpus / "models/SimpleSparseAccessor/glTF/SimpleSparseAccessor.gltf"
    gltf, blob = _parse(path)
    pos = AccessorReader(gltf, path, blob).accessor(gltf.meshes[0].primitives[0].attributes.POSITION)
    # the base grid is x = 0..6 on rows y = 0 and y = 1; the sparse values lift vertices
    # 8, 10 and 12 to y = 2, 3, 4 (accessor max is [6, 4, 0])
    expected = np.array([[x, 0, 0] for x in range(7)] + [[x, 1, 0] for x in range(7)], np.float64)
    expected[[8, 10, 12], 1] = [2, 3, 4]
    np.testing.assert_array_equal(pos, expected)


# -- buffers: GLB, data URIs, external files --------------------------------------------------

def _one_accessor_builder(values=np.array([[1.0, 2.0, 3.0]], np.float32)):
    b = GltfBuilder()
    acc = b.add_accessor(values)
    return b, acc, values


def test_glb_binary_chunk(tmp_path):
    b, acc, values = _one_accessor_builder()
    r = reader_for(b, tmp_path, glb=True)
    np.testing.assert_array_equal(r.accessor(acc), values)
    assert r.dependencies == []


def test_data_uri_buffer(tmp_path):
    b, acc, values = _one_accessor_builder()
    r = reader_for(b, tmp_path, embed=True)
    np.testing.assert_array_equal(r.accessor(acc), values)
    assert r.dependencies == []


def test_external_bin_is_read_and_recorded(tmp_path):
    b, acc, values = _one_accessor_builder()
    r = reader_for(b, tmp_path)
    np.testing.assert_array_equal(r.accessor(acc), values)
    assert r.dependencies == [(tmp_path / "m.bin").resolve()]


def test_percent_encoded_bin_name(tmp_path):
    b, acc, values = _one_accessor_builder()
    path = b.write_gltf(tmp_path / "m.gltf", bin_name="my data.bin")
    doc = json.loads(path.read_text())
    doc["buffers"][0]["uri"] = "my%20data.bin"
    path.write_text(json.dumps(doc))
    gltf, blob = _parse(path)
    np.testing.assert_array_equal(AccessorReader(gltf, path, blob).accessor(acc), values)


def test_missing_bin_names_the_file(tmp_path):
    b, acc, _ = _one_accessor_builder()
    r = reader_for(b, tmp_path)
    (tmp_path / "m.bin").unlink()
    with pytest.raises(MissingFileError, match=r"m\.bin"):
        r.accessor(acc)


def test_uri_escaping_the_folder_is_refused(tmp_path):
    b, acc, _ = _one_accessor_builder()
    inner = tmp_path / "model"
    inner.mkdir()
    path = b.write_gltf(inner / "m.gltf", bin_name="../secret.bin")
    assert (tmp_path / "secret.bin").is_file()  # it exists: only the confinement can refuse it
    gltf, blob = _parse(path)
    with pytest.raises(AssetError, match="outside"):
        AccessorReader(gltf, path, blob).accessor(acc)


def test_git_lfs_pointer_bin_is_a_clear_error(tmp_path):
    b, acc, _ = _one_accessor_builder()
    r = reader_for(b, tmp_path)
    (tmp_path / "m.bin").write_bytes(b"version https://git-lfs.github.com/spec/v1\noid sha256:abc\nsize 12\n")
    with pytest.raises(AssetError, match="LFS"):
        r.accessor(acc)


def test_buffer_shorter_than_byte_length(tmp_path):
    b, acc, _ = _one_accessor_builder()
    r = reader_for(b, tmp_path)
    (tmp_path / "m.bin").write_bytes(b"\0" * 4)
    with pytest.raises(AssetError, match="byteLength"):
        r.accessor(acc)


def test_decode_data_uri():
    payload = bytes(range(7))
    uri = "data:application/gltf-buffer;base64," + base64.b64encode(payload).decode()
    assert decode_data_uri(uri, Path("x.gltf"), "buffer 0") == payload
    assert data_uri_mime(uri) == "application/gltf-buffer"
    assert data_uri_mime("data:image/png;base64,AAAA") == "image/png"
    with pytest.raises(AssetError, match="base64"):
        decode_data_uri("data:text/plain,hello", Path("x.gltf"), "buffer 0")


# -- EXT_meshopt_compression ------------------------------------------------------------------

def _meshopt_view(b: GltfBuilder, encoded: bytes, *, count: int, stride: int, mode: str,
                  filt: str | None = None, name: str = "EXT_meshopt_compression") -> int:
    ext = {"buffer": 0, "byteOffset": b.add_bytes(encoded), "byteLength": len(encoded),
           "byteStride": stride, "count": count, "mode": mode}
    if filt:
        ext["filter"] = filt
    view = {"buffer": 0, "byteLength": count * stride, "extensions": {name: ext}}
    if mode == "ATTRIBUTES":
        view["byteStride"] = stride
    b.doc.setdefault("bufferViews", []).append(view)
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = [name]
    return len(b.doc["bufferViews"]) - 1


@pytest.mark.parametrize("ext_name", ["EXT_meshopt_compression", "KHR_meshopt_compression"])
def test_meshopt_vertex_buffer_float32(tmp_path, ext_name):
    import meshoptimizer
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(100, 3)).astype(np.float32)
    enc = meshoptimizer.encode_vertex_buffer(pos, len(pos), 12)
    b = GltfBuilder()
    view = _meshopt_view(b, enc, count=100, stride=12, mode="ATTRIBUTES", name=ext_name)
    acc = b.add_accessor(view=view, component_type=5126, type="VEC3", count=100)
    np.testing.assert_array_equal(reader_for(b, tmp_path).accessor(acc), pos)


def test_meshopt_interleaved_vertex_buffer(tmp_path):
    import meshoptimizer
    rec = np.dtype([("p", "<i2", 4), ("n", "i1", 4), ("t", "<u2", 2)])  # 16 bytes a vertex
    rng = np.random.default_rng(2)
    v = np.zeros(37, rec)
    v["p"] = rng.integers(-32768, 32767, size=(37, 4))
    v["n"] = rng.integers(-127, 127, size=(37, 4))
    v["t"] = rng.integers(0, 65535, size=(37, 2))
    enc = meshoptimizer.encode_vertex_buffer(v.view(np.uint8).reshape(37, 16), 37, 16)
    b = GltfBuilder()
    view = _meshopt_view(b, enc, count=37, stride=16, mode="ATTRIBUTES")
    a_p = b.add_accessor(view=view, component_type=5122, type="VEC3", count=37)
    a_n = b.add_accessor(view=view, byte_offset=8, component_type=5120, type="VEC3", count=37, normalized=True)
    a_t = b.add_accessor(view=view, byte_offset=12, component_type=5123, type="VEC2", count=37, normalized=True)
    r = reader_for(b, tmp_path)
    np.testing.assert_array_equal(r.accessor(a_p, as_float=False), v["p"][:, :3])
    np.testing.assert_allclose(r.accessor(a_n), np.maximum(v["n"][:, :3] / 127.0, -1), atol=1e-12)
    np.testing.assert_allclose(r.accessor(a_t), v["t"] / 65535.0, atol=1e-12)


@pytest.mark.parametrize("index_size", [2, 4])
def test_meshopt_index_buffer_triangles(tmp_path, index_size):
    import meshoptimizer
    # a 6x6 grid of quads: realistic triangle lists compress (and must decode) exactly
    g = np.arange(49).reshape(7, 7)
    a, b_, c, d = g[:-1, :-1].ravel(), g[:-1, 1:].ravel(), g[1:, :-1].ravel(), g[1:, 1:].ravel()
    idx = np.stack([np.stack([a, c, b_], 1), np.stack([b_, c, d], 1)], 1).reshape(-1).astype(np.uint32)
    enc = meshoptimizer.encode_index_buffer(idx, len(idx), 49)
    b = GltfBuilder()
    view = _meshopt_view(b, enc, count=len(idx), stride=index_size, mode="TRIANGLES")
    acc = b.add_accessor(view=view, component_type=5123 if index_size == 2 else 5125, type="SCALAR", count=len(idx))
    out = reader_for(b, tmp_path).accessor(acc, as_float=False)
    # the codec may rotate a triangle's vertices (same winding), so compare triangles canonically
    np.testing.assert_array_equal(_canonical(out.reshape(-1, 3)), _canonical(idx.reshape(-1, 3)))


@pytest.mark.parametrize("index_size", [2, 4])
def test_meshopt_index_sequence(tmp_path, index_size):
    import meshoptimizer
    seq = np.array([0, 1, 2, 2, 1, 3, 7, 5, 4, 100, 3, 0], np.uint32)
    enc = meshoptimizer.encode_index_sequence(seq, len(seq), 101)
    b = GltfBuilder()
    view = _meshopt_view(b, enc, count=len(seq), stride=index_size, mode="INDICES")
    acc = b.add_accessor(view=view, component_type=5123 if index_size == 2 else 5125, type="SCALAR", count=len(seq))
    np.testing.assert_array_equal(reader_for(b, tmp_path).accessor(acc, as_float=False), seq)


def test_meshopt_exponential_filter(tmp_path):
    import meshoptimizer
    # EXPONENTIAL: each 32-bit value is a signed 24-bit mantissa m and a signed 8-bit exponent e,
    # decoded as m * 2**e (meshoptimizer's reference encoding, written by hand here).
    m = np.array([[3, -5, 1, 1000], [0, 7, -1, 12345]], np.int64)
    e = np.array([[-1, 2, 0, -10], [0, -3, 4, -12]], np.int64)
    packed = ((e & 0xFF) << 24 | (m & 0xFFFFFF)).astype(np.uint32)
    enc = meshoptimizer.encode_vertex_buffer(packed.view(np.uint8).reshape(2, 16), 2, 16)
    b = GltfBuilder()
    view = _meshopt_view(b, enc, count=2, stride=16, mode="ATTRIBUTES", filt="EXPONENTIAL")
    acc = b.add_accessor(view=view, component_type=5126, type="VEC4", count=2)
    np.testing.assert_array_equal(reader_for(b, tmp_path).accessor(acc), m * np.exp2(e.astype(np.float64)))


def test_meshopt_garbage_is_an_asset_error(tmp_path):
    import meshoptimizer  # noqa: F401 (a hard dependency: a broken install fails here)
    b = GltfBuilder()
    view = _meshopt_view(b, b"\x00garbage-not-meshopt", count=10, stride=12, mode="ATTRIBUTES")
    acc = b.add_accessor(view=view, component_type=5126, type="VEC3", count=10)
    with pytest.raises(AssetError, match="does not decode"):
        reader_for(b, tmp_path).accessor(acc)


def _canonical(tris: np.ndarray) -> np.ndarray:
    """Each triangle rotated to start at its smallest index (winding kept), rows sorted."""
    tris = np.asarray(tris, np.int64)
    k = np.argmin(tris, axis=1)
    rows = np.arange(len(tris))[:, None]
    rot = tris[rows, (k[:, None] + np.arange(3)) % 3]
    return rot[np.lexsort(rot.T[::-1])]


def test_glb_round_trip_struct_layout(tmp_path):
    """The builder's GLB is well formed (guards the fixtures the other tests rely on)."""
    b, _, _ = _one_accessor_builder()
    data = b.glb_bytes()
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
