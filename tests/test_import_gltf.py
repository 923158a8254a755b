"""import_gltf: topology, node flattening, files and errors, materials, morphs, corpus checks."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import numpy as np
import pytest

from assetpipe.core.errors import AssetError, InvalidGeometryError, MissingFileError, UnsupportedError
from gltf_builder import PNG_1X1, GltfBuilder
from assetpipe.pipelines.import_gltf import import_gltf, node_matrix, triangles_from_mode

TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)  # CCW seen from +z
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)


def build(b: GltfBuilder, tmp_path: Path, name: str = "m.gltf", **kw):
    path = b.write_glb(tmp_path / name) if name.endswith(".glb") else b.write_gltf(tmp_path / name, **kw)
    return import_gltf(path)


def face_normals(positions: np.ndarray, tris: np.ndarray) -> np.ndarray:
    p = positions[tris.astype(np.int64)]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def canonical(tris) -> np.ndarray:
    """Each triangle rotated to start at its smallest vertex (winding kept)."""
    tris = np.asarray(tris, np.int64)
    k = np.argmin(tris, axis=1)
    return tris[np.arange(len(tris))[:, None], (k[:, None] + np.arange(3)) % 3]


def quat_z(angle: float) -> list[float]:
    return [0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)]


# -- primitive modes ------------------------------------------------------------------------

def spec_strip(v):
    # glTF 2.0, 3.7.2.1: p_i = {v_i, v_(i+(1+i%2)), v_(i+(2-i%2))}
    return [[v[i], v[i + 1 + i % 2], v[i + 2 - i % 2]] for i in range(len(v) - 2)]


def spec_fan(v):
    # glTF 2.0: p_i = {v_(i+1), v_(i+2), v_0}
    return [[v[i + 1], v[i + 2], v[0]] for i in range(len(v) - 2)]


@pytest.mark.parametrize("n", [3, 4, 5, 8])
def test_triangles_from_mode_matches_the_spec_formulas(n):
    v = np.array([10, 11, 12, 13, 14, 15, 16, 17][:n], np.uint32)
    np.testing.assert_array_equal(canonical(triangles_from_mode(v, 5)), canonical(spec_strip(v)))
    np.testing.assert_array_equal(triangles_from_mode(v, 6), spec_fan(v))
    tri = triangles_from_mode(v, 4)
    np.testing.assert_array_equal(tri, v[: (n // 3) * 3].reshape(-1, 3))


def test_triangles_from_mode_too_few_indices():
    assert triangles_from_mode(np.array([1, 2], np.uint32), 5).shape == (0, 3)
    assert triangles_from_mode(np.array([], np.uint32), 6).shape == (0, 3)


def _zigzag(n: int) -> np.ndarray:
    """A planar strip in z=0: vertices alternate top/bottom, moving right (first triangle CCW)."""
    i = np.arange(n)
    return np.stack([i // 2, 1 - i % 2, np.zeros(n)], 1).astype(np.float32)


@pytest.mark.parametrize("indexed", [False, True])
def test_strip_keeps_a_consistent_winding(tmp_path, indexed):
    pos = _zigzag(9)
    b = GltfBuilder()
    idx = np.arange(9)[::-1].copy() if indexed else None  # reversed: every face should point -z
    b.add_node(mesh=b.add_triangles(pos, idx, mode=5))
    m = build(b, tmp_path).meshes[0]
    assert m.triangle_count == 7
    nz = face_normals(m.positions, m.indices)[:, 2]
    expected_sign = -1 if indexed else 1
    assert (np.sign(nz) == expected_sign).all(), nz
    src = idx if indexed else np.arange(9)
    np.testing.assert_array_equal(canonical(m.indices), canonical(spec_strip(src)))


@pytest.mark.parametrize("indexed", [False, True])
def test_fan(tmp_path, indexed):
    ang = np.linspace(0, 1.5 * np.pi, 6)
    pos = np.concatenate([[[0, 0, 0]], np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1)]).astype(np.float32)
    idx = np.array([0, 1, 2, 3, 4, 5, 6]) if indexed else None
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(pos, idx, mode=6))
    m = build(b, tmp_path).meshes[0]
    np.testing.assert_array_equal(m.indices, spec_fan(np.arange(7)))
    assert m.indices.dtype == np.uint32
    assert (face_normals(m.positions, m.indices)[:, 2] > 0).all()


def test_triangles_without_indices(tmp_path):
    pos = np.concatenate([TRI, TRI + 5])
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(pos))
    m = build(b, tmp_path).meshes[0]
    np.testing.assert_array_equal(m.indices, [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(m.positions, pos)
    assert m.positions.dtype == np.float64


@pytest.mark.parametrize("mode, name", [(0, "POINTS"), (1, "LINES"), (2, "LINE_LOOP"), (3, "LINE_STRIP")])
def test_points_and_lines_are_skipped_with_a_warning(tmp_path, mode, name):
    b = GltfBuilder()
    lines = b.add_triangles(QUAD, mode=mode)
    tris = b.add_triangles(TRI)
    b.add_node(mesh=lines)
    b.add_node(mesh=tris)
    model = build(b, tmp_path)
    assert [m.name for m in model.meshes] == ["mesh-1-0"]
    assert any(name in w and "mesh 0 primitive 0" in w for w in model.warnings), model.warnings


@pytest.mark.parametrize("n", list(range(16)))
def test_corpus_primitive_modes(corpus, n):
    path = corpus / f"models/Mesh_PrimitiveMode/Mesh_PrimitiveMode/Mesh_PrimitiveMode_{n:02d}.gltf"
    doc = json.loads(path.read_text())
    mode = doc["meshes"][0]["primitives"][0].get("mode", 4)
    model = import_gltf(path)
    if mode in (4, 5, 6):
        (m,) = model.meshes
        assert m.triangle_count == 2
        # every sample is a unit quad in z=0 facing +z: two triangles of area 0.5, both front
        fn = face_normals(m.positions, m.indices)
        np.testing.assert_allclose(fn[:, 2], [1.0, 1.0], atol=1e-6)
    else:
        assert model.meshes == ()
        assert any(["POINTS", "LINES", "LINE_LOOP", "LINE_STRIP"][mode] in w for w in model.warnings)


# -- nodes ----------------------------------------------------------------------------------

class _Node:
    def __init__(self, **kw):
        self.matrix = kw.get("matrix")
        self.translation = kw.get("translation")
        self.rotation = kw.get("rotation")
        self.scale = kw.get("scale")


def test_node_matrix_trs_equals_matrix():
    t, q, s = [1.0, -2.0, 3.0], [0.2, -0.4, 0.1, 0.8], [2.0, 0.5, -3.0]
    qn = np.array(q) / np.linalg.norm(q)
    x, y, z, w = qn
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    expected = np.eye(4)
    expected[:3, :3] = r @ np.diag(s)
    expected[:3, 3] = t
    trs = node_matrix(_Node(translation=t, rotation=list(qn), scale=s))
    np.testing.assert_allclose(trs, expected, atol=1e-12)
    column_major = list(expected.T.reshape(-1))
    np.testing.assert_allclose(node_matrix(_Node(matrix=column_major)), expected, atol=1e-12)
    np.testing.assert_array_equal(node_matrix(_Node()), np.eye(4))


def test_trs_node_and_matrix_node_place_the_same_vertices(tmp_path):
    t, q, s = [1.0, 2.0, 3.0], quat_z(math.pi / 2), [2.0, 3.0, 4.0]
    b = GltfBuilder()
    mesh = b.add_triangles(TRI)
    b.add_node(mesh=mesh, translation=t, rotation=q, scale=s)
    # the same transform written as a column-major matrix: x -> 2*(0,1,0), y -> 3*(-1,0,0)
    b.add_node(mesh=mesh, matrix=[0, 2, 0, 0, -3, 0, 0, 0, 0, 0, 4, 0, 1, 2, 3, 1])
    a, c = build(b, tmp_path).meshes
    expected = np.array([[1, 2, 3], [1, 4, 3], [-2, 2, 3]], np.float64)
    np.testing.assert_allclose(a.positions, expected, atol=1e-12)
    np.testing.assert_allclose(c.positions, expected, atol=1e-12)


def test_three_level_hierarchy_is_flattened(tmp_path):
    b = GltfBuilder()
    mesh = b.add_triangles(TRI)
    leaf = b.add_node(root=False, mesh=mesh, scale=[2, 2, 2])
    mid = b.add_node(root=False, children=[leaf], rotation=quat_z(math.pi / 2), mesh=mesh)
    b.add_node(children=[mid], translation=[10, 0, 0])
    model = build(b, tmp_path)
    assert [m.name for m in model.meshes] == ["mesh-0-0", "mesh-0-0-n1"]  # depth-first: mid, then leaf
    mid_m, leaf_m = model.meshes
    # root T(10,0,0) * mid Rz(90) (* leaf S(2))
    np.testing.assert_allclose(mid_m.positions, [[10, 0, 0], [10, 1, 0], [9, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(leaf_m.positions, [[10, 0, 0], [10, 2, 0], [8, 0, 0]], atol=1e-12)


def test_mesh_used_by_two_nodes_appears_twice(tmp_path):
    b = GltfBuilder()
    m0 = b.add_triangles(TRI)
    m1 = b.add_mesh([{"attributes": {"POSITION": b.doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]}},
                     {"attributes": {"POSITION": b.add_accessor(QUAD)}, "indices": b.add_accessor(np.array([0, 1, 2, 0, 2, 3], np.uint16))}])
    b.add_node(mesh=m1)
    b.add_node(mesh=m0, translation=[0, 0, 5])
    b.add_node(mesh=m1, translation=[7, 0, 0])
    model = build(b, tmp_path)
    assert [m.name for m in model.meshes] == ["mesh-1-0", "mesh-1-1", "mesh-0-0", "mesh-1-0-n1", "mesh-1-1-n1"]
    by = {m.name: m for m in model.meshes}
    np.testing.assert_allclose(by["mesh-1-1-n1"].positions, QUAD + [7, 0, 0])
    np.testing.assert_allclose(by["mesh-1-1"].positions, QUAD)
    np.testing.assert_allclose(by["mesh-0-0"].positions, TRI + [0, 0, 5])
    np.testing.assert_array_equal(by["mesh-1-1-n1"].indices, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("scale", [[-1, 1, 1], [1, -2, 1], [-1, -1, -1], [1, 1, 1], [-1, -1, 1]])
def test_mirrored_node_keeps_front_faces_front(tmp_path, scale):
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    tangents = np.tile([1.0, 0.0, 0.0, 1.0], (3, 1))
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, NORMAL=normals, TANGENT=tangents),
               scale=scale, rotation=quat_z(0.3))
    m = build(b, tmp_path).meshes[0]
    world = node_matrix(_Node(scale=scale, rotation=quat_z(0.3)))[:3, :3]
    n_expected = np.linalg.inv(world).T @ [0, 0, 1]
    n_expected /= np.linalg.norm(n_expected)
    geo = face_normals(m.positions, m.indices)[0]
    geo /= np.linalg.norm(geo)
    np.testing.assert_allclose(geo, n_expected, atol=1e-9)  # winding agrees with the normal
    np.testing.assert_allclose(m.normals, np.tile(n_expected, (3, 1)), atol=1e-6)
    # the bitangent cross(n, t) * w is the transformed original bitangent (0, 1, 0)
    bt = np.cross(m.normals[0], m.tangents[0, :3]) * m.tangents[0, 3]
    bt_expected = world @ [0, 1, 0]
    np.testing.assert_allclose(bt, bt_expected / np.linalg.norm(bt_expected), atol=1e-6)


@pytest.mark.timeout(10)
@pytest.mark.parametrize("children", [{0: [0]}, {0: [1], 1: [2], 2: [0]}])
def test_node_cycle_is_an_asset_error(tmp_path, children):
    b = GltfBuilder()
    mesh = b.add_triangles(TRI)
    for i in range(len(children)):
        b.add_node(root=(i == 0), mesh=mesh)
    for i, c in children.items():
        b.doc["nodes"][i]["children"] = c
    with pytest.raises(AssetError, match="cycle"):
        build(b, tmp_path)


@pytest.mark.timeout(10)
def test_node_cycle_without_scenes_is_an_asset_error(tmp_path):
    b = GltfBuilder()
    mesh = b.add_triangles(TRI)
    b.add_node(root=False, mesh=mesh, children=[1])
    b.add_node(root=False, mesh=mesh, children=[0])
    with pytest.raises(AssetError, match="cycle"):
        build(b, tmp_path)


def test_shared_subtree_is_placed_under_each_parent(tmp_path):
    b = GltfBuilder()
    shared = b.add_node(root=False, mesh=b.add_triangles(TRI), translation=[0, 0, 1])
    b.add_node(children=[shared], translation=[1, 0, 0])
    b.add_node(children=[shared], translation=[2, 0, 0])
    a, c = build(b, tmp_path).meshes
    np.testing.assert_allclose(a.positions, TRI + [1, 0, 1])
    np.testing.assert_allclose(c.positions, TRI + [2, 0, 1])
    assert c.name == "mesh-0-0-n1"


def test_missing_node_is_an_asset_error(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI), children=[5])
    with pytest.raises(AssetError, match="node 5"):
        build(b, tmp_path)


def test_without_scenes_the_parentless_nodes_are_roots(tmp_path):
    b = GltfBuilder()
    mesh = b.add_triangles(TRI)
    child = b.add_node(root=False, mesh=mesh, translation=[0, 1, 0])
    b.add_node(root=False, mesh=mesh, children=[child], translation=[1, 0, 0])
    model = build(b, tmp_path)
    assert [m.name for m in model.meshes] == ["mesh-0-0", "mesh-0-0-n1"]
    np.testing.assert_allclose(model.meshes[0].positions, TRI + [1, 0, 0])
    np.testing.assert_allclose(model.meshes[1].positions, TRI + [1, 1, 0])


def test_only_the_default_scene_is_built(tmp_path):
    b = GltfBuilder()
    mesh = b.add_triangles(TRI)
    b.add_node(mesh=mesh)
    other = b.add_node(root=False, mesh=mesh, translation=[9, 9, 9])
    b.doc["scenes"].append({"nodes": [other]})
    b.doc["scene"] = 1
    (m,) = build(b, tmp_path).meshes
    np.testing.assert_allclose(m.positions, TRI + 9)


def test_quantized_int16_positions_with_node_scale(tmp_path):
    """KHR_mesh_quantization: integer positions, dequantized by the node's scale/translation."""
    q = np.array([[0, 0, 0], [32767, 0, 0], [0, -32767, 100]], np.int16)
    b = GltfBuilder()
    pos = b.add_accessor(q)
    normals = b.add_accessor(np.array([[0, 0, 127]] * 3, np.int8), normalized=True)
    b.add_node(mesh=b.add_mesh([{"attributes": {"POSITION": pos, "NORMAL": normals}}]),
               scale=[1 / 32767] * 3, translation=[1, 2, 3])
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    m = build(b, tmp_path).meshes[0]
    np.testing.assert_allclose(m.positions, q / 32767 + [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(m.normals, [[0, 0, 1]] * 3, atol=1e-7)


def test_normalized_int16_positions(tmp_path):
    q = np.array([[-32768, 0, 0], [32767, 0, 0], [0, 16384, 0]], np.int16)
    b = GltfBuilder()
    b.add_node(mesh=b.add_mesh([{"attributes": {"POSITION": b.add_accessor(q, normalized=True)}}]), scale=[4, 4, 4])
    m = build(b, tmp_path).meshes[0]
    np.testing.assert_allclose(m.positions, 4 * np.maximum(q / 32767.0, -1), atol=1e-12)


# -- containers, buffers and errors -----------------------------------------------------------

def _textured_builder(image: dict | None = None, tex_coord: int = 0) -> GltfBuilder:
    b = GltfBuilder()
    uv = np.array([[0, 0], [1, 0], [0, 1]], np.float32)
    b.doc["images"] = [image or {"uri": "tex.png"}]
    b.doc["textures"] = [{"source": 0}]
    mat = b.add_material(pbrMetallicRoughness={"baseColorTexture": {"index": 0, "texCoord": tex_coord}})
    b.add_node(mesh=b.add_triangles(TRI, material=mat, TEXCOORD_0=uv, TEXCOORD_1=uv * 2))
    return b


def test_glb_with_image_in_a_buffer_view(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, material=b.add_material(
        pbrMetallicRoughness={"baseColorTexture": {"index": b.add_texture(data=PNG_1X1)}})))
    model = build(b, tmp_path, "m.glb")
    tex = model.materials[0].base_color_texture
    assert tex.image.data == PNG_1X1 and tex.image.mime == "image/png"
    np.testing.assert_allclose(model.meshes[0].positions, TRI)
    assert model.dependencies == ()


def test_data_uri_buffer_and_image(tmp_path):
    b = _textured_builder({"uri": "data:image/png;base64," + base64.b64encode(PNG_1X1).decode()})
    model = build(b, tmp_path, embed=True)
    assert model.materials[0].base_color_texture.image.data == PNG_1X1
    np.testing.assert_allclose(model.meshes[0].positions, TRI)
    assert model.dependencies == ()
    assert list(tmp_path.iterdir()) == [tmp_path / "m.gltf"]


def test_external_bin_and_image_are_dependencies(tmp_path):
    (tmp_path / "tex.png").write_bytes(PNG_1X1)
    model = build(_textured_builder(), tmp_path)
    assert set(model.dependencies) == {(tmp_path / "m.bin").resolve(), (tmp_path / "tex.png").resolve()}
    assert model.materials[0].base_color_texture.image.data == PNG_1X1


def test_missing_bin_is_a_missing_file_error_naming_it(tmp_path):
    b = _textured_builder()
    path = b.write_gltf(tmp_path / "m.gltf", bin_name="geometry.bin")
    (tmp_path / "geometry.bin").unlink()
    with pytest.raises(MissingFileError, match=r"geometry\.bin"):
        import_gltf(path)


def test_corpus_missing_bin(corpus):
    with pytest.raises(MissingFileError, match=r"BoxTextured0\.bin") as err:
        import_gltf(corpus / "nasty/MissingBin/BoxTextured.gltf")
    assert "BoxTextured.gltf" in str(err.value)


def test_buffer_uri_escaping_the_folder_is_refused(tmp_path):
    inner = tmp_path / "inner"
    inner.mkdir()
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI))
    path = b.write_gltf(inner / "m.gltf", bin_name="../secret.bin")
    with pytest.raises(AssetError, match="outside"):
        import_gltf(path)


def test_image_uri_escaping_the_folder_is_refused(tmp_path):
    inner = tmp_path / "inner"
    inner.mkdir()
    (tmp_path / "secret.png").write_bytes(PNG_1X1)
    b = _textured_builder({"uri": "../secret.png"})
    with pytest.raises(AssetError, match="outside"):
        build(b, inner)


def test_git_lfs_pointer_is_a_clear_error(tmp_path, corpus):
    with pytest.raises(AssetError, match="Git LFS"):
        import_gltf(corpus / "nasty/Fox-lfs-pointer/Fox.glb")
    p = tmp_path / "x.gltf"
    p.write_text("version https://git-lfs.github.com/spec/v1\noid sha256:00\nsize 5\n")
    with pytest.raises(AssetError, match="Git LFS"):
        import_gltf(p)


@pytest.mark.parametrize("cut", [10, 19, 40, -4])
def test_truncated_glb_is_a_clear_error(tmp_path, cut):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI))
    data = b.glb_bytes()
    p = tmp_path / "t.glb"
    p.write_bytes(data[:cut])
    with pytest.raises(AssetError, match="truncated") as err:
        import_gltf(p)
    assert "t.glb" in str(err.value)


def test_glb_without_magic(tmp_path):
    p = tmp_path / "x.glb"
    p.write_bytes(b"\0" * 64)
    with pytest.raises(AssetError, match="GLB"):
        import_gltf(p)


@pytest.mark.parametrize("text, match", [
    ("{not json", "JSON"),
    ("\xff\xfe garbage", "JSON"),
    ("[1, 2, 3]", "asset"),
    ('{"meshes": []}', "asset"),
])
def test_garbage_json_is_a_clear_error(tmp_path, text, match):
    p = tmp_path / "g.gltf"
    p.write_bytes(text.encode("latin-1"))
    with pytest.raises(AssetError, match=match) as err:
        import_gltf(p)
    assert "g.gltf" in str(err.value)


def test_gltf_1_is_unsupported(tmp_path):
    p = tmp_path / "old.gltf"
    p.write_text('{"asset": {"version": "1.0"}}')
    with pytest.raises(UnsupportedError, match="1.0"):
        import_gltf(p)


def test_missing_file(tmp_path):
    with pytest.raises(AssetError, match="not found"):
        import_gltf(tmp_path / "nope.gltf")


def test_unsupported_required_extension_is_named(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI))
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["KHR_texture_transform", "EXT_fancy_thing"]
    with pytest.raises(UnsupportedError, match="EXT_fancy_thing") as err:
        build(b, tmp_path)
    assert "KHR_texture_transform" not in str(err.value)


def test_unsupported_used_but_not_required_extension_is_fine(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI))
    b.doc["extensionsUsed"] = ["EXT_fancy_thing"]
    assert len(build(b, tmp_path).meshes) == 1


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_positions_are_invalid_geometry(tmp_path, bad):
    pos = TRI.copy()
    pos[1, 2] = bad
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(pos))
    with pytest.raises(InvalidGeometryError, match="NaN or infinite"):
        build(b, tmp_path)


@pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")
def test_positions_overflowing_under_the_node_transform(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI * 3e38), scale=[1e300, 1e300, 1e300])
    with pytest.raises(InvalidGeometryError, match='positions are non-finite or beyond'):
        build(b, tmp_path)


def test_corpus_infinites(corpus):
    with pytest.raises(InvalidGeometryError, match="BoxWithInfinites.glb"):
        import_gltf(corpus / "nasty/BoxWithInfinites/BoxWithInfinites.glb")


def test_index_out_of_range_is_invalid_geometry(tmp_path, corpus):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, [0, 1, 3]))
    with pytest.raises(InvalidGeometryError, match="index 3 is out of range"):
        build(b, tmp_path)
    with pytest.raises(InvalidGeometryError, match="out of range"):
        import_gltf(corpus / "nasty/IndexOutOfRange/IndexOutOfRange.gltf")


def test_attribute_count_mismatch(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, NORMAL=np.zeros((2, 3))))
    with pytest.raises(AssetError, match="NORMAL"):
        build(b, tmp_path)


# -- materials ------------------------------------------------------------------------------

def test_base_color_factor_and_texture_with_tex_coord_1(tmp_path):
    (tmp_path / "tex.png").write_bytes(PNG_1X1)
    b = _textured_builder(tex_coord=1)
    b.doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = [0.5, 0.25, 1.0, 0.75]
    b.doc["materials"][0]["name"] = "painted"
    model = build(b, tmp_path)
    mat = model.materials[0]
    assert mat.name == "painted"
    assert mat.base_color_factor == (0.5, 0.25, 1.0, 0.75)
    assert mat.base_color_texture.tex_coord == 1
    m = model.meshes[0]
    assert m.material == 0
    np.testing.assert_allclose(m.uv0, [[0, 0], [1, 0], [0, 1]])
    np.testing.assert_allclose(m.uv1, [[0, 0], [2, 0], [0, 2]])
    assert m.uv0.dtype == np.float32 and m.uv1.dtype == np.float32


def test_mesh_without_material_uses_minus_one(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI))
    model = build(b, tmp_path)
    assert model.meshes[0].material == -1 and model.materials == ()


def _uv_after_transform(tmp_path, tt: dict, uvs, *, tex_coord: int = 0):
    (tmp_path / "tex.png").write_bytes(PNG_1X1)
    b = GltfBuilder()
    b.doc["images"] = [{"uri": "tex.png"}]
    b.doc["textures"] = [{"source": 0}]
    info = {"index": 0, "texCoord": tex_coord, "extensions": {"KHR_texture_transform": tt}}
    mat = b.add_material(pbrMetallicRoughness={"baseColorTexture": info})
    uvs = np.asarray(uvs, np.float32)
    b.add_node(mesh=b.add_triangles(TRI, material=mat, TEXCOORD_0=uvs, TEXCOORD_1=uvs))
    b.doc["extensionsUsed"] = ["KHR_texture_transform"]
    return build(b, tmp_path)


def test_texture_transform_offset_scale(tmp_path):
    model = _uv_after_transform(tmp_path, {"offset": [0.5, -0.25], "scale": [2, 3]},
                                [[0, 0], [1, 1], [0.25, 0.5]])
    np.testing.assert_allclose(model.meshes[0].uv0, [[0.5, -0.25], [2.5, 2.75], [1.0, 1.25]], atol=1e-6)
    np.testing.assert_allclose(model.meshes[0].uv1, [[0, 0], [1, 1], [0.25, 0.5]])  # set 1 untouched


def test_texture_transform_rotation(tmp_path):
    """Rotation as implementations and the TextureTransformTest sample apply it (KhronosGroup/glTF#1563):
    u' = cos r * u + sin r * v, v' = -sin r * u + cos r * v (after scale, before offset)."""
    r = 0.3
    model = _uv_after_transform(tmp_path, {"offset": [0.1, 0.2], "rotation": r, "scale": [2, 1]},
                                [[1, 0], [0, 1], [0.5, 0.5]])
    c, s = math.cos(r), math.sin(r)
    expected = [[0.1 + 2 * c, 0.2 - 2 * s], [0.1 + s, 0.2 + c], [0.1 + c + 0.5 * s, 0.2 - s + 0.5 * c]]
    np.testing.assert_allclose(model.meshes[0].uv0, expected, atol=1e-6)


def test_texture_transform_tex_coord_override(tmp_path):
    model = _uv_after_transform(tmp_path, {"offset": [1, 0], "texCoord": 1}, [[0, 0], [1, 1], [0, 1]])
    assert model.materials[0].base_color_texture.tex_coord == 1
    np.testing.assert_allclose(model.meshes[0].uv0, [[0, 0], [1, 1], [0, 1]])
    np.testing.assert_allclose(model.meshes[0].uv1, [[1, 0], [2, 1], [1, 1]])


def test_corpus_texture_transform_arrows_point_at_the_correct_markers(corpus):
    """In TextureTransformTest the arrow tip (texture uv (0.778, 0.778), where the 'not supported'
    markers sit) must land on the green 'correct' marker of the Rotation and Scale quads."""
    path = corpus / "models/TextureTransformTest/glTF/TextureTransformTest.gltf"
    doc = json.loads(path.read_text())
    model = import_gltf(path)
    by_mat = {}
    for m in model.meshes:
        by_mat.setdefault(doc["materials"][m.material]["name"], []).append(m)
    markers = [m.positions.mean(axis=0) for m in by_mat["Correct"]]
    for quad_name in ("Rotation", "Scale"):
        (quad,) = by_mat[quad_name]
        # uv is affine in position on the quad: fit it, then evaluate at the nearest correct marker
        a = np.hstack([quad.positions[:, :2], np.ones((quad.vertex_count, 1))])
        coef, *_ = np.linalg.lstsq(a, quad.uv0.astype(np.float64), rcond=None)
        centre = quad.positions.mean(axis=0)
        marker = min(markers, key=lambda p: np.linalg.norm(p[:2] - centre[:2]))
        uv = np.array([*marker[:2], 1.0]) @ coef
        np.testing.assert_allclose(uv, [0.778, 0.778], atol=2e-3, err_msg=quad_name)


def test_spec_gloss_diffuse_becomes_base_colour(tmp_path):
    (tmp_path / "diffuse.png").write_bytes(PNG_1X1)
    b = GltfBuilder()
    b.doc["images"] = [{"uri": "diffuse.png"}]
    b.doc["textures"] = [{"source": 0}]
    b.add_material(extensions={"KHR_materials_pbrSpecularGlossiness": {
        "diffuseFactor": [0.1, 0.2, 0.3, 0.4], "diffuseTexture": {"index": 0, "texCoord": 1},
        "specularFactor": [1, 1, 1], "glossinessFactor": 0.5}})
    b.add_node(mesh=b.add_triangles(TRI, material=0))
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["KHR_materials_pbrSpecularGlossiness"]
    mat = build(b, tmp_path).materials[0]
    assert mat.base_color_factor == (0.1, 0.2, 0.3, 0.4)
    assert mat.base_color_texture.image.data == PNG_1X1
    assert mat.base_color_texture.tex_coord == 1


def test_sampler_and_alpha_settings_are_carried(tmp_path):
    (tmp_path / "tex.png").write_bytes(PNG_1X1)
    b = GltfBuilder()
    tex = b.add_texture(uri="tex.png", sampler={"magFilter": 9728, "minFilter": 9986, "wrapS": 33071, "wrapT": 33648})
    plain = b.add_texture(uri="tex.png")
    m_mask = b.add_material(pbrMetallicRoughness={"baseColorTexture": {"index": tex}, "metallicFactor": 0.25,
                                                  "roughnessFactor": 0.75},
                            alphaMode="MASK", alphaCutoff=0.3, doubleSided=True,
                            normalTexture={"index": plain}, emissiveFactor=[1, 0.5, 0])
    m_blend = b.add_material(alphaMode="BLEND")
    m_default = b.add_material()
    for mi in (m_mask, m_blend, m_default):
        b.add_node(mesh=b.add_triangles(TRI, material=mi))
    mask, blend, default = build(b, tmp_path).materials
    s = mask.base_color_texture.sampler
    assert (s.mag_filter, s.min_filter, s.wrap_s, s.wrap_t) == (9728, 9986, 33071, 33648)
    ns = mask.normal_texture.sampler
    assert (ns.mag_filter, ns.min_filter, ns.wrap_s, ns.wrap_t) == (None, None, 10497, 10497)
    assert (mask.alpha_mode, mask.alpha_cutoff, mask.double_sided) == ("MASK", pytest.approx(0.3), True)
    assert (mask.metallic_factor, mask.roughness_factor) == (0.25, 0.75)
    assert mask.emissive_factor == (1.0, 0.5, 0.0)
    assert blend.alpha_mode == "BLEND" and not blend.double_sided
    assert (default.alpha_mode, default.alpha_cutoff, default.double_sided) == ("OPAQUE", 0.5, False)
    assert default.base_color_factor == (1.0, 1.0, 1.0, 1.0)
    assert (default.metallic_factor, default.roughness_factor) == (1.0, 1.0)
    # two images over one file: recognised as the same content
    assert mask.base_color_texture.image.digest == mask.normal_texture.image.digest


def test_missing_image_is_a_warning_not_an_error(tmp_path):
    model = build(_textured_builder(), tmp_path)  # tex.png never written
    assert model.materials[0].base_color_texture is None
    assert any("tex.png" in w for w in model.warnings), model.warnings
    assert len(model.meshes) == 1


def test_corpus_missing_textures_are_warnings(corpus):
    model = import_gltf(corpus / "nasty/FlightHelmet-missing-textures/glTF/FlightHelmet.gltf")
    missing = ["FlightHelmet_occlusionRoughnessMetallic.png", "FlightHelmet_baseColor1.png",
               "FlightHelmet_normal1.png", "FlightHelmet_occlusionRoughnessMetallic4.png"]
    for name in missing:
        assert any(name in w for w in model.warnings), name
    assert sum(m.triangle_count for m in model.meshes) == 94722
    assert model.materials[0].base_color_texture is not None


# -- morph targets, skins, vertex colours ---------------------------------------------------

@pytest.mark.parametrize("node_weights", [None, [0.0, 1.0]])
def test_morph_targets_default_weights_applied_with_warning(tmp_path, node_weights):
    b = GltfBuilder()
    pos = b.add_accessor(TRI)
    t0 = b.add_accessor(np.array([[0, 0, 1]] * 3, np.float32))
    t1 = b.add_accessor(np.array([[1, 0, 0], [0, 0, 0], [0, 2, 0]], np.float32))
    mesh = b.add_mesh([{"attributes": {"POSITION": pos}, "targets": [{"POSITION": t0}, {"POSITION": t1}]}],
                      weights=[0.5, 0.25])
    b.add_node(mesh=mesh, weights=node_weights)
    model = build(b, tmp_path)
    w = node_weights or [0.5, 0.25]
    expected = TRI + w[0] * np.array([[0, 0, 1]] * 3) + w[1] * np.array([[1, 0, 0], [0, 0, 0], [0, 2, 0]])
    np.testing.assert_allclose(model.meshes[0].positions, expected, atol=1e-12)
    assert any("morph target" in x for x in model.warnings)


def test_morphed_mesh_placed_by_nodes_with_different_weights(tmp_path):
    b = GltfBuilder()
    pos = b.add_accessor(TRI)
    t0 = b.add_accessor(np.array([[0, 0, 1]] * 3, np.float32))
    mesh = b.add_mesh([{"attributes": {"POSITION": pos}, "targets": [{"POSITION": t0}]}], weights=[0.0])
    b.add_node(mesh=mesh, weights=[1.0])
    b.add_node(mesh=mesh, weights=[3.0])
    b.add_node(mesh=mesh)
    a, c, d = build(b, tmp_path).meshes
    np.testing.assert_allclose(a.positions[:, 2], [1, 1, 1])
    np.testing.assert_allclose(c.positions[:, 2], [3, 3, 3])
    np.testing.assert_allclose(d.positions[:, 2], [0, 0, 0])
    assert [m.name for m in (a, c, d)] == ["mesh-0-0", "mesh-0-0-n1", "mesh-0-0-n2"]


def test_corpus_animated_morph_cube_warns(corpus):
    model = import_gltf(corpus / "models/AnimatedMorphCube/glTF/AnimatedMorphCube.gltf")
    assert any("morph target" in w for w in model.warnings)
    assert any("animation" in w for w in model.warnings)


def test_skin_warns_and_keeps_the_bind_pose(tmp_path):
    b = GltfBuilder()
    joint = b.add_node(root=False, translation=[5, 0, 0])
    b.doc["skins"] = [{"joints": [joint]}]
    b.add_node(mesh=b.add_triangles(TRI), skin=0)
    model = build(b, tmp_path)
    np.testing.assert_allclose(model.meshes[0].positions, TRI)
    assert any("skin" in w for w in model.warnings)


def test_vertex_colors_rgb_become_rgba(tmp_path):
    b = GltfBuilder()
    cols = b.add_accessor(np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8), normalized=True)
    b.add_node(mesh=b.add_mesh([{"attributes": {"POSITION": b.add_accessor(TRI), "COLOR_0": cols}}]))
    m = build(b, tmp_path).meshes[0]
    np.testing.assert_allclose(m.colors, [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]])
    assert m.colors.dtype == np.float32


def test_meshopt_compressed_primitive_imports(tmp_path):
    import meshoptimizer
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint32)
    b = GltfBuilder()
    views = []
    for enc, count, stride, mode in ((meshoptimizer.encode_vertex_buffer(pos, 4, 12), 4, 12, "ATTRIBUTES"),
                                     (meshoptimizer.encode_index_buffer(idx, 6, 4), 6, 2, "TRIANGLES")):
        ext = {"buffer": 0, "byteOffset": b.add_bytes(enc), "byteLength": len(enc), "byteStride": stride,
               "count": count, "mode": mode}
        view = {"buffer": 0, "byteLength": count * stride, "extensions": {"EXT_meshopt_compression": ext}}
        if mode == "ATTRIBUTES":
            view["byteStride"] = stride
        b.doc.setdefault("bufferViews", []).append(view)
        views.append(len(b.doc["bufferViews"]) - 1)
    p = b.add_accessor(view=views[0], component_type=5126, type="VEC3", count=4)
    i = b.add_accessor(view=views[1], component_type=5123, type="SCALAR", count=6)
    b.add_node(mesh=b.add_mesh([{"attributes": {"POSITION": p}, "indices": i}]))
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["EXT_meshopt_compression"]
    m = build(b, tmp_path).meshes[0]
    np.testing.assert_array_equal(m.positions, pos)
    np.testing.assert_array_equal(canonical(m.indices), canonical(idx.reshape(2, 3)))


# -- corpus against an independent loader (trimesh) ----------------------------------------

CORPUS_MODELS = {
    "BoxTextured": ("models/BoxTextured/glTF/BoxTextured.gltf", 12),
    "Duck": ("models/Duck/glTF/Duck.gltf", 4212),
    "2CylinderEngine": ("models/2CylinderEngine/glTF/2CylinderEngine.gltf", 121496),
    "CesiumMilkTruck": ("models/CesiumMilkTruck/glTF/CesiumMilkTruck.gltf", 3624),
    "MetalRoughSpheresNoTextures": ("models/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf", 1040409),
}


def _bounds(p: np.ndarray) -> np.ndarray:
    return np.concatenate([p.min(axis=0), p.max(axis=0)])


@pytest.mark.parametrize("name", list(CORPUS_MODELS))
def test_corpus_matches_trimesh_scene_dump(corpus, name):
    import trimesh
    from scipy.spatial import cKDTree

    rel, manifest_tris = CORPUS_MODELS[name]
    path = corpus / rel
    model = import_gltf(path)
    geoms = trimesh.load(path, force="scene", process=False).dump(concatenate=False)

    ours = np.concatenate([m.positions for m in model.meshes])
    theirs = np.concatenate([np.asarray(g.vertices, np.float64) for g in geoms])
    scale = float(np.linalg.norm(ours.max(axis=0) - ours.min(axis=0)))
    tol = 1e-6 * scale  # float32 precision of the source data, relative to the model's size

    assert sum(m.triangle_count for m in model.meshes) == sum(len(g.faces) for g in geoms) == manifest_tris
    assert len(model.meshes) == len(geoms)
    assert ours.shape == theirs.shape
    # the same vertex set, both ways
    d_ours, _ = cKDTree(theirs).query(ours)
    d_theirs, _ = cKDTree(ours).query(theirs)
    assert d_ours.max() <= tol and d_theirs.max() <= tol, (d_ours.max(), d_theirs.max(), tol)
    # the same per-mesh bounds (matched greedily: meshes may come in another order)
    left = [_bounds(np.asarray(g.vertices, np.float64)) for g in geoms]
    for m in model.meshes:
        b = _bounds(m.positions)
        k = next((k for k, t in enumerate(left) if np.abs(t - b).max() <= tol), None)
        assert k is not None, f"{m.name}: no trimesh mesh with bounds {b}"
        left.pop(k)
    # and every triangle refers to real vertices of its own mesh
    for m in model.meshes:
        assert m.indices.dtype == np.uint32 and m.indices.shape[1] == 3
        assert m.indices.size == 0 or int(m.indices.max()) < m.vertex_count


def test_corpus_mesh_names_and_instancing(corpus):
    model = import_gltf(corpus / CORPUS_MODELS["CesiumMilkTruck"][0])
    names = [m.name for m in model.meshes]
    assert len(names) == len(set(names))
    # the truck's wheels mesh is placed by two nodes
    assert any(n.endswith("-n1") for n in names)
    base = {n for n in names if not n.endswith("-n1")}
    assert {n[: -len("-n1")] for n in names if n.endswith("-n1")} <= base


def test_corpus_draco_engine(corpus):
    import DracoPy  # noqa: F401 (a hard dependency: a broken install fails here)
    model = import_gltf(corpus / "nasty/draco-2CylinderEngine/2CylinderEngine.gltf")
    assert sum(m.triangle_count for m in model.meshes) == 110336
    allpos = np.concatenate([m.positions for m in model.meshes])
    assert np.isfinite(allpos).all()
    # the MANIFEST's Draco bounds are trimesh's bogus figures (it cannot decode Draco); the
    # uncompressed engine in models/ is the same scene, up to Draco's position quantization
    plain = import_gltf(corpus / CORPUS_MODELS["2CylinderEngine"][0])
    ref = np.concatenate([m.positions for m in plain.meshes])
    np.testing.assert_allclose(allpos.min(axis=0), ref.min(axis=0), atol=0.1)
    np.testing.assert_allclose(allpos.max(axis=0), ref.max(axis=0), atol=0.1)
    assert [m.name for m in model.meshes] == [m.name for m in plain.meshes]
    for m in model.meshes:
        assert m.indices.size == 0 or int(m.indices.max()) < m.vertex_count


# -- hostile input (#13): every finding reproduced, each a clear one-line AssetError --------------

def _tri_doc(tmp_path: Path, **node) -> tuple[GltfBuilder, Path]:
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, [0, 1, 2]), **node)
    return b, b.write_gltf(tmp_path / "m.gltf")


def _edit(path: Path, edit) -> Path:
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    return path


def _one_line(err) -> str:
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(err.value.path))
    return text


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e400"])
def test_non_standard_or_overflowing_json_numbers_are_refused(tmp_path, token):
    # Python's json accepts NaN/Infinity (and reads 1e400 as inf); the build then crashed writing JSON.
    _, path = _tri_doc(tmp_path)
    path.write_text(path.read_text().replace('"version": "2.0"', f'"version": "2.0", "x": {token}'))
    with pytest.raises(AssetError, match=r"m\.gltf: has (the non-standard JSON number|the number 1e400)") as err:
        import_gltf(path)
    _one_line(err)


@pytest.mark.parametrize("array,key,value,phrase", [
    ("accessors", "byteOffset", -4, r"accessors\[0\]\.byteOffset is negative \(-4\)"),
    ("bufferViews", "byteOffset", -4, r"bufferViews\[0\]\.byteOffset is negative"),
    ("bufferViews", "buffer", None, r"bufferViews\[0\]\.buffer is null"),
    ("accessors", "count", None, r"accessors\[0\]\.count is null"),
    ("accessors", "count", -1, r"accessors\[0\]\.count is negative"),
])
def test_negative_or_null_structure_values_are_asset_errors(tmp_path, array, key, value, phrase):
    # were "internal error" (ValueError: offset must be non-negative; TypeError on None)
    _, path = _tri_doc(tmp_path)
    _edit(path, lambda d: d[array][0].__setitem__(key, value))
    with pytest.raises(AssetError, match=phrase) as err:
        import_gltf(path)
    _one_line(err)


def test_normal_on_a_vec2_accessor_and_float_vec3_indices_are_asset_errors(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, [0, 1, 2], NORMAL=np.zeros((3, 2), np.float32)))
    with pytest.raises(AssetError, match="attribute NORMAL is a VEC2 accessor, not VEC3"):
        build(b, tmp_path)
    _, path = _tri_doc(tmp_path)
    _edit(path, lambda d: d["meshes"][0]["primitives"][0].__setitem__("indices", 0))  # POSITION, float VEC3
    with pytest.raises(AssetError, match="indices accessor 0 is VEC3 of float32, not SCALAR unsigned"):
        import_gltf(path)


def test_deeply_nested_extras_is_an_asset_error_not_a_recursion_error(tmp_path):
    _, path = _tri_doc(tmp_path)
    path.write_text(path.read_text().rstrip()[:-1] + ', "extras": ' + "[" * 200_000 + "]" * 200_000 + "}")
    with pytest.raises(AssetError, match="nests its JSON deeper than can be read") as err:
        import_gltf(path)
    _one_line(err)


def test_bad_base64_buffer_says_so(tmp_path):
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, [0, 1, 2]))
    path = b.write_gltf(tmp_path / "m.gltf", embed=True)
    _edit(path, lambda d: d["buffers"][0].__setitem__("uri", "data:application/octet-stream;base64,@@@###"))
    with pytest.raises(AssetError, match="buffer 0: invalid base64 data URI"):  # was "buffer 0 has 0 bytes"
        import_gltf(path)


@pytest.mark.parametrize("node,found", [
    ({"scale": [1e300, 1e300, 1e300]}, "positions are non-finite or beyond"),
    ({"translation": [1e19, 0, 0]}, "3 of 3 positions are non-finite or beyond"),
])
def test_positions_overflowing_float32_under_the_transforms_are_refused(tmp_path, recwarn, node, found):
    # scale 1e300 overflowed to inf and crashed the build in canonical_json (traceback, exit 1)
    _, path = _tri_doc(tmp_path, **node)
    with pytest.raises(InvalidGeometryError, match=found) as err:
        import_gltf(path)
    _one_line(err)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]  # no extra lines from numpy


def test_one_position_at_3e38_is_refused_not_built_empty(tmp_path):
    # a valid float32 whose differences overflow: every triangle became "degenerate", model built empty
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(np.array([[3e38, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), [0, 1, 2]))
    with pytest.raises(InvalidGeometryError, match=r"1 of 3 positions are non-finite or beyond \+-1e\+18"):
        build(b, tmp_path)


def test_huge_declared_accessors_are_refused_before_allocating(tmp_path):
    # an accessor without a bufferView is zeros: 3e7 VEC3 built with 6.3 GB peak; 1e9 indices
    # allocated 7.8 GB before "out of memory". Both are refused from the declared counts.
    import resource
    import time

    _, path = _tri_doc(tmp_path)
    _edit(path, lambda d: d["accessors"].__setitem__(0, {"componentType": 5126, "count": 30_000_000, "type": "VEC3"}))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with pytest.raises(AssetError, match=r"need 686\.6 MiB or more decoded: over the model's memory budget of 512\.0 MiB"):
        import_gltf(path)
    _, path = _tri_doc(tmp_path)
    _edit(path, lambda d: d["accessors"].__setitem__(1, {"componentType": 5125, "count": 1_000_000_000, "type": "SCALAR"}))
    with pytest.raises(AssetError, match=r"need 7\.5 GiB or more decoded"):
        import_gltf(path)
    elapsed = time.perf_counter() - t0
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    # nothing near the declared sizes was allocated (the smaller one alone is 687 MiB decoded)
    assert grown_mb < 100, grown_mb
    assert elapsed < 5, elapsed  # was 20 s; the checks read only the JSON


def test_budgets_are_configurable(tmp_path):
    from assetpipe.pipelines.budgets import InputBudgets

    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(QUAD, [0, 1, 2, 0, 2, 3]))
    path = b.write_gltf(tmp_path / "m.gltf")
    assert len(import_gltf(path).meshes) == 1
    with pytest.raises(AssetError, match="over the triangle budget of 1"):
        import_gltf(path, InputBudgets(max_triangles=1))
    with pytest.raises(AssetError, match="over the model's memory budget of 100 bytes"):
        import_gltf(path, InputBudgets(max_model_bytes=100))
    with pytest.raises(InvalidGeometryError, match=r"beyond \+-0\.5"):
        import_gltf(path, InputBudgets(max_coordinate=0.5))


def test_shared_subtrees_are_counted_not_walked(tmp_path):
    # 24 levels of a node listing the same child twice: 2^24 placements were refused only after
    # 34 s and 738 MB (223 s under load); they are counted over the DAG and refused at once.
    import time

    b = GltfBuilder()
    mesh = b.add_triangles(TRI, [0, 1, 2])
    child = b.add_node(mesh=mesh, root=False)
    for _ in range(24):
        child = b.add_node(children=[child, child], root=False)
    b.doc["scenes"] = [{"nodes": [child]}]
    b.doc["scene"] = 0
    path = b.write_gltf(tmp_path / "m.gltf")
    t0 = time.perf_counter()
    with pytest.raises(AssetError, match="places more than 1000000 nodes"):
        import_gltf(path)
    assert time.perf_counter() - t0 < 2
    # a small shared hierarchy still builds, each placement once: 2^3 = 8 meshes
    b.doc["nodes"] = b.doc["nodes"][:4]
    b.doc["scenes"] = [{"nodes": [3]}]
    assert len(build(b, tmp_path, "small.gltf").meshes) == 8


@pytest.mark.parametrize("uri,error", [
    ("file:///etc/passwd", r"refuses the URI 'file:///etc/passwd'"),
    ("data:image/png;base64,@@@", "invalid base64 data URI"),
])
def test_one_reference_policy_for_images_and_buffers(tmp_path, uri, error):
    # an image's file:// or broken data URI warned and dropped the texture, while the same URI on a
    # buffer failed the asset: both are errors now, for both kinds
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(TRI, [0, 1, 2], material=b.add_material(
        pbrMetallicRoughness={"baseColorTexture": {"index": b.add_texture(uri=uri)}})))
    with pytest.raises(AssetError, match=error):
        build(b, tmp_path)
    _, path = _tri_doc(tmp_path)
    _edit(path, lambda d: d["buffers"][0].__setitem__("uri", uri))
    with pytest.raises(AssetError, match=error):
        import_gltf(path)
