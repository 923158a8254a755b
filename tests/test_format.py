"""Output encoding: seed keys and order, byte ranges, LOD placement, dtypes, bounds, determinism."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from assetpipe.format import (
    SEED_MATERIAL_KEYS, SEED_MESH_KEYS, SEED_MODEL_KEYS, OutputLod, OutputMaterial, OutputMesh,
    bounds_of, encode_model)
from assetpipe.pipelines.mesh_options import ATTRIBUTE_COMPONENTS

LAYOUT = ("position", "uv0")


def _mat(i: int, tex: str = "") -> OutputMaterial:
    return OutputMaterial(id=f"M-mat-{i}", name=f"mat{i}", color=(1.0, 0.5, 0.25, 1.0), texture_path=tex,
                          alpha_mode="OPAQUE", alpha_cutoff=0.5, double_sided=False, transparent=False)


def _mesh(mid: str, nverts: int, lod_tris: list[int], mat: str = "M-mat-0", shift: float = 0.0) -> OutputMesh:
    v = np.zeros((nverts, 5))
    v[:, 0] = np.arange(nverts) + shift
    v[:, 1] = -np.arange(nverts) * 0.5
    v[:, 2] = 1.0
    v[:, 3:] = 0.25
    lods = []
    for li, m in enumerate(lod_tris):
        idx = (np.arange(m * 3) % nverts).astype(np.uint32).reshape(m, 3)
        err = {} if li == 0 else {"simplifier": 0.01 * li, "hausdorff": 0.1 * li, "rms": 0.05 * li,
                                  "hausdorffRel": 0.001, "rmsRel": 0.0005}
        lods.append(OutputLod(indices=idx, vertex_count=nverts, error=err, switch_distance=10.0 * li))
    return OutputMesh(id=mid, name=mid.upper(), material_id=mat, vertices=v, lods=tuple(lods))


def _encode(meshes, materials=None, layout=LAYOUT, **kw):
    return encode_model("M", meshes, materials if materials is not None else [_mat(0)], layout,
                        ATTRIBUTE_COMPONENTS, stats=kw.pop("stats", {"degenerateTriangles": 0, "weldedVertices": 0}),
                        warnings=kw.pop("warnings", []), sources=kw.pop("sources", [{"path": "M.gltf", "digest": "x"}]),
                        generator="assetpipe test", **kw)


def _two_meshes():
    return [_mesh("mesh-0-0", 4, [4, 2, 1]), _mesh("mesh-1-0", 6, [5, 3], shift=10.0)]


def test_file_names_and_seed_key_sets_in_seed_order():
    files = _encode(_two_meshes(), [_mat(0, "textures/a.png"), _mat(1)])
    assert set(files) == {"M.idx", "M.vtx", "M.json", "M-mat.json", "M.asset.json"}
    model = json.loads(files["M.json"])
    assert tuple(model) == SEED_MODEL_KEYS == ("id", "meshes", "idxFilename", "vtxFilename")
    assert model["idxFilename"] == "M.idx" and model["vtxFilename"] == "M.vtx" and model["id"] == "M"
    for m in model["meshes"]:
        assert tuple(m) == SEED_MESH_KEYS == ("id", "materialId", "idxOffset", "idxSize", "vtxOffset", "vtxSize")
    mats = json.loads(files["M-mat.json"])
    assert isinstance(mats, list) and len(mats) == 2
    for m in mats:
        assert tuple(m) == SEED_MATERIAL_KEYS == ("id", "texturePath", "color")
    assert mats[0] == {"id": "M-mat-0", "texturePath": "textures/a.png", "color": [1.0, 0.5, 0.25, 1.0]}
    assert mats[1]["texturePath"] == ""
    side = json.loads(files["M.asset.json"])
    assert list(side) == ["formatVersion", "id", "generator", "vertexLayout", "bounds", "meshes",
                          "materials", "stats", "warnings", "sources"]
    assert side["formatVersion"] == 1 and side["generator"] == "assetpipe test"


def test_byte_ranges_of_meshes_and_lods():
    meshes = _two_meshes()
    files = _encode(meshes)
    model = json.loads(files["M.json"])
    side = json.loads(files["M.asset.json"])
    s0, s1 = model["meshes"]
    # LOD0 ranges first, in mesh order
    assert (s0["idxOffset"], s0["idxSize"]) == (0, 4 * 12)
    assert (s1["idxOffset"], s1["idxSize"]) == (48, 5 * 12)
    assert (s0["vtxOffset"], s0["vtxSize"]) == (0, 4 * 20)
    assert (s1["vtxOffset"], s1["vtxSize"]) == (80, 6 * 20)
    # then the coarser levels: mesh 0's LOD1, LOD2, mesh 1's LOD1
    l0 = side["meshes"][0]["lods"]
    l1 = side["meshes"][1]["lods"]
    assert [(l["level"], l["idxOffset"], l["idxSize"], l["triangles"]) for l in l0] == [
        (0, 0, 48, 4), (1, 108, 24, 2), (2, 132, 12, 1)]
    assert [(l["level"], l["idxOffset"], l["idxSize"], l["triangles"]) for l in l1] == [
        (0, 48, 60, 5), (1, 144, 36, 3)]
    assert len(files["M.idx"]) == 180 and len(files["M.vtx"]) == 200
    # lods[0] is exactly the seed range
    for seed, sm in zip(model["meshes"], side["meshes"]):
        assert (sm["lods"][0]["idxOffset"], sm["lods"][0]["idxSize"]) == (seed["idxOffset"], seed["idxSize"])
    # every range holds exactly its level's indices, local to the mesh
    idx = np.frombuffer(files["M.idx"], dtype="<u4")
    for m, sm in zip(meshes, side["meshes"]):
        for lod, rec in zip(m.lods, sm["lods"]):
            part = idx[rec["idxOffset"] // 4:(rec["idxOffset"] + rec["idxSize"]) // 4]
            np.testing.assert_array_equal(part.reshape(-1, 3), lod.indices)


def test_little_endian_float32_vertices_and_uint32_indices():
    meshes = _two_meshes()
    files = _encode(meshes)
    vtx = np.frombuffer(files["M.vtx"], dtype="<f4").reshape(-1, 5)
    np.testing.assert_array_equal(vtx[:4], meshes[0].vertices.astype(np.float32))
    np.testing.assert_array_equal(vtx[4:], meshes[1].vertices.astype(np.float32))
    # explicit little-endian bytes of the first float (x = 0.0) and second vertex x = 1.0
    assert files["M.vtx"][20:24] == b"\x00\x00\x80\x3f"
    assert files["M.idx"][4:8] == b"\x01\x00\x00\x00"
    # big-endian input arrays are converted, not copied byte for byte
    be = OutputMesh(id="mesh-0-0", name="be", material_id="M-mat-0",
                    vertices=meshes[0].vertices.astype(">f8"),
                    lods=(OutputLod(indices=meshes[0].lods[0].indices.astype(">u4"), vertex_count=4),))
    fb = _encode([be])
    assert fb["M.vtx"] == meshes[0].vertices.astype("<f4").tobytes()
    assert fb["M.idx"] == meshes[0].lods[0].indices.astype("<u4").tobytes()


def test_vertex_layout_in_sidecar():
    layout = ("position", "uv0", "normal", "tangent", "uv1", "color")
    m = OutputMesh(id="mesh-0-0", name="x", material_id="M-mat-0", vertices=np.zeros((3, 18)),
                   lods=(OutputLod(indices=np.array([[0, 1, 2]], np.uint32), vertex_count=3),))
    files = _encode([m], layout=layout)
    vl = json.loads(files["M.asset.json"])["vertexLayout"]
    assert vl == {"stride": 72, "attributes": [
        {"name": "position", "format": "float32x3", "offset": 0},
        {"name": "uv0", "format": "float32x2", "offset": 12},
        {"name": "normal", "format": "float32x3", "offset": 20},
        {"name": "tangent", "format": "float32x4", "offset": 32},
        {"name": "uv1", "format": "float32x2", "offset": 48},
        {"name": "color", "format": "float32x4", "offset": 56}]}
    assert len(files["M.vtx"]) == 3 * 72


def test_bounds_model_and_per_mesh():
    files = _encode(_two_meshes())
    side = json.loads(files["M.asset.json"])
    b0 = side["meshes"][0]["bounds"]
    assert b0["min"] == [0.0, -1.5, 1.0] and b0["max"] == [3.0, 0.0, 1.0]
    assert b0["center"] == [1.5, -0.75, 1.0]
    assert b0["radius"] == pytest.approx(math.hypot(1.5, 0.75), rel=1e-7)
    b = side["bounds"]
    assert b["min"] == [0.0, -2.5, 1.0] and b["max"] == [15.0, 0.0, 1.0]
    assert b["center"] == [7.5, -1.25, 1.0]
    assert b["radius"] == pytest.approx(math.hypot(7.5, 1.25), rel=1e-7)
    # bounds_of directly: the sphere is centred on the box and holds every point
    p = np.random.default_rng(1).normal(size=(200, 3)).astype(np.float32)
    bb = bounds_of(p)
    d = np.linalg.norm(p.astype(np.float64) - np.array(bb["center"]), axis=1)
    assert d.max() <= bb["radius"] * (1 + 1e-7) and d.max() >= bb["radius"] * (1 - 1e-7)
    assert bounds_of(np.zeros((0, 3))) == {"min": [0.0] * 3, "max": [0.0] * 3, "center": [0.0] * 3, "radius": 0.0}


def test_sidecar_mesh_and_lod_records():
    files = _encode(_two_meshes(), stats={"degenerateTriangles": 3, "weldedVertices": 7}, warnings=["w1"])
    side = json.loads(files["M.asset.json"])
    m0 = side["meshes"][0]
    assert (m0["id"], m0["name"], m0["materialId"], m0["vertexCount"], m0["triangleCount"]) == (
        "mesh-0-0", "MESH-0-0", "M-mat-0", 4, 4)
    assert m0["lods"][0]["error"] == {"simplifier": 0.0, "hausdorff": 0.0, "rms": 0.0, "hausdorffRel": 0.0,
                                      "rmsRel": 0.0, "hausdorffLowerRel": 0.0, "boundConverged": True}
    assert m0["lods"][0]["switchDistance"] == 0.0 and m0["lods"][2]["switchDistance"] == 20.0
    assert m0["lods"][1]["error"]["hausdorff"] == 0.1 and m0["lods"][1]["vertexCount"] == 4
    assert side["stats"] == {"degenerateTriangles": 3, "weldedVertices": 7}
    assert side["warnings"] == ["w1"] and side["sources"] == [{"path": "M.gltf", "digest": "x"}]
    assert side["materials"][0] == {"id": "M-mat-0", "name": "mat0", "baseColorFactor": [1.0, 0.5, 0.25, 1.0],
                                    "alphaMode": "OPAQUE", "alphaCutoff": 0.5, "doubleSided": False,
                                    "transparent": False, "textures": {}}


def test_nan_errors_are_written_as_null():
    m = _mesh("mesh-0-0", 4, [4, 2])
    lod1 = OutputLod(indices=m.lods[1].indices, vertex_count=3,
                     error={"simplifier": float("nan"), "hausdorff": 0.5, "rms": float("inf"),
                            "hausdorffRel": 0.1, "rmsRel": float("nan")},
                     switch_distance=float("nan"))
    files = _encode([OutputMesh(id=m.id, name=m.name, material_id=m.material_id, vertices=m.vertices,
                                lods=(m.lods[0], lod1))])
    text = files["M.asset.json"].decode()
    assert "NaN" not in text and "Infinity" not in text
    lod = json.loads(text)["meshes"][0]["lods"][1]
    assert lod["error"] == {"simplifier": None, "hausdorff": 0.5, "rms": None, "hausdorffRel": 0.1, "rmsRel": None}
    assert lod["switchDistance"] is None


def test_floats_rounded_to_float32_precision():
    mat = OutputMaterial(id="M-mat-0", name="m", color=(0.1, 1 / 3, 0.7, 1.0), texture_path="",
                         alpha_mode="MASK", alpha_cutoff=0.1, double_sided=True, transparent=False)
    files = _encode([_mesh("mesh-0-0", 3, [1])], [mat])
    mats = json.loads(files["M-mat.json"])
    assert mats[0]["color"] == [0.1, 0.333333333, 0.7, 1.0]


def test_deterministic_same_input_same_bytes():
    a = _encode(_two_meshes(), [_mat(0, "textures/a.png")])
    b = _encode(_two_meshes(), [_mat(0, "textures/a.png")])
    assert a == b
    assert a["M.json"].endswith(b"\n") and a["M.json"].decode("utf-8")


def test_empty_model():
    files = _encode([], [])
    assert files["M.idx"] == b"" and files["M.vtx"] == b""
    assert json.loads(files["M.json"]) == {"id": "M", "meshes": [], "idxFilename": "M.idx", "vtxFilename": "M.vtx"}
    assert json.loads(files["M-mat.json"]) == []
    side = json.loads(files["M.asset.json"])
    assert side["meshes"] == [] and side["bounds"]["radius"] == 0.0
