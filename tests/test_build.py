"""End-to-end builds through the CLI on small real models: the seed contract, the report,
determinism, and failure isolation."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from assetpipe.cli import main
from seed_loader import load_seed_model


def run_build(*args: str):
    result = CliRunner().invoke(main, ["build", *args], catch_exceptions=False)
    return result


def outputs_of(out: Path) -> list[Path]:
    """Output files (relative), without the build's own state folder."""
    return sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file() and ".assetpipe" not in p.parts)


def test_box_textured_builds_in_the_seed_layout(corpus, tmp_path):
    out = tmp_path / "out"
    r = run_build(str(corpus / "models/BoxTextured/glTF/BoxTextured.gltf"), "-o", str(out),
                  "--json", str(tmp_path / "report.json"))
    assert r.exit_code == 0, r.output
    model = load_seed_model(out / "BoxTextured.json")
    assert [m.id for m in model.meshes] == ["mesh-0-0"]
    mesh = model.meshes[0]
    assert mesh.indices.shape == (12, 3)
    assert int(mesh.indices.max()) < mesh.positions.shape[0]
    # the glTF node rotates the box; the unit cube stays a unit cube (rotation by 90 degrees)
    np.testing.assert_allclose(np.abs(mesh.positions).max(axis=0), [0.5, 0.5, 0.5], atol=1e-6)
    assert model.materials[0]["texturePath"].startswith("textures/")
    assert (out / model.materials[0]["texturePath"]).is_file()
    report = json.loads((tmp_path / "report.json").read_text())
    entry = report["assets"][0]
    assert entry["status"] == "built" and entry["id"] == "BoxTextured" and entry["error"] is None
    assert set(entry) >= {"source", "id", "status", "outputs", "warnings", "error", "seconds"}
    assert sorted(Path(p).name for p in entry["outputs"]) == sorted(
        ["BoxTextured.json", "BoxTextured-mat.json", "BoxTextured.asset.json"])


def test_sidecar_describes_layout_bounds_and_lod0(corpus, tmp_path):
    out = tmp_path / "out"
    assert run_build(str(corpus / "models/Duck/glTF/Duck.gltf"), "-o", str(out)).exit_code == 0
    side = json.loads((out / "Duck.asset.json").read_text())
    seed = json.loads((out / "Duck.json").read_text())
    assert side["formatVersion"] == 1
    assert side["vertexLayout"] == {"stride": 20, "attributes": [
        {"name": "position", "format": "float32x3", "offset": 0},
        {"name": "uv0", "format": "float32x2", "offset": 12}]}
    sm, m = side["meshes"][0], seed["meshes"][0]
    assert (sm["lods"][0]["idxOffset"], sm["lods"][0]["idxSize"]) == (m["idxOffset"], m["idxSize"])
    assert sm["vertexCount"] * 20 == m["vtxSize"] and sm["triangleCount"] * 12 == m["idxSize"]
    # bounds equal the vertex data's
    v = np.fromfile(out / "Duck.vtx", dtype="<f4").reshape(-1, 5)[:, :3]
    np.testing.assert_allclose(sm["bounds"]["min"], v.min(axis=0), rtol=1e-6)
    np.testing.assert_allclose(sm["bounds"]["max"], v.max(axis=0), rtol=1e-6)
    assert side["sources"][0]["path"] == "Duck.gltf" and side["sources"][0]["digest"].startswith("xxh3:")
    assert {s["path"] for s in side["sources"]} >= {"Duck0.bin", "DuckCM.png"}
    mat = side["materials"][0]
    assert mat["alphaMode"] == "OPAQUE" and mat["transparent"] is False
    assert mat["textures"]["baseColor"]["levels"] == 10  # 512x512 -> 10 levels


def test_outputs_are_byte_identical_across_runs(corpus, tmp_path):
    src = str(corpus / "models/CesiumMilkTruck/glTF/CesiumMilkTruck.gltf")
    assert run_build(src, "-o", str(tmp_path / "a")).exit_code == 0
    assert run_build(src, "-o", str(tmp_path / "b")).exit_code == 0
    files_a = outputs_of(tmp_path / "a")
    files_b = outputs_of(tmp_path / "b")
    assert files_a == files_b and files_a
    for rel in files_a:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def test_points_and_lines_only_models_build_empty_with_a_warning(corpus, tmp_path):
    out = tmp_path / "out"
    r = run_build(str(corpus / "models/Mesh_PrimitiveMode"), "-o", str(out), "--json", str(tmp_path / "r.json"))
    assert r.exit_code == 0, r.output
    report = {a["id"]: a for a in json.loads((tmp_path / "r.json").read_text())["assets"]}
    assert len(report) == 16
    points = report["Mesh_PrimitiveMode_00"]
    assert points["status"] == "built" and any("POINTS" in w for w in points["warnings"])
    assert load_seed_model(out / "Mesh_PrimitiveMode_00.json").meshes == []
    # strips and fans (with and without indices) give the two triangles of the quad
    for i in (4, 5, 11, 12):
        meshes = load_seed_model(out / f"Mesh_PrimitiveMode_{i:02d}.json").meshes
        assert sum(m.indices.shape[0] for m in meshes) == 2, i


def test_same_file_names_in_different_folders_get_distinct_ids(corpus, tmp_path):
    out = tmp_path / "out"
    r = run_build(str(corpus / "models/BoxTextured"), str(corpus / "models/BoxTextured-glTF-Embedded"),
                  "-o", str(out), "--json", str(tmp_path / "r.json"))
    assert r.exit_code == 0, r.output
    ids = sorted(a["id"] for a in json.loads((tmp_path / "r.json").read_text())["assets"])
    assert len(set(ids)) == 2 and all(i.endswith("BoxTextured") for i in ids)
    for i in ids:
        load_seed_model(out / f"{i}.json")


def test_a_failed_rebuild_keeps_the_earlier_outputs(corpus, tmp_path):
    src = tmp_path / "src"
    shutil.copytree(corpus / "models/BoxTextured/glTF", src)
    out = tmp_path / "out"
    assert run_build(str(src / "BoxTextured.gltf"), "-o", str(out)).exit_code == 0
    before = {p: (out / p).read_bytes() for p in outputs_of(out)}
    (src / "BoxTextured0.bin").write_bytes(b"\0" * 10)  # truncated buffer
    r = run_build(str(src / "BoxTextured.gltf"), "-o", str(out))
    assert r.exit_code == 1
    assert "BoxTextured.gltf" in r.output and "Traceback" not in r.output
    after = {p: (out / p).read_bytes() for p in outputs_of(out)}
    assert after == before
    assert not list(out.rglob("*.tmp"))


def test_cli_rejects_unknown_input_kinds(tmp_path):
    (tmp_path / "notes.txt").write_text("hi")
    r = run_build(str(tmp_path / "notes.txt"), "-o", str(tmp_path / "out"))
    assert r.exit_code != 0 and "not a model file" in r.output
    r = run_build(str(tmp_path / "missing.gltf"), "-o", str(tmp_path / "out"))
    assert r.exit_code != 0 and "no such file" in r.output


def test_inspect_reports_a_consistent_model_and_catches_corruption(corpus, tmp_path):
    out = tmp_path / "out"
    assert run_build(str(corpus / "models/Duck/glTF/Duck.gltf"), "-o", str(out)).exit_code == 0
    r = CliRunner().invoke(main, ["inspect", str(out / "Duck.json")])
    assert r.exit_code == 0 and "consistent: yes" in r.output and "4212 triangles" in r.output
    idx = np.fromfile(out / "Duck.idx", dtype="<u4")
    idx[5] = 10**6
    idx.tofile(out / "Duck.idx")
    r = CliRunner().invoke(main, ["inspect", str(out / "Duck.json")])
    assert r.exit_code == 1 and "index 1000000" in r.output


@pytest.mark.parametrize("rel", ["Duck/glTF/Duck.gltf", "CesiumMilkTruck/glTF/CesiumMilkTruck.gltf",
                                 "2CylinderEngine/glTF/2CylinderEngine.gltf", "fuze/fuze.obj"])
def test_built_positions_match_trimeshs_flattened_scene(corpus, tmp_path, rel):
    """Independent check of node flattening and triangulation on the *built* files."""
    import trimesh
    from scipy.spatial import cKDTree

    src = corpus / "models" / rel
    out = tmp_path / "out"
    assert run_build(str(src), "-o", str(out), "--no-lod", "--json", str(tmp_path / "r.json")).exit_code == 0
    entry = json.loads((tmp_path / "r.json").read_text())["assets"][0]
    model = load_seed_model(out / f"{entry['id']}.json")
    ours = np.vstack([m.positions for m in model.meshes]).astype(np.float64)
    ours_tris = sum(m.indices.shape[0] for m in model.meshes)

    scene = trimesh.load(src, force="scene", process=False)
    geoms = scene.dump(concatenate=False) if hasattr(scene, "dump") else [scene]
    ref = np.vstack([np.asarray(g.vertices, dtype=np.float64) for g in geoms])
    ref_tris = sum(len(g.faces) for g in geoms)

    diag = float(np.linalg.norm(ref.max(axis=0) - ref.min(axis=0)))
    tol = 1e-6 * diag + 1e-6
    d_ours, _ = cKDTree(ref).query(ours)
    d_ref, _ = cKDTree(ours).query(ref)
    assert d_ours.max() <= tol and d_ref.max() <= tol, (d_ours.max(), d_ref.max(), tol)
    # every source triangle is built, or counted as a dropped degenerate one
    assert ours_tris + entry["stats"]["degenerateTriangles"] == ref_tris


def test_lod_chain_in_the_built_files(corpus, tmp_path):
    out = tmp_path / "out"
    assert run_build(str(corpus / "models/Duck/glTF/Duck.gltf"), "-o", str(out)).exit_code == 0
    side = json.loads((out / "Duck.asset.json").read_text())
    idx = np.fromfile(out / "Duck.idx", dtype="<u4")
    vtx = np.fromfile(out / "Duck.vtx", dtype="<f4").reshape(-1, 5)
    mesh = side["meshes"][0]
    lods = mesh["lods"]
    assert len(lods) == 5  # ratios 1, 1/2, 1/4, 1/8, 1/16 on 4212 triangles
    tris = [l["triangles"] for l in lods]
    assert all(a > b for a, b in zip(tris, tris[1:]))
    errs = [l["error"]["hausdorffRel"] for l in lods]
    assert errs[0] == 0 and all(a <= b for a, b in zip(errs, errs[1:]))
    sw = [l["switchDistance"] for l in lods]
    assert sw[0] == 0 and all(a <= b for a, b in zip(sw, sw[1:]))
    counts = [l["vertexCount"] for l in lods]
    assert counts[0] == mesh["vertexCount"] and all(a >= b for a, b in zip(counts, counts[1:]))
    for l in lods:
        part = idx[l["idxOffset"] // 4:(l["idxOffset"] + l["idxSize"]) // 4]
        assert part.size == 3 * l["triangles"]
        assert int(part.max()) < l["vertexCount"]  # coarse levels use a prefix of the vertex range
    # the coarse levels' vertices are LOD0 vertices: no new positions
    assert np.isfinite(vtx).all()
    assert abs(lods[1]["error"]["hausdorff"] - lods[1]["error"]["hausdorffRel"] * np.linalg.norm(
        np.array(mesh["bounds"]["max"]) - mesh["bounds"]["min"])) < 1e-3 * lods[1]["error"]["hausdorff"] + 1e-9


# -- the same features on fixtures the repository holds or generates (run without the corpus) ------

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_outputs_are_byte_identical_across_runs_on_the_examples(tmp_path):
    assert run_build(str(EXAMPLES), "-o", str(tmp_path / "a"), "-j", "1").exit_code == 0
    assert run_build(str(EXAMPLES), "-o", str(tmp_path / "b"), "-j", "2").exit_code == 0
    files_a, files_b = outputs_of(tmp_path / "a"), outputs_of(tmp_path / "b")
    assert files_a == files_b and any(p.suffix == ".ktx2" for p in files_a)
    for rel in files_a:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def test_points_and_lines_only_models_build_empty_with_a_warning_generated(tmp_path):
    from gltf_builder import GltfBuilder

    quad = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    (tmp_path / "src").mkdir()
    for name, mode in (("points", 0), ("lines", 1), ("strip", 5)):
        b = GltfBuilder()
        b.add_node(mesh=b.add_mesh([{"attributes": {"POSITION": b.add_accessor(quad)}, "mode": mode}]))
        b.write_gltf(tmp_path / "src" / f"{name}.gltf")
    out = tmp_path / "out"
    r = run_build(str(tmp_path / "src"), "-o", str(out), "--json", str(tmp_path / "r.json"))
    assert r.exit_code == 0, r.output
    report = {a["id"]: a for a in json.loads((tmp_path / "r.json").read_text())["assets"]}
    for name, word in (("points", "POINTS"), ("lines", "LINES")):
        assert report[name]["status"] == "built" and any(word in w for w in report[name]["warnings"]), report[name]
        assert load_seed_model(out / f"{name}.json").meshes == []
    assert sum(m.indices.shape[0] for m in load_seed_model(out / "strip.json").meshes) == 2


def test_same_file_names_in_different_folders_get_distinct_ids_on_the_examples(tmp_path):
    for folder in ("a", "b"):
        shutil.copytree(EXAMPLES / "pyramid", tmp_path / folder / "pyramid")
    out = tmp_path / "out"
    r = run_build(str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(out), "--json", str(tmp_path / "r.json"))
    assert r.exit_code == 0, r.output
    ids = sorted(a["id"] for a in json.loads((tmp_path / "r.json").read_text())["assets"])
    assert len(set(ids)) == 2 and all(i.endswith("pyramid") for i in ids)
    for i in ids:
        load_seed_model(out / f"{i}.json")


def test_a_failed_rebuild_keeps_the_earlier_outputs_on_the_examples(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(EXAMPLES / "crate", src)
    out = tmp_path / "out"
    assert run_build(str(src / "crate.gltf"), "-o", str(out)).exit_code == 0
    before = {p: (out / p).read_bytes() for p in outputs_of(out)}
    (src / "crate.bin").write_bytes(b"\0" * 10)  # truncated buffer
    r = run_build(str(src / "crate.gltf"), "-o", str(out))
    assert r.exit_code == 1
    assert "crate.gltf" in r.output and "Traceback" not in r.output
    assert {p: (out / p).read_bytes() for p in outputs_of(out)} == before
    assert not list(out.rglob("*.tmp"))
