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
    (folder / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\n"
                                  "f 1 2 3\nf 2 4 3\nf 1 3 4\n")
    (folder / "m.mtl").write_text("newmtl a\nKd 1 0 0\n")
    out = tmp_path / "draws"
    out.mkdir()
    files = draw_files(folder / "m.obj", 3, out)
    assert files[0] == folder / "m.obj" and len(files) == 3
    for f in files[1:]:
        assert f.name == "m.obj" and (f.parent / "m.mtl").read_text() == "newmtl a\nKd 1 0 0\n"
        assert sorted(f.read_text().splitlines()) == sorted((folder / "m.obj").read_text().splitlines())
