"""benchmarks/lod_draws.py's draws: the same model with its triangles in another order, and
nothing else changed (or the benchmark would compare different models, not draws)."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from lod_draws import draw_files, permute_gltf, permute_obj  # noqa: E402


def _glb_parts(data: bytes) -> tuple[dict, bytes, int]:
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + json_len])
    at = 20 + json_len
    n = struct.unpack_from("<I", data, at)[0]
    return doc, data[at + 8:at + 8 + n], at + 8


def _triangles(doc: dict, blob: bytes) -> list[np.ndarray]:
    """Each TRIANGLES primitive's index rows (K, 3)."""
    out = []
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            acc = doc["accessors"][prim["indices"]]
            view = doc["bufferViews"][acc["bufferView"]]
            dt = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32}[acc["componentType"]]
            start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
            out.append(np.frombuffer(blob, dt, acc["count"], start).reshape(-1, 3))
    return out


@pytest.fixture
def glb(tmp_path: Path) -> Path:
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.icosphere(2), geom_name="ball")
    scene.add_geometry(trimesh.creation.cylinder(0.3, 1.0, sections=16).apply_translation([2, 0, 0]),
                       geom_name="rod")
    path = tmp_path / "two.glb"
    scene.export(str(path))
    return path


def test_a_gltf_draw_permutes_every_primitive_and_keeps_every_other_byte(glb: Path, tmp_path: Path):
    before = glb.read_bytes()
    doc, blob, blob_at = _glb_parts(before)
    copy = tmp_path / "copy.glb"
    copy.write_bytes(before)
    permute_gltf(copy, seed=1)
    after = copy.read_bytes()
    doc2, blob2, _ = _glb_parts(after)
    assert doc2 == doc and len(after) == len(before)
    old, new = _triangles(doc, blob), _triangles(doc2, blob2)
    assert len(old) == 2
    for a, b in zip(old, new):
        # the same rows (each triangle's corners and winding kept), in another order
        assert sorted(map(tuple, a.tolist())) == sorted(map(tuple, b.tolist()))
        assert not np.array_equal(a, b)
    # outside the index data nothing moved
    changed = np.flatnonzero(np.frombuffer(before, np.uint8) != np.frombuffer(after, np.uint8))
    spans = []
    for prim_rows, mesh in zip(old, doc["meshes"]):
        acc = doc["accessors"][mesh["primitives"][0]["indices"]]
        view = doc["bufferViews"][acc["bufferView"]]
        start = blob_at + view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        spans.append((start, start + prim_rows.nbytes))
    assert all(any(s <= i < e for s, e in spans) for i in changed.tolist())


def test_an_obj_draw_permutes_the_face_lines_of_each_run(tmp_path: Path):
    src = tmp_path / "m.obj"
    lines = ["mtllib m.mtl", *(f"v {i} {i % 3} {i % 5}" for i in range(12)), "usemtl a",
             *(f"f {i} {i + 1} {i + 2}" for i in range(1, 9)), "usemtl b",
             *(f"f {i + 2} {i + 1} {i}" for i in range(1, 9))]
    src.write_text("\n".join(lines) + "\n")
    dst = tmp_path / "p.obj"
    permute_obj(src, dst, seed=2)
    out = dst.read_text().splitlines()
    assert len(out) == len(lines)
    # every line that is not a face stays where it was; each run keeps its faces
    assert [x for x in out if not x.startswith("f ")] == [x for x in lines if not x.startswith("f ")]
    assert all((a.startswith("f ")) == (b.startswith("f ")) for a, b in zip(out, lines))
    run_a, run_b = slice(14, 22), slice(23, 31)
    for run in (run_a, run_b):
        assert sorted(out[run]) == sorted(lines[run]) and out[run] != lines[run]


def test_draws_keep_the_files_beside_the_model(tmp_path: Path):
    folder = tmp_path / "model"
    folder.mkdir()
    faces = "".join(f"f {a} {b} {c}\n" for a, b, c in ((1, 2, 3), (2, 4, 3), (1, 3, 4), (1, 2, 4),
                                                       (4, 3, 2), (3, 1, 2), (4, 1, 3), (2, 1, 4)))
    (folder / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\n" + faces)
    (folder / "m.mtl").write_text("newmtl a\nKd 1 0 0\n")
    out = tmp_path / "draws"
    out.mkdir()
    source = (folder / "m.obj").read_text()
    files = draw_files(folder / "m.obj", 3, out)
    assert files[0] == folder / "m.obj" and len(files) == 3
    assert (folder / "m.obj").read_text() == source  # the model itself is left as it was
    for f in files[1:]:
        assert f.name == "m.obj" and (f.parent / "m.mtl").read_text() == "newmtl a\nKd 1 0 0\n"
        assert sorted(f.read_text().splitlines()) == sorted(source.splitlines())
    assert len({f.read_text() for f in files}) == 3  # each draw its own order


def test_an_obj_draw_gathers_vertices_and_permutes_whole_groups(tmp_path: Path):
    """Exporters write each face's texture coordinates just before it: the faces of a group are
    then permuted as a whole, the vertex lines moved ahead in their order (positive indices
    keep naming the same vertices), and no face leaves its group."""
    lines = ["mtllib m.mtl", "v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "usemtl a"]
    for i in range(6):
        lines += [f"vt {i} 0", f"f 1/{i + 1} 2/{i + 1} 3/{i + 1}"]
    lines += ["usemtl b", "s 1"]
    for i in range(6, 12):
        lines += [f"vt {i} 1", f"f 2/{i + 1} 4/{i + 1} 3/{i + 1}"]
    src = tmp_path / "m.obj"
    src.write_text("\n".join(lines) + "\n")
    permute_obj(src, tmp_path / "p.obj", seed=4)
    out = (tmp_path / "p.obj").read_text().splitlines()
    first_face = next(i for i, x in enumerate(out) if x.startswith("f "))
    vertex_lines = [x for x in lines if x.split()[0] in ("v", "vt")]
    assert out[0] == "mtllib m.mtl" and out[1:1 + len(vertex_lines)] == vertex_lines
    assert all(x.split()[0] not in ("v", "vt") for x in out[first_face:])
    a_faces = [x for x in lines[5:18] if x.startswith("f ")]
    b_faces = [x for x in lines[18:] if x.startswith("f ")]
    got_a = [x for x in out[:out.index("usemtl b")] if x.startswith("f ")]
    got_b = [x for x in out[out.index("usemtl b"):] if x.startswith("f ")]
    assert sorted(got_a) == sorted(a_faces) and got_a != a_faces
    assert sorted(got_b) == sorted(b_faces) and got_b != b_faces
    assert out.index("usemtl a") < out.index(got_a[0])


def test_an_obj_with_relative_indices_keeps_its_layout(tmp_path: Path):
    run = ["f -3 -1 -2", "f -4 -3 -1", "f -2 -4 -1", "f -1 -2 -3", "f -4 -2 -3", "f -1 -4 -2"]
    lines = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "f -3 -2 -1", "v 1 1 0", *run]
    src = tmp_path / "r.obj"
    src.write_text("\n".join(lines) + "\n")
    permute_obj(src, tmp_path / "q.obj", seed=1)
    out = (tmp_path / "q.obj").read_text().splitlines()
    # a relative index counts back from the face: every line keeps its kind at its place
    assert out[:5] == lines[:5]
    assert sorted(out[5:]) == sorted(run) and out[5:] != run


def test_a_gltf_draw_handles_shared_offset_and_other_index_accessors(tmp_path: Path):
    """A .gltf with an external buffer: a uint8 accessor at a byte offset that two TRIANGLES
    primitives share (permuted once), a uint32 one (permuted), a uint16 one a LINES primitive
    reads and one a TRIANGLES and a LINES primitive share (both left alone); the JSON and every
    other byte stay as they were."""
    rng = np.random.default_rng(0)
    u8 = rng.permutation(np.arange(24, dtype=np.uint8))           # 8 triangles
    u32 = np.arange(30, dtype=np.uint32)[::-1].copy()             # 10 triangles
    lines16 = np.arange(12, dtype=np.uint16)
    shared16 = np.arange(18, dtype=np.uint16)
    blob = bytearray(b"\xee" * 8) + u8.tobytes() + bytearray(b"\xdd" * 8) \
        + u32.tobytes() + lines16.tobytes() + shared16.tobytes()
    views = [{"buffer": 0, "byteOffset": 4, "byteLength": 4 + 24},
             {"buffer": 0, "byteOffset": 40, "byteLength": 120},
             {"buffer": 0, "byteOffset": 160, "byteLength": 24},
             {"buffer": 0, "byteOffset": 184, "byteLength": 36}]
    accessors = [{"bufferView": 0, "byteOffset": 4, "componentType": 5121, "count": 24, "type": "SCALAR"},
                 {"bufferView": 1, "componentType": 5125, "count": 30, "type": "SCALAR"},
                 {"bufferView": 2, "componentType": 5123, "count": 12, "type": "SCALAR"},
                 {"bufferView": 3, "componentType": 5123, "count": 18, "type": "SCALAR"}]
    prims = [{"attributes": {}, "indices": 0}, {"attributes": {}, "indices": 0, "mode": 4},
             {"attributes": {}, "indices": 1}, {"attributes": {}, "indices": 2, "mode": 1},
             {"attributes": {}, "indices": 3}, {"attributes": {}, "indices": 3, "mode": 1}]
    doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": "m.bin", "byteLength": len(blob)}],
           "bufferViews": views, "accessors": accessors, "meshes": [{"primitives": prims}]}
    (tmp_path / "m.gltf").write_text(json.dumps(doc))
    (tmp_path / "m.bin").write_bytes(bytes(blob))
    permute_gltf(tmp_path / "m.gltf", seed=5)
    assert json.loads((tmp_path / "m.gltf").read_text()) == doc
    after = (tmp_path / "m.bin").read_bytes()
    got8 = np.frombuffer(after, np.uint8, 24, 8).reshape(-1, 3)
    got32 = np.frombuffer(after, np.uint32, 30, 40).reshape(-1, 3)
    for old, new in ((u8.reshape(-1, 3), got8), (u32.reshape(-1, 3), got32)):
        assert sorted(map(tuple, old.tolist())) == sorted(map(tuple, new.tolist()))
        assert not np.array_equal(old, new)
    assert after[:8] == blob[:8] and after[32:40] == blob[32:40] and after[160:] == blob[160:]
