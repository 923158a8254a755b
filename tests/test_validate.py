"""The validator: the fixture passes every check; deliberately broken builds fail."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from assetpipe.renderer.reports import write_json_report, write_junit_report
from assetpipe.renderer.session import shared_renderer
from assetpipe.renderer.batch import validate_batch, validate_model
from assetpipe.renderer.validate import ValidateOptions, ValidationResult
from tests.json_edits import value_paths, with_value

pytestmark = pytest.mark.vulkan
BUILT = Path(__file__).parent / "data" / "built"
CUBE = BUILT / "cube" / "cube.json"
OPTS = ValidateOptions(width=128, height=128)


def _fixtures_module():
    spec = importlib.util.spec_from_file_location("make_fixtures", BUILT / "make_fixtures.py")
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture()
def cube(tmp_path: Path) -> Path:
    shutil.copytree(BUILT / "cube", tmp_path / "cube")
    shutil.copytree(BUILT / "src", tmp_path / "src")
    return tmp_path / "cube" / "cube.json"


def _ktx(cube: Path) -> Path:
    return next((cube.parent / "textures").glob("*.ktx2"))


def test_fixture_passes_every_check() -> None:
    r = validate_model(CUBE, OPTS, isolate=False)
    assert r.passed, r.failures()
    assert [c.name for c in r.checks] == ["load", "vulkan", "bounds", "silhouette", "source", "uvs", "lods",
                                          "textures", "roles"]
    # the fixture's source is an OBJ: texture roles are compared for glTF sources only
    assert all(c.status == "pass" for c in r.checks if c.name != "roles"), r.to_json()
    sil = r.check("silhouette")
    assert sil is not None and all(v["maxBoxErrorPx"] <= 1.0 for v in sil.figures["views"])
    src = r.check("source")
    assert src is not None and all(v["xor"] < 0.01 for v in src.figures["views"])


def test_checks_beside_give_the_same_results_and_phases_add_up(monkeypatch: pytest.MonkeyPatch) -> None:
    """The checks that read files only (Check.beside: textures, roles) run on threads beside the
    others: every result equals the one of running them in turn, the report keeps the registry
    order, and the phases (load, upload, render, compare) still add up to at most the model's
    wall time (a check beside is not split into phases; the runner's wait for it is compare)."""
    import time

    from assetpipe.renderer.checks import REGISTRY

    assert {c.name for c in REGISTRY if c.beside} == {"textures", "roles"}
    t0 = time.perf_counter()
    side = validate_model(CUBE, OPTS, isolate=False)
    wall = time.perf_counter() - t0
    assert sum(side.timings.values()) <= wall
    for c in REGISTRY:
        monkeypatch.setattr(type(c), "beside", False)
    inline = validate_model(CUBE, OPTS, isolate=False)
    assert [c.name for c in side.checks] == [c.name for c in inline.checks]
    for a, b in zip(side.checks, inline.checks):
        assert (a.status, a.messages, a.figures) == (b.status, b.messages, b.figures), a.name


def test_index_out_of_range_fails(cube: Path) -> None:
    idx = cube.with_name("cube.idx")
    a = np.fromfile(idx, "<u4")
    a[7] = 4000
    a.tofile(idx)
    r = validate_model(cube, OPTS, isolate=False)
    assert not r.passed and r.check("load").status == "fail"
    assert "out of range" in r.failures()[0]


def test_wrong_material_id_fails(cube: Path) -> None:
    seed = json.loads(cube.read_text())
    seed["meshes"][1]["materialId"] = "cube-mat-9"
    cube.write_text(json.dumps(seed))
    r = validate_model(cube, OPTS, isolate=False)
    assert not r.passed and "cube-mat-9" in " ".join(r.failures())


def test_truncated_vtx_fails(cube: Path) -> None:
    vtx = cube.with_name("cube.vtx")
    vtx.write_bytes(vtx.read_bytes()[:-40])
    r = validate_model(cube, OPTS, isolate=False)
    assert not r.passed and "truncated" in " ".join(r.failures())


def test_swapped_texture_fails(cube: Path) -> None:
    """Another texture (same size) in place of the material's: level 0 and colours disagree."""
    mk = _fixtures_module()
    levels = [np.ascontiguousarray(lv[..., [2, 0, 1, 3]]) for lv in mk.texture_levels()]  # other colours
    _ktx(cube).write_bytes(mk.ktx2_bytes(levels))
    r = validate_model(cube, OPTS, isolate=False)
    assert not r.passed
    assert r.check("textures").status == "fail"
    assert r.check("source").status == "fail", r.check("source")


def test_missing_mip_level_fails(cube: Path) -> None:
    mk = _fixtures_module()
    _ktx(cube).write_bytes(mk.ktx2_bytes(mk.texture_levels()[:3]))
    r = validate_model(cube, OPTS, isolate=False)
    tex = r.check("textures")
    assert tex is not None and tex.status == "fail"
    assert any("3 of 4 mip levels" in m for m in tex.messages)


def test_black_mip_level_fails(cube: Path) -> None:
    mk = _fixtures_module()
    levels = mk.texture_levels()
    levels[2] = np.zeros_like(levels[2])
    _ktx(cube).write_bytes(mk.ktx2_bytes(levels))
    r = validate_model(cube, OPTS, isolate=False)
    assert any("levels [2] are all black" in m for m in r.check("textures").messages)


def test_bad_lod_fails(cube: Path) -> None:
    """LOD1 that lost a face: far more than 1 px away from LOD0 at its switch distance."""
    idx = cube.with_name("cube.idx")
    a = np.fromfile(idx, "<u4")
    a[150:156] = 0  # the first face of LOD1 becomes degenerate
    a.tofile(idx)
    r = validate_model(cube, OPTS, isolate=False)
    lods = r.check("lods")
    assert lods is not None and lods.status == "fail", lods
    assert r.check("silhouette").status == "pass"


def test_moved_geometry_fails_source_check(cube: Path) -> None:
    """Vertices shifted in the build (bounds kept): the render no longer matches the source."""
    vtx = cube.with_name("cube.vtx")
    v = np.fromfile(vtx, "<f4").reshape(-1, 5)
    v[:54, 0] *= 0.7
    v.tofile(vtx)
    r = validate_model(cube, OPTS, isolate=False)
    assert r.check("source").status == "fail"


def test_validation_messages_are_collected() -> None:
    """An invalid Vulkan call shows up in the context's messages (what the vulkan check reads)."""
    r = shared_renderer()
    vk, ctx = r.vk, r.ctx
    ctx.take_messages()
    buf = vk.vkCreateBuffer(ctx.device, vk.VkBufferCreateInfo(size=0, usage=vk.VK_BUFFER_USAGE_VERTEX_BUFFER_BIT,
                                                              sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE), None)
    vk.vkDestroyBuffer(ctx.device, buf, None)
    msgs = ctx.take_messages()
    assert msgs and any("size" in text for _, text in msgs)


def test_batch_in_subprocess_with_reports(tmp_path: Path, cube: Path) -> None:
    idx = cube.with_name("cube.idx")
    a = np.fromfile(idx, "<u4")
    a[0] = 10_000
    a.tofile(idx)
    stats: dict = {}
    results = validate_batch([CUBE, cube, tmp_path / "missing.json"], OPTS, stats=stats)
    assert [r.passed for r in results] == [True, False, False]
    # the worker set its device up before the first model (warm): one set-up, in no model's time
    assert len(stats["setup"]) == 1 and stats["setup"][0] > 0
    assert all(r.timings.get("setup", 0.0) == 0.0 for r in results)
    write_json_report(results, tmp_path / "report.json")
    write_junit_report(results, tmp_path / "report.xml")
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["summary"] == {"models": 3, "passed": 1, "failed": 2, "acceptedByBaseline": 0}
    assert ValidationResult.from_json(data["results"][0]).passed
    root = ET.parse(tmp_path / "report.xml").getroot()
    assert root.tag == "testsuites" and int(root.get("failures")) >= 2


def test_crash_fails_one_asset_and_batch_continues(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A renderer process that dies (here: SIGKILL on a marker file) fails that asset only."""
    crash = tmp_path / "crash"
    crash.mkdir()
    (crash / "crash.json").write_text("{}")
    monkeypatch.setenv("ASSETPIPE_RENDERER_CRASH_ON", "crash.json")
    results = validate_batch([crash / "crash.json", CUBE], OPTS)
    assert results[0].error is not None and "SIGKILL" in results[0].error
    assert results[1].passed, results[1].failures()


def test_timeout_fails_one_asset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    hang = tmp_path / "hang"
    hang.mkdir()
    (hang / "hang.json").write_text("{}")
    monkeypatch.setenv("ASSETPIPE_RENDERER_HANG_ON", "hang.json")
    opts = ValidateOptions(width=128, height=128, timeout_s=2.0)
    results = validate_batch([hang / "hang.json", CUBE], opts)
    assert results[0].error is not None and "timed out" in results[0].error
    assert results[1].passed


def test_cli_commands(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from assetpipe.renderer.cli_commands import preview, validate

    runner = CliRunner()
    res = runner.invoke(validate, [str(BUILT), "--in-process", "--size", "96", "--junit", str(tmp_path / "j.xml")])
    assert res.exit_code == 0, res.output
    assert "1 of 1 models passed" in res.output and (tmp_path / "j.xml").is_file()
    res = runner.invoke(validate, [str(BUILT), "--checks", "load,bogus"])
    assert res.exit_code != 0
    res = runner.invoke(preview, [str(CUBE), "-o", str(tmp_path / "p.png"), "--size", "64"])
    assert res.exit_code == 0 and (tmp_path / "p.png").is_file()


def _shrink_bounds(cube: Path, factor: float) -> None:
    side_p = cube.with_name("cube.asset.json")
    side = json.loads(side_p.read_text())
    c = np.asarray(side["bounds"]["center"])
    side["bounds"]["max"] = list(c + (np.asarray(side["bounds"]["max"]) - c) * factor)
    side_p.write_text(json.dumps(side))


def test_reports_name_measured_value_and_tolerance(tmp_path: Path, cube: Path) -> None:
    _shrink_bounds(cube, 0.9)
    r = validate_model(cube, OPTS, isolate=False)
    b = r.check("bounds")
    # 1e-5 of the diagonal plus the 9-digit printing at the cube's coordinates (5e-9 of them)
    assert b is not None and b.status == "fail" and b.measured["outsideBox"] > b.tolerance["outsideBox"]
    assert 1e-5 < b.tolerance["outsideBox"] < 1.001e-5
    write_json_report([r], tmp_path / "r.json")
    write_junit_report([r], tmp_path / "r.xml")
    fail = json.loads((tmp_path / "r.json").read_text())["failures"]
    entry = next(f for f in fail if f["check"] == "bounds")
    assert entry["model"] == "cube" and entry["tolerance"]["outsideBox"] == b.tolerance["outsideBox"]
    assert entry["measured"]["outsideBox"] == pytest.approx(b.measured["outsideBox"])
    case = next(c for c in ET.parse(tmp_path / "r.xml").getroot().iter("testcase") if c.get("name") == "bounds")
    assert case.find("failure").get("message").startswith("bounds: outsideBox measured ")


def test_baseline_accepts_known_differences_and_catches_regressions(tmp_path: Path, cube: Path) -> None:
    from assetpipe.renderer.baseline import apply_baseline, baseline_of

    _shrink_bounds(cube, 0.9)
    known = baseline_of([validate_model(cube, OPTS, isolate=False)])["models"]
    assert set(known["cube"]) == {"bounds", "silhouette"}  # the silhouette exceeds the projected bounds too
    r = apply_baseline(validate_model(cube, OPTS, isolate=False), known)
    assert r.passed and r.check("bounds").accepted.startswith("accepted by the baseline")
    _shrink_bounds(cube, 0.5)  # a regression: the vertices stick out further than accepted
    r = apply_baseline(validate_model(cube, OPTS, isolate=False), known)
    assert not r.passed and r.check("bounds").accepted is None and r.check("bounds").status == "fail"


def test_cli_json_option_baseline_and_jobs(tmp_path: Path, cube: Path) -> None:
    from click.testing import CliRunner

    from assetpipe.renderer.cli_commands import validate

    _shrink_bounds(cube, 0.9)
    runner = CliRunner()
    base = ["--size", "96", "--checks", "load,bounds,textures"]
    res = runner.invoke(validate, [str(cube), "--in-process", *base, "--json", str(tmp_path / "a.json"),
                                   "--write-baseline", str(tmp_path / "base.json")])
    assert res.exit_code == 1 and "bounds [outsideBox" in res.output, res.output
    assert json.loads((tmp_path / "a.json").read_text())["summary"]["failed"] == 1
    res = runner.invoke(validate, [str(cube), str(CUBE), *base, "-j", "2", "--baseline", str(tmp_path / "base.json"),
                                   "--json-report", str(tmp_path / "b.json")])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "b.json").read_text())
    assert doc["summary"] == {"models": 2, "passed": 2, "failed": 0, "acceptedByBaseline": 1}
    res = runner.invoke(validate, ["--list-checks"])
    assert res.exit_code == 0 and all(f"{n}\n  measures:" in res.output for n in ("load", "roles", "lods"))


def test_open_edges_are_compared_per_mesh() -> None:
    """A hole in a small part of a large model: under 0.05 of the model's diagonal, 0.5 of the part's."""
    import numpy as np

    from assetpipe.renderer.checks.lods import boundary_lengths, mesh_diagonals
    from assetpipe.renderer.loader import Lod, Material, Mesh, RenderModel

    def grid(n: int, size: float, x0: float) -> tuple[np.ndarray, np.ndarray]:
        y, x = np.mgrid[0:n + 1, 0:n + 1]
        pos = np.c_[x0 + x.ravel() * size / n, y.ravel() * size / n, np.zeros(x.size)].astype(np.float32)
        q = (y[:-1, :-1] * (n + 1) + x[:-1, :-1]).ravel()
        tris = np.r_[np.c_[q, q + 1, q + n + 2], np.c_[q, q + n + 2, q + n + 1]].astype(np.uint32)
        return pos, tris

    big_p, big_t = grid(4, 100.0, 0.0)
    small_p, small_t = grid(4, 1.0, 200.0)
    holed = small_t[~np.isin(np.arange(len(small_t)), [5, 21])]  # the two halves of one inner quad
    idx = np.r_[big_t.ravel(), small_t.ravel(), big_t.ravel(), holed.ravel()].astype(np.uint32)
    nb, ns = big_t.size, small_t.size
    meshes = [Mesh("big", 0, 0, len(big_p), [Lod(0, 0, nb), Lod(1, nb + ns, nb)], np.zeros(3)),
              Mesh("small", 0, len(big_p), len(small_p), [Lod(0, nb, ns), Lod(1, 2 * nb + ns, holed.size)],
                   np.zeros(3))]
    pos = np.r_[big_p, small_p]
    model = RenderModel("m", pos, np.zeros((len(pos), 2), np.float32), np.ones((len(pos), 4), np.float32), idx,
                        meshes, [Material("m")], pos.min(0), pos.max(0), np.zeros(3), 1.0)
    grown = boundary_lengths(model, 1) - boundary_lengths(model, 0)
    diag = float(np.linalg.norm(pos.max(0) - pos.min(0)))
    assert grown[0] == 0 and abs(grown[1] - 4 * 0.25) < 1e-6  # the hole's four edges, 0.25 each
    assert grown.sum() / diag < 0.05 < grown[1] / mesh_diagonals(model)[1]


@pytest.mark.corpus
def test_sparse_accessors_are_applied_to_the_source_reference(corpus) -> None:
    """trimesh ignores sparse accessors; the reference applies them (SimpleSparseAccessor moves three
    vertices up to y = 4; trimesh alone reads a maximum of 1)."""
    from assetpipe.renderer.source_model import load_source_model

    src = corpus / "models" / "SimpleSparseAccessor" / "glTF" / "SimpleSparseAccessor.gltf"
    model = load_source_model(src)
    assert model.sidecar["sparseApplied"] and float(model.positions[:, 1].max()) == 4.0


def test_wires_thinner_than_a_pixel_are_judged_on_a_finer_sampling(tmp_path: Path) -> None:
    """A good model with wires under a pixel wide: at one sample a pixel its silhouette box misses
    a wire's tip and its coarse LOD's dotted wires fall apart from LOD0's, so both checks fail
    it; rendered again at ``supersample`` x the pixels a side (judged in the same pixel units)
    it passes. The control with ``supersample=1`` keeps the false alarm in sight."""
    from click.testing import CliRunner

    from assetpipe.cli import main

    from validate_assets import write_wires_obj

    src = write_wires_obj(tmp_path / "wires.obj")
    # levels over LOD0's vertices: with moved vertices (the default since LOD step 19) its LOD4
    # turns triangles of some wires away where the first view sees them and fails lods by 80 px
    # (budget 45), rightly; the in-place levels turn as many away but not where that view looks
    # (docs/VALIDATE.md, "Known, left")
    r = CliRunner().invoke(main, ["build", str(src), "-o", str(tmp_path / "out"), "--cache",
                                  str(tmp_path / "cache"), "-j", "1", "-q", "--no-lod-move"])
    assert r.exit_code == 0, r.output
    model = tmp_path / "out" / "wires.json"
    coarse = validate_model(model, ValidateOptions(supersample=1), isolate=False)
    assert coarse.check("silhouette").status == "fail" and coarse.check("lods").status == "fail", coarse.failures()
    fine = validate_model(model, ValidateOptions(), isolate=False)
    assert fine.passed, fine.failures()
    sil, lods = fine.check("silhouette"), fine.check("lods")
    second = [v["supersampledBoxErrorPx"] for v in sil.figures["views"] if "supersampledBoxErrorPx" in v] + \
             [lv["supersampledUnexplainedPx"] for lv in lods.figures["perLevel"] if "supersampledUnexplainedPx" in lv]
    assert len(second) >= 2, (sil.figures, lods.figures)  # the second look decided both


def test_a_ring_is_judged_where_it_has_geometry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A thin ring (torus, radius 1, tube 0.03): at LOD1's switch distance the lods picture, capped
    at lod_max_render_px, shows only the middle of the model, where a ring has nothing. The check
    then aims at the drawn LOD0 vertex nearest the centre (same distance and field of view)
    instead of failing with "LOD0 covers no pixel"; the control without that aim fails."""
    import trimesh
    from click.testing import CliRunner

    from assetpipe.cli import main
    from assetpipe.renderer.checks import lods as lods_check

    trimesh.creation.torus(1.0, 0.03, major_sections=256, minor_sections=16).export(tmp_path / "ring.obj")
    r = CliRunner().invoke(main, ["build", str(tmp_path / "ring.obj"), "-o", str(tmp_path / "out"), "--cache",
                                  str(tmp_path / "cache"), "-j", "1", "-q"])
    assert r.exit_code == 0, r.output
    model = tmp_path / "out" / "ring.json"
    res = validate_model(model, ValidateOptions(checks=("load", "lods")), isolate=False)
    lods = res.check("lods")
    assert lods.status == "pass", lods.messages
    assert any(lv.get("aimedAtNearestVertex") for lv in lods.figures["perLevel"]), lods.figures
    assert all(lv["areaPx"] > 0 for lv in lods.figures["perLevel"])
    monkeypatch.setattr(lods_check, "nearest_drawn", lambda model, point: None)
    res = validate_model(model, ValidateOptions(checks=("load", "lods")), isolate=False)
    assert res.check("lods").status == "fail" and "covers no pixel" in " ".join(res.check("lods").messages)


def test_an_inside_out_model_is_named_as_such(tmp_path: Path) -> None:
    """A sphere whose triangles face inward shows only back faces from outside: the lods check,
    which judges front faces, says so instead of "LOD0 covers no pixel"."""
    import trimesh
    from click.testing import CliRunner

    from assetpipe.cli import main

    s = trimesh.creation.icosphere(4)
    s.invert()
    s.export(tmp_path / "inside_out.obj")
    r = CliRunner().invoke(main, ["build", str(tmp_path / "inside_out.obj"), "-o", str(tmp_path / "out"),
                                  "--cache", str(tmp_path / "cache"), "-j", "1", "-q"])
    assert r.exit_code == 0, r.output
    res = validate_model(tmp_path / "out" / "inside_out.json", ValidateOptions(checks=("load", "lods")),
                         isolate=False)
    lods = res.check("lods")
    assert lods.status == "fail" and "only back faces" in " ".join(lods.messages), lods.messages


def test_a_one_sided_sheet_facing_away_is_judged_from_its_front(tmp_path: Path) -> None:
    """A one-sided bumpy sheet facing away from the first view (a ceiling) shows only back faces
    there: the lods check judges it from the opposite side, where its front is (a closed model
    turned inside out shows back faces from both sides and still fails, test above)."""
    import trimesh
    from click.testing import CliRunner

    from assetpipe.cli import main

    n = 30
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    v = np.c_[x.ravel(), y.ravel(), 0.02 * np.sin(5 * x.ravel()) * np.cos(4 * y.ravel())]
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.r_[np.c_[a, a + 1, a + n + 1], np.c_[a, a + n + 1, a + n]]
    for name, rot in (("ceiling", np.diag([1.0, -1.0, -1.0])), ("floor", np.eye(3))):
        trimesh.Trimesh(v @ rot.T, f, process=False).export(tmp_path / f"{name}.obj")
    r = CliRunner().invoke(main, ["build", str(tmp_path / "ceiling.obj"), str(tmp_path / "floor.obj"), "-o",
                                  str(tmp_path / "out"), "--cache", str(tmp_path / "cache"), "-j", "1", "-q"])
    assert r.exit_code == 0, r.output
    flipped = {}
    for name in ("ceiling", "floor"):
        res = validate_model(tmp_path / "out" / f"{name}.json", ValidateOptions(checks=("load", "lods")),
                             isolate=False)
        lods = res.check("lods")
        assert lods.status == "pass", (name, lods.messages)
        flipped[name] = any(lv.get("seenFromOppositeSide") for lv in lods.figures["perLevel"])
    assert flipped == {"ceiling": True, "floor": False}  # the first view sees the floor's front


def test_a_gltf_factor_alpha_without_alpha_mode_is_opaque_in_the_reference(tmp_path: Path) -> None:
    """glTF's alphaMode defaults to OPAQUE whatever the base colour factor's alpha: the build
    draws such a material opaque, and so must the source reference (it blended it, and the
    source check failed a good model by 0.12 of colour). An MTL's dissolve below 1 stays
    blended on both sides."""
    from click.testing import CliRunner

    from assetpipe.cli import main
    from assetpipe.renderer.source_model import load_source_model

    from gltf_builder import GltfBuilder
    from validate_assets import sphere

    b = GltfBuilder()
    pos, nrm, _, _, idx = sphere()
    for k, alpha in enumerate((0.2, 0.6)):
        m = b.add_material(name=f"m{k}", pbrMetallicRoughness={"baseColorFactor": [0.9, 0.3 * k, 0.1, alpha]})
        b.add_node(mesh=b.add_triangles(pos + [2.5 * k, 0, 0], idx, material=m, NORMAL=nrm), name=f"s{k}")
    src = b.write_glb(tmp_path / "alpha.glb")
    assert all(m.alpha_mode == "OPAQUE" for m in load_source_model(src).materials)
    r = CliRunner().invoke(main, ["build", str(src), "-o", str(tmp_path / "out"), "--cache", str(tmp_path / "cache"),
                                  "-j", "1", "-q"])
    assert r.exit_code == 0, r.output
    res = validate_model(tmp_path / "out" / "alpha.json", ValidateOptions(source_root=str(tmp_path)), isolate=False)
    assert res.check("source").status == "pass", res.check("source").messages

    (tmp_path / "d.obj").write_text("mtllib d.mtl\nusemtl glass\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "d.mtl").write_text("newmtl glass\nKd 0.2 0.4 0.8\nd 0.5\n")
    assert load_source_model(tmp_path / "d.obj").materials[0].alpha_mode == "BLEND"


@pytest.mark.parametrize("indexed", [False, True])
def test_triangle_fans_are_compared_with_their_source(tmp_path: Path, indexed: bool) -> None:
    """trimesh's glTF reader drops TRIANGLE_FAN primitives: the source check had nothing to
    compare (a skip), so a build with its winding reversed passed (4 missed mutations on the
    corpus's Mesh_PrimitiveMode fans). The reference now reads a fan as the spec's triangles
    {v[i+1], v[i+2], v[0]}: the good build passes the source check, the reversed one fails it."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from gltf_builder import GltfBuilder

    from assetpipe.api import build
    from assetpipe.renderer.source_model import load_source_model

    pentagon = np.array([[0, 0, 0], [1, 0, 0], [1.3, 0.8, 0], [0.5, 1.4, 0], [-0.3, 0.8, 0]], np.float32)
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(pentagon, [0, 1, 2, 3, 4] if indexed else None, mode=6))
    (tmp_path / "src").mkdir()
    src = b.write_gltf(tmp_path / "src" / "fan.gltf")
    ref = load_source_model(src)
    tri = ref.indices.reshape(-1, 3)
    assert tri.shape == (3, 3)  # five vertices: three fan triangles
    # each one counter-clockwise seen from +z, as the fan winds: {v1, v2, v0}, {v2, v3, v0}, ...
    p = ref.positions[tri]
    assert (np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2] > 0).all()
    out = tmp_path / "out"
    assert not build([src], out, jobs=1, cache_dir=tmp_path / "cache").failed
    r = validate_model(out / "fan.json", OPTS, isolate=False)
    assert r.check("source").status == "pass", r.check("source")
    idx = out / "fan.idx"
    a = np.fromfile(idx, "<u4").reshape(-1, 3)
    a[:, [1, 2]] = a[:, [2, 1]]
    a.tofile(idx)
    r = validate_model(out / "fan.json", OPTS, isolate=False)
    assert r.check("source").status == "fail"


@pytest.mark.parametrize("name", ["cube.json", "cube-mat.json", "cube.asset.json"])
def test_a_value_of_another_shape_fails_a_check_and_never_raises(cube: Path, name: str) -> None:
    # every value of the three JSON files replaced in turn by "x", null or []: each run ends in a
    # report (a failed load or check naming the problem), never an exception (an offset that was
    # a string, a null materials list, a texture whose width was null were raised from the
    # loader or the textures and source checks, 141 of 615 such edits of a built example)
    path = cube.parent / name
    doc = json.loads(path.read_text())
    failed = 0
    for where in list(value_paths(doc, first=2)):
        for value in ("x", None, []):
            path.write_text(json.dumps(with_value(doc, where, value)))
            r = validate_model(cube, dataclasses.replace(OPTS, width=32, height=32, supersample=1), isolate=False)
            failed += not r.passed
    assert failed > 0  # the edits reach the checks
