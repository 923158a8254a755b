"""Every file of ../shared/corpus/nasty/ ends in a correct build or one clear error line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from assetpipe.cli import main
from seed_loader import load_seed_model

# file -> (status, words the error or a warning must contain)
EXPECTED = {
    "BoxWithInfinites/BoxWithInfinites.glb": ("failed", ["BoxWithInfinites.glb", "NaN or infinite"]),
    "IndexOutOfRange/IndexOutOfRange.gltf": ("failed", ["IndexOutOfRange.gltf", "index 255 is out of range"]),
    "MissingBin/BoxTextured.gltf": ("failed", ["MissingBin/BoxTextured.gltf", "BoxTextured0.bin", "not found"]),
    "Fox-lfs-pointer/Fox.glb": ("failed", ["Fox.glb", "Git LFS pointer"]),
    "draco-2CylinderEngine/2CylinderEngine.gltf": ("built", []),
    "issue-295-huge-coords/issue-295-trianguation-failure.obj": ("built", []),
    "viking_room-missing-mtl/viking_room.obj": ("built", ["viking_room.mtl"]),
    "FlightHelmet-missing-textures/glTF/FlightHelmet.gltf": ("built", ["FlightHelmet_baseColor1.png"]),
}


@pytest.fixture(scope="module")
def nasty_build(corpus, tmp_path_factory):
    """One build of every nasty file plus one good model, as a user would run it."""
    tmp = tmp_path_factory.mktemp("nasty")
    out = tmp / "out"
    inputs = [str(corpus / "nasty" / rel) for rel in EXPECTED] + [str(corpus / "models/Duck/glTF/Duck.gltf")]
    r = CliRunner().invoke(main, ["build", *inputs, "-o", str(out), "--json", str(tmp / "report.json")])
    report = json.loads((tmp / "report.json").read_text())
    by_source = {a["source"]: a for a in report["assets"]}
    return r, out, by_source


def test_every_nasty_file_is_covered(corpus):
    on_disk = {p.relative_to(corpus / "nasty").as_posix() for p in (corpus / "nasty").rglob("*")
               if p.suffix.lower() in (".gltf", ".glb", ".obj")}
    assert on_disk == set(EXPECTED)


@pytest.mark.parametrize("rel", sorted(EXPECTED))
def test_nasty_outcome(nasty_build, corpus, rel):
    r, out, by_source = nasty_build
    entry = by_source[str(corpus / "nasty" / rel)]
    status, words = EXPECTED[rel]
    assert entry["status"] == status, entry
    if status == "failed":
        assert "\n" not in entry["error"] and "Traceback" not in entry["error"]
        for w in words:
            assert w in entry["error"], (w, entry["error"])
        assert entry["outputs"] == []
        assert not (out / f"{entry['id']}.json").exists()
    else:
        text = " ".join(entry["warnings"])
        for w in words:
            assert w in text, (w, entry["warnings"])
        model = load_seed_model(out / f"{entry['id']}.json")
        for m in model.meshes:
            assert np.isfinite(m.positions).all()
            assert int(m.indices.max()) < m.positions.shape[0]


def test_failures_do_not_stop_the_batch_and_set_the_exit_status(nasty_build):
    r, out, by_source = nasty_build
    assert r.exit_code == 1
    assert "Traceback" not in r.output
    failed_lines = [l for l in r.output.splitlines() if l.startswith("FAILED")]
    assert len(failed_lines) == 4
    assert (out / "Duck.json").exists()
    assert not list(out.rglob("*.tmp"))


def test_draco_geometry_is_decoded_not_dropped(nasty_build, corpus):
    _, out, by_source = nasty_build
    entry = by_source[str(corpus / "nasty/draco-2CylinderEngine/2CylinderEngine.gltf")]
    model = load_seed_model(out / f"{entry['id']}.json")
    # MANIFEST: 110336 triangles once instanced; the build drops degenerate ones and says so
    side = json.loads((out / f"{entry['id']}.asset.json").read_text())
    kept = sum(m.indices.shape[0] for m in model.meshes)
    assert kept + side["stats"]["degenerateTriangles"] == 110336


# -- generated hostile inputs (#13): one bad model never stops the batch --------------------------

def test_overflowing_models_fail_alone_with_one_line_each(tmp_path):
    """A node scale 1e300 and an OBJ 'v 1e308 1e308 1e308' overflowed to inf and crashed the whole
    build in canonical_json (traceback, exit 1, no --json report, the good model not built)."""
    import sys

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from gltf_builder import GltfBuilder

    src = tmp_path / "in"
    src.mkdir()
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), [0, 1, 2]),
               scale=[1e300, 1e300, 1e300])
    b.write_gltf(src / "scaled.gltf")
    (src / "huge.obj").write_text("v 1e308 1e308 1e308\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (src / "junk.obj").write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n\x00\x00junk\nf 1 2 3\n")
    (src / "good.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["build", str(src), "-o", str(out), "--no-lod", "--cache", str(tmp_path / "c"),
                                  "--json", str(tmp_path / "r.json")])
    assert r.exit_code == 1 and "Traceback" not in r.output, r.output
    report = {a["id"]: a for a in json.loads((tmp_path / "r.json").read_text())["assets"]}
    assert report["good"]["status"] == "built" and (out / "good.json").exists()
    assert report["junk"]["status"] == "built"
    assert "junk.obj: 1 line(s) with binary bytes skipped (line 4)" in " ".join(report["junk"]["warnings"])
    for name, words in (("scaled", "positions are non-finite or beyond"), ("huge", "has a coordinate beyond")):
        entry = report[name]
        assert entry["status"] == "failed" and "\n" not in entry["error"], entry
        assert entry["error"].startswith(str(src / f"{name}.")) and words in entry["error"], entry["error"]


def test_max_image_pixels_reaches_the_texture_step(tmp_path):
    from PIL import Image

    src = tmp_path / "in"
    src.mkdir()
    Image.new("RGBA", (64, 64), (200, 10, 10, 255)).save(src / "t.png")
    (src / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3\n")
    (src / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    args = ["build", str(src), "--no-lod", "--cache", str(tmp_path / "c"), "--json", str(tmp_path / "r.json")]
    r = CliRunner().invoke(main, args + ["-o", str(tmp_path / "small"), "--max-image-pixels", "100"])
    entry = json.loads((tmp_path / "r.json").read_text())["assets"][0]
    assert any("64x64 = 4096 pixels" in w and "over the limit of 100 RGBA8 texels" in w for w in entry["warnings"]), r.output
    r = CliRunner().invoke(main, args + ["-o", str(tmp_path / "default")])
    entry = json.loads((tmp_path / "r.json").read_text())["assets"][0]
    assert r.exit_code == 0 and not entry["warnings"], entry
