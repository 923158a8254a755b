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
