"""inspect's consistency check: a consistent build passes, each kind of corruption is reported."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from assetpipe.format import OutputLod, OutputMaterial, OutputMesh, encode_model
from assetpipe.inspect import check_model, summarize
from assetpipe.pipelines.mesh_options import ATTRIBUTE_COMPONENTS
from tests.json_edits import value_paths, with_value


def _build(out: Path) -> Path:
    """A small consistent model 'M' (two meshes, LODs, one textured material) written to ``out``."""
    meshes = []
    for k, (nv, lods) in enumerate([(4, [2, 1]), (5, [3, 2])]):
        v = np.zeros((nv, 5))
        v[:, 0] = np.arange(nv)
        v[:, 1] = k
        idx = [(np.arange(m * 3) % nv).astype(np.uint32).reshape(m, 3) for m in lods]
        meshes.append(OutputMesh(id=f"mesh-{k}-0", name=f"n{k}", material_id=f"M-mat-{k}", vertices=v,
                                 lods=tuple(OutputLod(indices=i, vertex_count=nv) for i in idx)))
    tex = {"baseColor": {"path": "textures/t.png", "ktx2": "textures/t-baseColor.ktx2", "width": 4,
                         "height": 4, "levels": 3, "colorSpace": "srgb", "vkFormat": 43, "texCoord": 0,
                         "sampler": {}}}
    mats = [OutputMaterial(id="M-mat-0", name="a", color=(1, 1, 1, 1), texture_path="textures/t.png",
                           alpha_mode="OPAQUE", alpha_cutoff=0.5, double_sided=False, transparent=False,
                           textures=tex),
            OutputMaterial(id="M-mat-1", name="b", color=(1, 0, 0, 1), texture_path="", alpha_mode="OPAQUE",
                           alpha_cutoff=0.5, double_sided=False, transparent=False)]
    files = encode_model("M", meshes, mats, ("position", "uv0"), ATTRIBUTE_COMPONENTS, stats={}, warnings=["w"],
                         sources=[], generator="test")
    for name, data in files.items():
        (out / name).write_bytes(data)
    (out / "textures").mkdir()
    (out / "textures" / "t.png").write_bytes(b"png")
    (out / "textures" / "t-baseColor.ktx2").write_bytes(b"ktx2")
    return out / "M.json"


def _edit_json(path: Path, fn) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


@pytest.fixture
def model(tmp_path) -> Path:
    return _build(tmp_path)


def _one(problems: list[str], *words: str) -> None:
    assert len(problems) >= 1, problems
    assert any(all(w in p for w in words) for p in problems), problems


def test_consistent_build_passes_and_summarises(model):
    assert check_model(model) == []
    text = summarize(model)
    assert "model M: 2 mesh(es), 2 material(s)" in text
    assert "mesh-1-0: 5 vertices, 3 triangles" in text and "LOD triangles 3 / 2" in text
    assert "baseColor 4x4 (3 levels)" in text and "warning: w" in text


def test_consistent_seed_only_build_passes(model):
    (model.parent / "M.asset.json").unlink()
    assert check_model(model) == []


def test_unknown_key_in_model(model):
    _edit_json(model, lambda d: d.update(extra=1))
    _one(check_model(model), "ID.json keys", "extra")


def test_unknown_key_in_mesh(model):
    _edit_json(model, lambda d: d["meshes"][1].update(lod=1))
    _one(check_model(model), "mesh mesh-1-0", "keys")


def test_unknown_key_in_material(model):
    _edit_json(model.parent / "M-mat.json", lambda d: d[0].update(roughness=1))
    _one(check_model(model), "material M-mat-0", "keys")


def test_missing_material(model):
    _edit_json(model.parent / "M-mat.json", lambda d: d.pop(1))
    _one(check_model(model), "mesh mesh-1-0", "materialId", "M-mat-1")


def test_truncated_vtx(model):
    vtx = model.parent / "M.vtx"
    vtx.write_bytes(vtx.read_bytes()[:-20])
    _one(check_model(model), "mesh mesh-1-0", "vertex range")


def test_vtx_not_a_multiple_of_the_stride(model):
    vtx = model.parent / "M.vtx"
    vtx.write_bytes(vtx.read_bytes()[:-6])
    _one(check_model(model), "M.vtx", "stride")


def test_truncated_idx(model):
    idx = model.parent / "M.idx"
    idx.write_bytes(idx.read_bytes()[:-12])
    _one(check_model(model), "mesh mesh-1-0 LOD1", "index range")


def test_out_of_range_index(model):
    idx = model.parent / "M.idx"
    data = bytearray(idx.read_bytes())
    seed = json.loads(model.read_text())["meshes"][0]
    struct.pack_into("<I", data, seed["idxOffset"] + 4, 4)  # mesh 0 has 4 vertices: 4 is one too many
    idx.write_bytes(bytes(data))
    _one(check_model(model), "mesh mesh-0-0 LOD0", "index 4 >= vertex count 4")


def test_out_of_range_index_in_a_coarser_level(model):
    idx = model.parent / "M.idx"
    side = json.loads((model.parent / "M.asset.json").read_text())
    lod1 = side["meshes"][1]["lods"][1]
    data = bytearray(idx.read_bytes())
    struct.pack_into("<I", data, lod1["idxOffset"], 99)
    idx.write_bytes(bytes(data))
    _one(check_model(model), "mesh mesh-1-0 LOD1", "index 99")


def test_misaligned_index_range(model):
    _edit_json(model, lambda d: d["meshes"][1].update(idxOffset=d["meshes"][1]["idxOffset"] + 2))
    problems = check_model(model)
    _one(problems, "mesh mesh-1-0 LOD0", "index range")


def test_index_range_not_whole_triangles(model):
    def f(d):
        d["meshes"][0]["idxSize"] -= 4
    _edit_json(model, f)
    _one(check_model(model), "mesh mesh-0-0 LOD0", "index range")


def test_misaligned_vertex_range(model):
    _edit_json(model, lambda d: d["meshes"][1].update(vtxOffset=d["meshes"][1]["vtxOffset"] + 4))
    _one(check_model(model), "mesh mesh-1-0", "vertex range")


def test_missing_texture(model):
    (model.parent / "textures" / "t.png").unlink()
    _one(check_model(model), "material M-mat-0", "texturePath textures/t.png does not exist")


def test_missing_ktx2(model):
    (model.parent / "textures" / "t-baseColor.ktx2").unlink()
    _one(check_model(model), "material M-mat-0", "baseColor ktx2")


def test_sidecar_lod0_differs_from_the_seed_range(model):
    _edit_json(model.parent / "M.asset.json", lambda d: d["meshes"][0]["lods"][0].update(idxSize=12))
    _one(check_model(model), "mesh mesh-0-0", "sidecar lods[0]")


def test_sidecar_vertex_count_differs(model):
    _edit_json(model.parent / "M.asset.json", lambda d: d["meshes"][1].update(vertexCount=4))
    _one(check_model(model), "mesh mesh-1-0", "vertexCount")


def test_non_finite_float_in_vtx(model):
    vtx = model.parent / "M.vtx"
    data = bytearray(vtx.read_bytes())
    struct.pack_into("<f", data, 24, float("nan"))
    struct.pack_into("<f", data, 28, float("inf"))
    vtx.write_bytes(bytes(data))
    _one(check_model(model), "M.vtx", "2 non-finite floats")


def test_non_finite_float_in_material_color(model):
    mat = model.parent / "M-mat.json"
    mat.write_text(mat.read_text().replace("[\n      1.0,\n      0.0,", "[\n      NaN,\n      0.0,"))
    assert "NaN" in mat.read_text()
    _one(check_model(model), "material M-mat-1", "color")


def test_duplicate_mesh_id(model):
    _edit_json(model, lambda d: d["meshes"][1].update(id="mesh-0-0"))
    _one(check_model(model), "mesh id mesh-0-0 is not unique")


def test_unreadable_files_reported_not_raised(model):
    (model.parent / "M.idx").unlink()
    _one(check_model(model), "cannot read the binary files")
    (model.parent / "M-mat.json").unlink()
    _one(check_model(model), "cannot read the model files")


def test_lod_index_beyond_its_vertex_count_prefix(model):
    side_path = model.parent / "M.asset.json"
    _edit_json(side_path, lambda d: d["meshes"][1]["lods"][1].update(vertexCount=2))  # LOD1 uses vertices 0..4
    _one(check_model(model), "mesh mesh-1-0 LOD1")


@pytest.mark.parametrize("name", ["M.json", "M-mat.json", "M.asset.json"])
def test_any_value_of_another_type_is_a_problem_not_a_crash(tmp_path, name):
    # (a sidecar without its vertexLayout, an ID-mat.json where ID.json belongs, ... were
    # tracebacks of the check or the summary; every value here is replaced by 5 of other types)
    from click.testing import CliRunner

    from assetpipe.cli import main

    runner = CliRunner()
    _build(tmp_path)
    path = tmp_path / name
    doc = json.loads(path.read_text())
    for where in list(value_paths(doc, first=3)):
        for value in ("x", -1, None, [], {"a": 1}):
            path.write_text(json.dumps(with_value(doc, where, value)))
            r = runner.invoke(main, ["inspect", str(tmp_path / "M.json")])
            assert r.exit_code in (0, 1) and (r.exception is None or isinstance(r.exception, SystemExit)), \
                (where, value, r.output, r.exception)
            assert ("consistent: yes" in r.output) == (r.exit_code == 0), (where, value, r.output)
    path.write_text(json.dumps(doc))
    assert check_model(tmp_path / "M.json") == []


@pytest.mark.parametrize("text", ['[{"id": "M-mat-0"}]', "\x00\x01", '{"id": "M", "meshes": [1]}'])
def test_a_file_that_is_not_a_model_is_one_problem(tmp_path, text):
    (tmp_path / "X.json").write_text(text)
    problems = check_model(tmp_path / "X.json")
    assert len(problems) == 1 and "cannot read the model files" in problems[0]
