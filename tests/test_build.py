"""End-to-end builds through the CLI on small real models: the seed contract, the report,
determinism, and failure isolation."""

from __future__ import annotations

import json
import os
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
    # levels over LOD0's vertices use a prefix (never growing); a level whose vertices moved
    # (docs/FORMAT.md) has its own rows after LOD0's: [vertexStart, vertexCount)
    n0 = lods[0]["vertexCount"]
    prefix = [l["vertexCount"] for l in lods if "vertexStart" not in l]
    assert prefix[0] <= mesh["vertexCount"] and all(a >= b for a, b in zip(prefix, prefix[1:]))
    assert any("vertexStart" in l for l in lods)  # the Duck's levels move vertices (LOD step 19)
    for l in lods:
        part = idx[l["idxOffset"] // 4:(l["idxOffset"] + l["idxSize"]) // 4]
        assert part.size == 3 * l["triangles"]
        assert int(part.max()) < l["vertexCount"] <= mesh["vertexCount"]
        if "vertexStart" in l:
            assert n0 <= l["vertexStart"] == int(part.min())
        else:
            assert l["vertexCount"] <= n0
    assert np.isfinite(vtx).all()
    # ...Rel is a fraction of LOD0's diagonal (the mesh's bounds also hold moved vertices)
    p0 = vtx[np.unique(idx[:lods[0]["idxSize"] // 4]), :3].astype(np.float64)
    assert abs(lods[1]["error"]["hausdorff"] - lods[1]["error"]["hausdorffRel"] * np.linalg.norm(
        p0.max(0) - p0.min(0))) < 1e-3 * lods[1]["error"]["hausdorff"] + 1e-9


# -- one bad model never crashes the build; nothing outside -o and --cache (#13) -------------

def _cli(*args, env=None):
    from robust_models import run_cli

    return run_cli(*args, env=env)


def _good_and_bad(tmp_path):
    """good.obj beside three models whose numbers overflow to infinity on the way."""
    from gltf_builder import GltfBuilder
    from robust_models import uv_sphere, write_obj

    src = tmp_path / "src"
    src.mkdir()
    pos, tris, _ = uv_sphere(8, 4)
    write_obj(src / "good.obj", pos, tris)
    (src / "huge.obj").write_text("v 1e308 1e308 1e308\nv -1e308 0 0\nv 0 1 0\nf 1 2 3\n")
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), scale=[1e300, 1e300, 1e300])
    b.write_gltf(src / "scaled.gltf")
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles([[0, 0, 0], [1, 0, 0], [0, 1, 0]], material=b.add_material(
        pbrMetallicRoughness={"baseColorFactor": [1e39, 0.5, 0.5, 1.0]})))
    b.write_gltf(src / "colour.gltf")
    return src


def test_non_finite_numbers_fail_their_model_in_one_line_and_the_rest_builds(tmp_path):
    src = _good_and_bad(tmp_path)
    report_path = tmp_path / "r.json"
    r = _cli("build", src, "-o", tmp_path / "out", "--cache", tmp_path / "c", "--json", report_path)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stderr + r.stdout and "internal error" not in r.stderr + r.stdout
    report = {Path(a["source"]).name: a for a in json.loads(report_path.read_text())["assets"]}
    assert report["good.obj"]["status"] == "built"
    assert (tmp_path / "out" / "good.json").is_file()
    for name in ("huge.obj", "scaled.gltf"):
        a = report[name]
        assert a["status"] == "failed", a
        assert "\n" not in a["error"] and str(src / name) in a["error"], a["error"]
        assert a.get("traceback") is None
    # a colour of 1e39 is finite in float64 JSON: it is either built or fails in one line
    assert report["colour.gltf"]["status"] in ("built", "failed")
    assert report["colour.gltf"].get("traceback") is None


def _task_out_of_memory():
    import numpy as np

    return np.zeros(1 << 62, np.uint8)  # numpy raises MemoryError (_ArrayMemoryError) at once


def test_out_of_memory_names_the_input_and_the_step(tmp_path):
    from assetpipe.cache.stat_cache import StatCache
    from assetpipe.cache.store import Store
    from assetpipe.graph import AssetState, Graph
    from assetpipe.options import DEFAULT_BUILD_OPTIONS

    store = Store(tmp_path / "c")
    graph = Graph(store, StatCache(tmp_path / "c" / "stat.json"), DEFAULT_BUILD_OPTIONS, {})
    a = AssetState(source=tmp_path / "big.obj", id="big")
    graph._run_phase([([a], "mesh", {"step": "mesh", "test": 1}, (_task_out_of_memory,))])
    assert a.error == f"{tmp_path / 'big.obj'}: out of memory in step mesh"


def test_nothing_is_written_outside_out_and_cache(tmp_path):
    """HOME and XDG_CACHE_HOME point at a folder that must stay empty when --cache is given."""
    import os

    from robust_models import cli_env, make_inputs

    src = make_inputs(tmp_path / "src", n_obj=1, n_gltf=1)
    home = tmp_path / "home"
    home.mkdir()
    env = cli_env(HOME=home, XDG_CACHE_HOME=home / "xdg")
    env.pop("ASSETPIPE_CACHE", None)
    r = _cli("build", src, "-o", tmp_path / "out", "--cache", tmp_path / "c", "-j", "2", env=env)
    assert r.returncode == 0, r.stderr
    assert list(home.rglob("*")) == [], "the build wrote outside -o and --cache"
    assert (tmp_path / "c" / "library-versions.json").is_file()
    assert sorted(os.listdir(tmp_path)) == ["c", "home", "out", "src"]


def test_a_link_in_the_output_folder_never_carries_a_write_outside(tmp_path):
    from robust_models import make_inputs

    src = make_inputs(tmp_path / "src", n_obj=1, n_gltf=1)
    outside = tmp_path / "outside"
    outside.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "textures").symlink_to(outside, target_is_directory=True)
    report_path = tmp_path / "r.json"
    r = _cli("build", src, "-o", out, "--cache", tmp_path / "c", "--json", report_path)
    assert r.returncode == 1
    assert list(outside.iterdir()) == []
    report = {a["id"]: a for a in json.loads(report_path.read_text())["assets"]}
    assert report["ball0"]["status"] == "built"  # no texture: nothing to write through the link
    assert report["tex0"]["status"] == "failed" and "refused" in report["tex0"]["error"]
    assert "\n" not in report["tex0"]["error"] and report["tex0"].get("traceback") is None

    # the build's own state folder as a link leading out: refused before anything is written
    out2 = tmp_path / "out2"
    out2.mkdir()
    (out2 / ".assetpipe").symlink_to(outside, target_is_directory=True)
    r = _cli("build", src, "-o", out2, "--cache", tmp_path / "c")
    assert r.returncode != 0 and "leading out of the output folder" in r.stderr
    assert list(outside.iterdir()) == []


def test_a_restored_state_file_cannot_delete_outside_out(tmp_path):
    from robust_models import make_inputs

    src = make_inputs(tmp_path / "src", n_obj=1, n_gltf=0)
    out = tmp_path / "out"
    assert _cli("build", src, "-o", out, "--cache", tmp_path / "c").returncode == 0
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    absolute = tmp_path / "abs.txt"
    absolute.write_text("keep me too")
    state_path = out / ".assetpipe" / "state.json"
    state = json.loads(state_path.read_text())
    (entry,) = state["assets"].values()
    entry["outputs"]["../victim.txt"] = ["xxh3:00", 7, 0]
    entry["outputs"][str(absolute)] = ["xxh3:00", 11, 0]
    entry["outputs"]["textures/../../victim.txt"] = ["xxh3:00", 7, 0]
    state["assets"]["/nowhere/gone.obj"] = {**entry, "id": "gone"}  # a vanished source: its outputs are stale
    state_path.write_text(json.dumps(state))
    r = _cli("build", src, "-o", out, "--cache", tmp_path / "c")
    assert r.returncode == 0, r.stderr
    assert victim.read_text() == "keep me" and absolute.read_text() == "keep me too"


def test_output_size_limit_fails_the_model_in_one_line(tmp_path):
    from robust_models import make_inputs

    src = make_inputs(tmp_path / "src", n_obj=1, n_gltf=0)
    report_path = tmp_path / "r.json"
    r = _cli("build", src, "-o", tmp_path / "out", "--cache", tmp_path / "c", "--max-output-mb", "0.001",
             "--json", report_path)
    assert r.returncode == 1
    (a,) = json.loads(report_path.read_text())["assets"]
    assert a["status"] == "failed" and "per-model limit of 0 MiB" not in a["error"]
    assert "over the per-model limit" in a["error"] and "\n" not in a["error"] and str(src / "ball0.obj") in a["error"]
    assert not (tmp_path / "out" / "ball0.json").exists()
    assert _cli("build", src, "-o", tmp_path / "out", "--cache", tmp_path / "c").returncode == 0


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


def test_a_texture_on_a_uv_set_the_layout_lacks_is_named_in_the_warnings(tmp_path):
    # the pbr kind's occlusion samples TEXCOORD_1, its base colour TEXCOORD_0: the default layout
    # (position, uv0) does not carry that set, so the build says which role and what to do;
    # with uv1 in the layout there is nothing to say
    from validate_assets import write_assets

    write_assets(tmp_path / "src", ("pbr", "multiuv"))
    for layout, want in (("position,uv0", True), ("position,uv0,uv1", False)):
        out = tmp_path / f"out-{want}"
        r = run_build(str(tmp_path / "src"), "-o", str(out), "--layout", layout, "--no-lod",
                      "--json", str(tmp_path / "r.json"))
        assert r.exit_code == 0, r.output
        report = {a["id"]: a for a in json.loads((tmp_path / "r.json").read_text())["assets"]}
        pbr = [w for a, rep in report.items() if a.endswith("pbr") for w in rep["warnings"]]
        said = [w for w in pbr if "occlusion texture samples TEXCOORD_1" in w and "add uv1 to --layout" in w]
        assert bool(said) == want, pbr
        # multiuv: its base colour is on TEXCOORD_1, so uv0 holds that set: nothing missing
        assert not any("TEXCOORD" in w for a, rep in report.items() if a.endswith("multiuv")
                       for w in rep["warnings"])


def test_a_file_name_that_is_not_utf8_fails_alone(tmp_path):
    # it went into the build graph's JSON and failed every model of the build (UnicodeEncodeError)
    art = tmp_path / "art"
    art.mkdir()
    tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    (art / "good.obj").write_bytes(tri)
    bad = os.path.join(os.fsencode(art), b"bad\xffname.obj")
    with open(bad, "wb") as f:
        f.write(tri)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["build", str(art), "-o", str(out), "--cache", str(tmp_path / "c"), "-j", "1",
                                  "--json", str(tmp_path / "r.json")])
    assert r.exit_code == 1, r.output
    report = json.loads((tmp_path / "r.json").read_text())
    by_status = {a["status"]: a for a in report["assets"]}
    assert by_status["built"]["id"] == "good" and (out / "good.json").is_file()
    assert "bad\\xffname.obj: the file name is not valid UTF-8" in by_status["failed"]["error"]
    assert "bad\\xffname.obj: the file name is not valid UTF-8" in r.output


def test_a_fatal_error_after_some_models_were_written_keeps_their_state(tmp_path, monkeypatch):
    """The cache failing in the middle of the last steps stops the build with its one error; the
    models already written keep their state entries, so the next build takes them as up to date
    (it neither builds nor rewrites them) and builds the rest."""
    from assetpipe.build import run_build
    from assetpipe.core.errors import CacheError
    from assetpipe.graph import Graph
    from assetpipe.options import BuildOptions

    cube = "".join(f"v {x} {y} {z}\n" for x in (0, 1) for y in (0, 1) for z in (0, 1)) + (
        "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n")
    src = tmp_path / "src"
    src.mkdir()
    for name in ("a", "b", "c"):
        (src / f"{name}.obj").write_text(cube)
    out, cache = tmp_path / "out", tmp_path / "cache"
    real = Graph.build
    written: list[str] = []

    def failing(self, assets, on_done=None):
        def done(a):
            on_done(a)
            written.append(a.id)
            raise CacheError("the cache folder became unusable (simulated)")
        return real(self, assets, on_done=done)

    monkeypatch.setattr(Graph, "build", failing)
    with pytest.raises(CacheError, match="simulated"):
        run_build([src], out, BuildOptions(), jobs=1, cache_dir=cache)
    assert len(written) == 1 and (out / f"{written[0]}.json").is_file()
    first = out / f"{written[0]}.idx"
    stamp = first.stat().st_mtime_ns
    monkeypatch.setattr(Graph, "build", real)
    report = run_build([src], out, BuildOptions(), jobs=1, cache_dir=cache)
    status = {r.id: (r.status, r.reason) for r in report.results}
    # up to date from the state file: not looked up step by step in the cache
    assert status[written[0]] == ("cached", "up to date") and sorted(status) == ["a", "b", "c"], status
    assert all(s == "built" or r.startswith("results cached") for i, (s, r) in status.items() if i != written[0]), status
    assert first.stat().st_mtime_ns == stamp  # not written again
