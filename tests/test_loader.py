"""Loading built models: the fixture loads, and broken builds are caught by name."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from assetpipe.core.errors import AssetError, InvalidGeometryError
from assetpipe.renderer.loader import decode_vertices, load_built_model

pytestmark = pytest.mark.vulkan
BUILT = Path(__file__).parent / "data" / "built"


@pytest.fixture()
def cube(tmp_path: Path) -> Path:
    """A private copy of the cube fixture (and its source) to break."""
    shutil.copytree(BUILT / "cube", tmp_path / "cube")
    shutil.copytree(BUILT / "src", tmp_path / "src")
    return tmp_path / "cube" / "cube.json"


def test_fixture_loads() -> None:
    m = load_built_model(BUILT / "cube" / "cube.json")
    assert [x.id for x in m.meshes] == ["mesh-0-0", "mesh-1-0"]
    assert m.triangles(0) == 50 and m.triangles(1) == 14
    assert m.lod_count == 2
    tex = m.materials[0].texture
    assert tex is not None and tex.from_ktx2 and [lv.shape for lv in tex.levels] == [
        (8, 8, 4), (4, 4, 4), (2, 2, 4), (1, 1, 4)]
    assert m.materials[1].alpha_mode == "BLEND" and m.materials[1].double_sided
    assert m.positions.shape == (58, 3) and m.notes == []


def test_index_out_of_range(cube: Path) -> None:
    idx = cube.with_name("cube.idx")
    a = np.fromfile(idx, "<u4")
    a[4] = 999
    a.tofile(idx)
    with pytest.raises(InvalidGeometryError, match="index 999 out of range"):
        load_built_model(cube)


def test_unknown_material_id(cube: Path) -> None:
    seed = json.loads(cube.read_text())
    seed["meshes"][0]["materialId"] = "cube-mat-7"
    cube.write_text(json.dumps(seed))
    with pytest.raises(AssetError, match="materialId 'cube-mat-7'"):
        load_built_model(cube)


def test_material_id_disagreeing_with_sidecar(cube: Path) -> None:
    seed = json.loads(cube.read_text())
    seed["meshes"][0]["materialId"] = "cube-mat-1"
    cube.write_text(json.dumps(seed))
    with pytest.raises(AssetError, match="differs from the sidecar"):
        load_built_model(cube)


@pytest.mark.parametrize("cut", [8, 20])
def test_truncated_vtx(cube: Path, cut: int) -> None:
    vtx = cube.with_name("cube.vtx")
    vtx.write_bytes(vtx.read_bytes()[:-cut])
    with pytest.raises(InvalidGeometryError, match="truncated"):
        load_built_model(cube)


def test_truncated_idx(cube: Path) -> None:
    idx = cube.with_name("cube.idx")
    idx.write_bytes(idx.read_bytes()[:-12])
    with pytest.raises(InvalidGeometryError, match="exceed"):
        load_built_model(cube)


def test_missing_ktx2_falls_back_to_png(cube: Path) -> None:
    side_path = cube.with_name("cube.asset.json")
    side = json.loads(side_path.read_text())
    del side["materials"][0]["textures"]["baseColor"]["ktx2"]
    side_path.write_text(json.dumps(side))
    m = load_built_model(cube)
    tex = m.materials[0].texture
    assert tex is not None and not tex.from_ktx2 and len(tex.levels) == 1
    assert any("no KTX2" in n for n in m.notes)


def test_decode_layout_with_colour() -> None:
    layout = {"stride": 28, "attributes": [{"name": "position", "format": "float32x3", "offset": 0},
                                           {"name": "color", "format": "float32x4", "offset": 12}]}
    raw = np.array([[1, 2, 3, 0.5, 0.25, 1, 1]], "<f4").tobytes()
    pos, uv, col = decode_vertices(raw, layout, Path("x.vtx"))
    assert pos.tolist() == [[1, 2, 3]] and uv.tolist() == [[0, 0]] and col.tolist() == [[0.5, 0.25, 1, 1]]


def test_frame_origin():
    """Where the validator draws a built model from: a recentred model's positionOffset, a far
    model's centre on float32's grid, else the origin."""
    from assetpipe.renderer.loader import FAR_RADII, frame_origin

    assert frame_origin({"positionOffset": [1e7, 2.5, -3.0]}).tolist() == [1e7, 2.5, -3.0]
    near = {"bounds": {"center": [10.0, 0.0, 0.0], "radius": 1.0}}
    assert not frame_origin(near).any()  # 10 radii: float32 draws it as well as at the origin
    far_c = [2000000.1, -1000000.3, 5.0]
    o = frame_origin({"bounds": {"center": far_c, "radius": 3.0}})
    assert o.tolist() == np.float32(far_c).astype(np.float64).tolist() and o.dtype == np.float64
    edge = FAR_RADII * 2.0
    assert not frame_origin({"bounds": {"center": [edge, 0, 0], "radius": 2.0}}).any()
    assert frame_origin({"bounds": {"center": [edge * 1.01, 0, 0], "radius": 2.0}}).any()
    for bad in (None, {}, {"bounds": {"center": "x"}}, {"bounds": {"center": [float("nan"), 0, 0], "radius": 1}},
                {"positionOffset": [1, 2]}, {"positionOffset": ["a", "b", "c"]}, {"positionOffset": {"x": 1}}):
        assert not frame_origin(bad).any()


@pytest.mark.parametrize("offset", [[1, 2], ["a", "b", "c"], [1, float("inf"), 0], "far"])
def test_a_bad_position_offset_is_one_clear_error(tmp_path, offset):
    cube = tmp_path / "cube"
    shutil.copytree(BUILT / "cube", cube)
    side_path = cube / "cube.asset.json"
    side = json.loads(side_path.read_text())
    side["positionOffset"] = offset
    side_path.write_text(json.dumps(side))
    with pytest.raises(AssetError, match="positionOffset is not three finite numbers"):
        load_built_model(cube / "cube.json")
