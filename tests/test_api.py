"""The Python API (assetpipe.build / validate / load), through public names only, on the bundled
examples and a generated sphere: no corpus needed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import assetpipe
from assetpipe.options import BuildOptions, LodOptions, MeshOptions

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"


def write_sphere_obj(path: Path, n_lat: int = 16, n_lon: int = 32) -> int:
    """A closed UV sphere (radius 1) as OBJ; returns its triangle count."""
    lat = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    ring = np.stack([np.outer(np.sin(lat), np.cos(lon)), np.outer(np.cos(lat), np.ones_like(lon)),
                     np.outer(np.sin(lat), np.sin(lon))], axis=-1).reshape(-1, 3)
    verts = np.vstack([[0, 1, 0], ring, [0, -1, 0]])
    r = lambda i, j: 1 + i * n_lon + (j % n_lon)  # noqa: E731 (0-based vertex of ring i, column j)
    j = np.arange(n_lon)
    faces = [np.stack([np.zeros(n_lon, int), r(0, j + 1), r(0, j)], 1)]
    for i in range(n_lat - 2):  # one vectorised band per ring pair
        faces.append(np.stack([r(i, j), r(i, j + 1), r(i + 1, j + 1)], 1))
        faces.append(np.stack([r(i, j), r(i + 1, j + 1), r(i + 1, j)], 1))
    bottom = len(verts) - 1
    faces.append(np.stack([r(n_lat - 2, j), r(n_lat - 2, j + 1), np.full(n_lon, bottom)], 1))
    f = np.vstack(faces) + 1
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts] + [f"f {a} {b} {c}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")
    return len(f)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("api")
    n_tris = write_sphere_obj(tmp / "ball.obj")
    # a cache of its own: the session's shared cache may already hold the examples (built by
    # tests that ran first), and this report is asserted to have built all three
    report = assetpipe.build([EXAMPLES, tmp / "ball.obj"], tmp / "out", jobs=1, cache_dir=tmp / "cache")
    return tmp, report, n_tris


def test_build_returns_a_report_of_every_input(built):
    tmp, report, _ = built
    assert isinstance(report, assetpipe.BuildReport)
    assert report.failed == []
    assert sorted(r.id for r in report.results) == ["ball", "crate", "pyramid"]
    assert report.counts() == {"built": 3}
    assert all(Path(p).is_file() for r in report.results for p in r.outputs)


def test_load_gives_numpy_arrays_with_lod_ranges_and_materials(built):
    tmp, _, n_tris = built
    model = assetpipe.load(tmp / "out" / "ball.json")
    assert isinstance(model, assetpipe.LoadedModel)
    assert model.positions.dtype == np.float32 and model.positions.shape[1] == 3
    assert model.indices.dtype == np.uint32
    (mesh,) = model.meshes
    levels = mesh.lod_ranges
    # every vertex LOD0 draws is on the unit sphere, within float32 rounding of the %.6f text
    # (coarse levels may move theirs: own rows after LOD0's, docs/FORMAT.md)
    lod0 = model.indices[levels[0, 0]:levels[0, 0] + levels[0, 1]]
    np.testing.assert_allclose(np.linalg.norm(model.positions[lod0], axis=1), 1.0, atol=2e-6)
    assert levels.shape[1] == 2 and levels[0, 1] == 3 * n_tris  # LOD0 is the whole sphere
    assert len(levels) > 1 and np.all(np.diff(levels[:, 1]) < 0)  # coarser levels have fewer triangles
    assert np.all(np.diff(mesh.switch_distances) > 0)
    rows = model.lod_ranges
    assert rows.shape == (len(levels), 4) and np.array_equal(rows[:, 2:], levels)
    tris = model.triangles(0, len(levels) - 1)
    assert tris.shape == (levels[-1, 1] // 3, 3) and int(tris.max()) < mesh.vertex_base + mesh.vertex_count
    assert model.materials[mesh.material]["id"].startswith("ball-mat-")


def test_load_of_a_textured_model_names_its_textures(built):
    tmp, _, _ = built
    crate = assetpipe.load(tmp / "out" / "crate.json")
    tex = crate.materials[crate.meshes[0].material]["textures"]["baseColor"]
    assert (tmp / "out" / tex["ktx2"]).is_file() and (tmp / "out" / tex["path"]).is_file()


def test_options_are_the_clis_dataclasses(built, tmp_path):
    tmp, _, _ = built
    report = assetpipe.build(tmp / "ball.obj", tmp_path / "out", lod=None,
                             mesh=MeshOptions(layout=("position", "normal")), jobs=1)
    assert report.failed == []
    model = assetpipe.load(tmp_path / "out" / "ball.json")
    assert len(model.meshes[0].lod_ranges) == 1  # lod=None: LOD0 only
    assert [a["name"] for a in model.sidecar["vertexLayout"]["attributes"]] == ["position", "normal"]
    again = assetpipe.build(tmp / "ball.obj", tmp_path / "out", options=BuildOptions(lod=None,
                            mesh=MeshOptions(layout=("position", "normal"))), jobs=1)
    assert again.counts() == {"cached": 1}  # the same options, given whole: a no-op


def test_a_bad_input_is_a_failed_entry_not_an_exception(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nf 1 2 3\n")
    report = assetpipe.build([bad, EXAMPLES / "pyramid"], tmp_path / "out", jobs=1)
    assert [r.id for r in report.failed] == ["bad"]
    assert str(bad) in report.failed[0].error and "\n" not in report.failed[0].error
    assert (tmp_path / "out" / "pyramid.json").is_file()


def test_wrong_option_types_are_refused(tmp_path):
    with pytest.raises(TypeError, match="lod must be a LodOptions or None"):
        assetpipe.build(EXAMPLES, tmp_path, lod={"ratios": [1, 0.5]})
    with pytest.raises(TypeError, match="options must be a BuildOptions"):
        assetpipe.build(EXAMPLES, tmp_path, options=LodOptions())
    with pytest.raises(ValueError, match="jobs must be at least 1"):
        assetpipe.build(EXAMPLES, tmp_path, jobs=0)


def test_load_of_a_broken_build_names_the_file(built, tmp_path):
    tmp, _, _ = built
    for name in ("crate.json", "crate-mat.json", "crate.asset.json", "crate.vtx"):
        (tmp_path / name).write_bytes((tmp / "out" / name).read_bytes())
    idx = (tmp / "out" / "crate.idx").read_bytes()
    (tmp_path / "crate.idx").write_bytes(idx[: len(idx) // 2])
    with pytest.raises(assetpipe.AssetError, match=r"crate\.idx.*exceed"):
        assetpipe.load(tmp_path / "crate.json")


def test_scene_builds_through_the_api(tmp_path):
    report = assetpipe.build([REPO / "tests/data/scenes/town.scene.json"], tmp_path / "out", jobs=1)
    assert report.failed == []
    scene = json.loads((tmp_path / "out" / "town.scene.json").read_text())
    assert len(scene["objects"]) == 4


def test_import_assetpipe_and_its_api_stay_light():
    """numpy is imported when a model is loaded or built, not by ``import assetpipe`` or the API's names
    (a no-op ``assetpipe.build`` imports none, as the CLI's)."""
    code = ("import sys, assetpipe; a = 'assetpipe.api' in sys.modules; assetpipe.load; assetpipe.BuildOptions; "
            "print(a, 'assetpipe.api' in sys.modules, 'numpy' in sys.modules, callable(assetpipe.build))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True", "False", "True"]


@pytest.mark.vulkan
def test_validate_renders_the_built_models(built):
    tmp, _, _ = built
    options = assetpipe.ValidateOptions(width=64, height=64, source_root=str(EXAMPLES))
    results = assetpipe.validate(tmp / "out", options, isolate=False)  # in process: the CLI test covers isolation
    assert sorted(r.id for r in results) == ["ball", "crate", "pyramid"]
    assert all(r.passed for r in results), [(r.id, r.error, [c.messages for c in r.checks if not c.passed])
                                            for r in results]


def test_build_takes_the_texture_compression(tmp_path):
    crate = Path(__file__).resolve().parents[1] / "examples/crate/crate.gltf"
    r = assetpipe.build(crate, tmp_path / "out", lod=None, texture_compression="etc2", jobs=1,
                        cache_dir=tmp_path / "cache")
    assert not r.failed
    tex = json.loads((tmp_path / "out/crate.asset.json").read_text())["materials"][0]["textures"]["baseColor"]
    assert tex["vkFormat"] == 148  # ETC2 RGB8 sRGB: the crate's base colour is opaque
    with pytest.raises(ValueError, match="texture compression must be one of none, bc, etc2, not 'astc'"):
        assetpipe.build(crate, tmp_path / "out2", texture_compression="astc", cache_dir=tmp_path / "cache")
