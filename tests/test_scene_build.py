"""Scene-driven builds: only what scenes reference is built, with only the LOD levels, mip
levels and attributes they can use; the reasons are reported; the scene output round-trips."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from assetpipe.build import run_build
from assetpipe.core.ktx2 import read_ktx2
from assetpipe.options import DEFAULT_BUILD_OPTIONS
from seed_loader import load_seed_model


def write_scene(path: Path, objects: list[dict], **extra) -> Path:
    path.write_text(json.dumps({"scene": {"ambient_light": [1, 1, 1, 0.2], "objects": objects, **extra}}))
    return path


def build(tmp: Path, *inputs):
    return run_build(list(inputs), tmp / "out", DEFAULT_BUILD_OPTIONS, cache_dir=tmp / "cache")


def outputs(out: Path) -> set[str]:
    return {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() and ".assetpipe" not in p.parts}


@pytest.fixture
def two_of_many(corpus, tmp_path):
    duck = corpus / "models/Duck/glTF/Duck.gltf"
    box = corpus / "models/BoxTextured/glTF/BoxTextured.gltf"
    scene = write_scene(tmp_path / "level.json", [
        {"model": {"name": str(duck)}, "instances": [[{"translation": [0, 0, -5]}]]},
        {"model": {"name": str(box)}, "instances": [[{"translation": [2, 0, -5]}, {"rotationY": 90}]]},
    ])
    return scene


def test_a_scene_builds_only_the_models_it_uses(corpus, tmp_path, two_of_many):
    r = build(tmp_path, two_of_many, corpus / "models")
    by_status: dict[str, list] = {}
    for a in r.results:
        by_status.setdefault(a.status, []).append(a)
    assert sorted(a.id for a in by_status["built"]) == ["BoxTextured", "Duck", "level"]
    n_models = len([p for p in (corpus / "models").rglob("*") if p.suffix.lower() in (".gltf", ".glb", ".obj")])
    assert len(by_status["skipped"]) == n_models - 2
    assert all(a.reason == "not built: no scene references it" for a in by_status["skipped"])
    model_files = {n.split(".")[0].removesuffix("-mat") for n in outputs(tmp_path / "out") if "/" not in n}
    assert model_files == {"BoxTextured", "Duck", "level"}
    assert not r.failed


def test_removing_an_object_removes_its_outputs(tmp_path, two_of_many):
    build(tmp_path, two_of_many)
    assert "BoxTextured.json" in outputs(tmp_path / "out")
    doc = json.loads(two_of_many.read_text())
    doc["scene"]["objects"].pop(1)
    two_of_many.write_text(json.dumps(doc))
    r = build(tmp_path, two_of_many)
    names = outputs(tmp_path / "out")
    assert "BoxTextured.json" not in names and "Duck.json" in names and "level.scene.json" in names
    assert "BoxTextured.json" in r.removed
    scene = json.loads((tmp_path / "out/level.scene.json").read_text())
    assert [m["id"] for m in scene["models"]] == ["Duck"]


def test_unselectable_lod_and_mip_levels_are_not_built_and_are_explained(corpus, tmp_path):
    duck = corpus / "models/Duck/glTF/Duck.gltf"
    full = run_build([duck], tmp_path / "full", DEFAULT_BUILD_OPTIONS, cache_dir=tmp_path / "cache")
    assert not full.failed
    switch = [l["switchDistance"] for l in
              json.loads((tmp_path / "full/Duck.asset.json").read_text())["meshes"][0]["lods"]]
    assert len(switch) == 5
    far = (switch[2] + switch[3]) / 2  # levels 3 and 4 switch in beyond it: never selected
    scene = write_scene(tmp_path / "near.json", [{"model": {"name": str(duck)}, "view_distance": [0, far]}])
    r = build(tmp_path, scene)
    assert not r.failed
    side = json.loads((tmp_path / "out/Duck.asset.json").read_text())
    lods = side["meshes"][0]["lods"]
    assert len(lods) == 3 and [l["switchDistance"] for l in lods] == pytest.approx(switch[:3], rel=1e-6)
    result = next(a for a in r.results if a.id == "Duck")
    assert any("LOD levels 3, 4 not built" in s for s in result.skipped), result.skipped
    assert side["materials"][0]["textures"]["baseColor"]["width"] == 512  # no size limit: all mips

    # the same object at most 60 px on screen: it never comes near enough for the fine levels,
    # and samples at most 64 texels: the 512 px texture's top mip levels are not built either
    scene = write_scene(tmp_path / "near.json", [
        {"model": {"name": str(duck)}, "view_distance": [0, far], "max_screen_px": 60}])
    r = build(tmp_path, scene)
    assert not r.failed
    side = json.loads((tmp_path / "out/Duck.asset.json").read_text())
    lods = side["meshes"][0]["lods"]
    assert [l.get("chainLevel", 0) for l in lods][0] > 0 and len(lods) < 3
    result = next(a for a in r.results if a.id == "Duck")
    assert any("not built: finer than level" in s for s in result.skipped), result.skipped
    tex = side["materials"][0]["textures"]["baseColor"]
    assert tex["width"] == 64 and tex["levels"] == 7
    k = read_ktx2((tmp_path / "out" / tex["ktx2"]).read_bytes())
    assert (k.width, k.height, len(k.levels)) == (64, 64, 7)
    assert any("mip levels above 64x64 not built" in s for s in result.skipped), result.skipped
    # the seed mesh is the coarser level now, on the vertex prefix it uses
    seed = load_seed_model(tmp_path / "out/Duck.json")
    assert seed.meshes[0].indices.shape[0] == lods[0]["triangles"]
    assert seed.meshes[0].positions.shape[0] == lods[0]["vertexCount"]


def test_uvs_of_untextured_meshes_are_not_computed(corpus, tmp_path):
    spheres = corpus / "models/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf"
    fuze = corpus / "models/fuze/fuze.obj"
    scene = write_scene(tmp_path / "s.json", [{"model": {"name": str(spheres), "lod": {"generate": False}}},
                                              {"model": {"name": str(fuze), "lod": {"generate": False}}}])
    r = build(tmp_path, scene)
    assert not r.failed
    spheres_r = next(a for a in r.results if a.id == "MetalRoughSpheresNoTextures")
    assert any("uv0 not computed" in s for s in spheres_r.skipped)
    m = load_seed_model(tmp_path / "out/MetalRoughSpheresNoTextures.json")
    assert all((x.uvs == 0).all() for x in m.meshes)
    f = load_seed_model(tmp_path / "out/fuze.json")  # textured: its UVs are kept
    assert np.ptp(np.vstack([x.uvs for x in f.meshes]), axis=0).min() > 0.5


def test_a_hand_made_lod_list_is_one_model_with_measured_levels(corpus, tmp_path):
    import meshoptimizer  # noqa: F401 - the simplifier makes the hand-made copies
    import trimesh

    from assetpipe.pipelines.simplify import simplify

    src = tmp_path / "fuze"
    src.mkdir()
    for name in ("fuze.obj", "fuze.obj.mtl", "fuze uv.jpg"):
        shutil.copy(corpus / "models/fuze" / name, src / name)
    mesh = trimesh.load(src / "fuze.obj", force="mesh", process=False)
    lines = (src / "fuze.obj").read_text().splitlines()
    header = [l for l in lines if l.startswith(("mtllib", "usemtl"))]
    v = np.asarray(mesh.vertices)
    uv = np.asarray(mesh.visual.uv)
    counts = [len(mesh.faces)]
    for k, target in ((1, 500), (2, 250)):
        idx, _ = simplify(v, np.asarray(mesh.faces, dtype=np.uint32), target)
        counts.append(len(idx))
        body = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v] + [f"vt {a:.6f} {b:.6f}" for a, b in uv]
        body += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in idx]
        (src / f"fuze{k}.obj").write_text("\n".join(header[:1] + body[:len(v) + len(uv)] + header[1:]
                                                   + body[len(v) + len(uv):]) + "\n")
    scene = write_scene(tmp_path / "hand.json", [
        {"model": {"lod": {"final_clamp": 1000, "lods": ["fuze/fuze.obj", "fuze/fuze1.obj", "fuze/fuze2.obj"]}}}])
    r = build(tmp_path, scene)
    assert not r.failed, [a.error for a in r.results]
    model = next(a for a in r.results if a.id.startswith("fuze"))
    side = json.loads((tmp_path / f"out/{model.id}.asset.json").read_text())
    lods = side["meshes"][0]["lods"]
    # each level is its file's mesh (less any zero-area triangle the processing drops)
    assert len(lods) == 3 and counts[2] < counts[1] < counts[0]
    assert all(0.98 * c <= l["triangles"] <= c for l, c in zip(lods, counts))
    h = [l["error"]["hausdorffRel"] for l in lods]
    assert h[0] == 0 and 0 < h[1] <= h[2] < 0.2
    seed = load_seed_model(tmp_path / f"out/{model.id}.json")
    idx = np.fromfile(tmp_path / f"out/{model.id}.idx", dtype="<u4")
    for l in lods:
        part = idx[l["idxOffset"] // 4:(l["idxOffset"] + l["idxSize"]) // 4]
        assert int(part.max()) < l["vertexCount"] <= seed.meshes[0].positions.shape[0]


def test_a_hand_made_list_must_share_materials(corpus, tmp_path):
    scene = write_scene(tmp_path / "bad.json", [{"model": {"lod": {"lods": [
        str(corpus / "models/fuze/fuze.obj"), str(corpus / "models/spider/spider.obj")]}}}])
    r = build(tmp_path, scene)
    failed = [a for a in r.results if a.status == "failed"]
    assert failed and "hand-made LOD list" in failed[0].error and "\n" not in failed[0].error


def test_instances_round_trip_as_matrices(tmp_path):
    crate = Path(__file__).resolve().parents[1] / "examples/crate/crate.gltf"
    ops = [{"translation": [1, 2, 3]}, {"rotationY": 90}, {"scaling": [2, 2, 2]}]
    scene = write_scene(tmp_path / "m.json", [{"model": {"name": str(crate)}, "instances": [ops, []]}])
    r = build(tmp_path, scene)
    assert not r.failed
    out = json.loads((tmp_path / "out/m.scene.json").read_text())
    inst = out["objects"][0]["instances"]
    t = np.eye(4)
    t[:3, 3] = [1, 2, 3]
    c, s = math.cos(math.radians(90)), math.sin(math.radians(90))
    ry = np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])
    sc = np.diag([2.0, 2.0, 2.0, 1.0])
    np.testing.assert_allclose(inst[0]["matrix"], t @ ry @ sc, atol=1e-12)
    np.testing.assert_allclose(inst[1]["matrix"], np.eye(4))
    assert inst[0]["lodScale"] == 2.0
    assert out["models"] == [{"id": "crate", "file": "crate.json",
                              "bounds": json.loads((tmp_path / "out/crate.asset.json").read_text())["bounds"]}]
    assert out["objects"][0]["lod"]["switchDistances"][0] == 0.0


def test_a_bad_scene_fails_with_one_line(tmp_path):
    scene = write_scene(tmp_path / "bad.json", [{"model": {"name": "missing.obj"}}])
    r = build(tmp_path, scene)
    assert len(r.results) == 1 and r.results[0].status == "failed"
    err = r.results[0].error
    assert "bad.json" in err and "object 0" in err and "missing.obj" in err and "\n" not in err


def test_a_recentred_model_carries_its_offset_into_the_scene(tmp_path):
    """#13: with --recenter the scene output gives each model's positionOffset, so an engine
    places world = matrix . (vertex + offset)."""
    import dataclasses

    from robust_models import uv_sphere, write_obj

    pos, tris, _ = uv_sphere(16, 8, center=(1e6, 2.5, -3e6))
    write_obj(tmp_path / "far.obj", pos, tris)
    scene = write_scene(tmp_path / "s.json", [{"model": {"name": str(tmp_path / "far.obj")},
                                                "instances": [[{"translation": [1, 0, 0]}]]}])
    opts = dataclasses.replace(DEFAULT_BUILD_OPTIONS, mesh=dataclasses.replace(DEFAULT_BUILD_OPTIONS.mesh,
                                                                               recenter=True))
    r = run_build([scene], tmp_path / "out", opts, cache_dir=tmp_path / "cache")
    assert not r.failed, [a.error for a in r.failed]
    side = json.loads((tmp_path / "out/far.asset.json").read_text())
    center = ((pos.min(0) + pos.max(0)) / 2).tolist()
    assert side["positionOffset"] == center
    out = json.loads((tmp_path / "out/s.scene.json").read_text())
    (model,) = out["models"]
    assert model["positionOffset"] == center
    # the written positions are local: within the sphere's radius of 0, and a coarse level's
    # moved vertices (docs/FORMAT.md) within its recorded Hausdorff bound of that
    bound = max(l["error"]["hausdorff"] for m in side["meshes"] for l in m["lods"])
    assert max(abs(v) for v in side["bounds"]["max"] + side["bounds"]["min"]) <= 1.0 + bound + 1e-6


def _crate_textures(out: Path, model_id: str = "crate") -> dict:
    side = json.loads((out / f"{model_id}.asset.json").read_text())
    return side["materials"][0]["textures"]


def test_a_scene_asks_for_compressed_textures_of_what_it_uses(tmp_path):
    """``texture_compression`` in a scene: its model's textures and its objects' own textures
    are BC (vkFormat 146, BC7 sRGB for base colour) while the build's default stays ``none``;
    the scene's texture budget caps the chain before compression (only 32x32 and below are
    encoded), and a model no scene uses is not built at all."""
    crate_dir = Path(__file__).resolve().parents[1] / "examples/crate"
    shutil.copytree(crate_dir, tmp_path / "crate")
    shutil.copy(crate_dir / "crate.png", tmp_path / "own.png")
    scene = write_scene(tmp_path / "s.json", [{"model": {"name": str(tmp_path / "crate/crate.gltf"),
                                                         "lod": {"generate": False}},
                                               "texture": str(tmp_path / "own.png")}],
                        texture_budget=32, texture_compression="bc")
    assert DEFAULT_BUILD_OPTIONS.texture.compression == "none"
    r = build(tmp_path, scene)
    assert not r.failed, r.failed
    tex = _crate_textures(tmp_path / "out")["baseColor"]
    assert tex["vkFormat"] == 146 and (tex["width"], tex["levels"]) == (32, 6)
    k = read_ktx2((tmp_path / "out" / tex["ktx2"]).read_bytes())
    assert (k.vk_format, k.width, len(k.levels)) == (146, 32, 6)
    assert [lv.shape for lv in k.levels][:2] == [(8, 8, 16), (4, 4, 16)]  # 32x32 and 16x16 in 4x4 blocks
    own = json.loads((tmp_path / "out/s.scene.json").read_text())["objects"][0]["texture"]
    k = read_ktx2((tmp_path / "out" / own["ktx2"]).read_bytes())
    assert (k.vk_format, k.width) == (146, 32)

    # the same model built without the scene keeps the build's default: RGBA8
    r = run_build([tmp_path / "crate/crate.gltf"], tmp_path / "plain", DEFAULT_BUILD_OPTIONS,
                  cache_dir=tmp_path / "cache")
    assert not r.failed
    tex = _crate_textures(tmp_path / "plain")["baseColor"]
    assert tex["vkFormat"] == 43 and tex["width"] == 256


def test_scenes_that_disagree_on_a_models_codec_fail_with_one_line(tmp_path):
    crate = Path(__file__).resolve().parents[1] / "examples/crate/crate.gltf"
    a = write_scene(tmp_path / "a.json", [{"model": {"name": str(crate)}}], texture_compression="bc")
    b = write_scene(tmp_path / "b.json", [{"model": {"name": str(crate)}}], texture_compression="etc2")
    r = build(tmp_path, a, b)
    assert r.failed
    assert "scenes ask for different texture_compression (bc in scene a object 0, etc2 in scene b object 0)" \
        in r.failed[0].error


def test_a_scene_says_which_cap_dropped_its_mip_levels(tmp_path):
    """A scene build names the cause of a texture's missing top levels: the scene's own budget
    when it is the lower cap, else the build's maximum texture size."""
    import dataclasses

    crate_dir = Path(__file__).resolve().parents[1] / "examples/crate"
    shutil.copytree(crate_dir, tmp_path / "crate")
    model = {"model": {"name": str(tmp_path / "crate/crate.gltf"), "lod": {"generate": False}}}
    opts = dataclasses.replace(DEFAULT_BUILD_OPTIONS,
                               texture=dataclasses.replace(DEFAULT_BUILD_OPTIONS.texture, max_size=64))
    cases = {"build": (write_scene(tmp_path / "a.json", [model]), "the build's maximum texture size"),
             "scene": (write_scene(tmp_path / "b.json", [model], texture_budget=32), "the scene's texture budget")}
    for name, (scene, why) in cases.items():
        r = run_build([scene], tmp_path / f"out-{name}", opts, cache_dir=tmp_path / "cache")
        assert not r.failed, r.failed
        lines = [s for a in r.results for s in a.skipped if "mip levels above" in s]
        assert lines and all(why in s for s in lines), (name, lines)
