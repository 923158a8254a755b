"""Input budgets (pipelines/budgets.py) as build options (#13): set from the command line or the
project file, shown by --explain, and part of the import step's cache key."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from assetpipe.cli import main
from assetpipe.options import DEFAULT_BUILD_OPTIONS
from assetpipe.pipelines.budgets import DEFAULT_INPUT_BUDGETS, InputBudgets

QUAD = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"  # 2 triangles


@pytest.fixture
def proj(tmp_path: Path) -> Path:
    (tmp_path / "art").mkdir()
    (tmp_path / "art" / "quad.obj").write_text(QUAD)
    return tmp_path


def build(proj: Path, *args: str):
    return CliRunner().invoke(main, ["build", str(proj / "art"), "-o", str(proj / "out"), "--cache",
                                     str(proj / "cache"), "--json", str(proj / "r.json"), "-j", "1", "--no-lod",
                                     "--explain", *args])


def import_run(r) -> str | None:
    """The explain line of the import step ('new', 'option changed: ...'), None if it did not run."""
    for line in r.output.splitlines():
        if line.strip().startswith("import:"):
            return line.split(":", 1)[1].strip()
    return None


def test_build_options_carry_the_default_budgets() -> None:
    assert DEFAULT_BUILD_OPTIONS.budgets == DEFAULT_INPUT_BUDGETS == InputBudgets()
    assert DEFAULT_BUILD_OPTIONS.to_json()["budgets"]["max_triangles"] == DEFAULT_INPUT_BUDGETS.max_triangles


def test_cli_budget_refuses_a_model_over_it_and_explain_names_the_source(proj: Path) -> None:
    r = build(proj, "--max-triangles", "1")
    assert r.exit_code == 1, r.output
    assert "option max-triangles: 1 (command line)" in r.output
    report = json.loads((proj / "r.json").read_text())
    [entry] = report["results"] if "results" in report else report["assets"]
    assert "quad.obj: has 2 triangles after triangulation: over the triangle budget of 1" in entry["error"]
    # the defaults, and where they came from
    r = build(proj)
    assert r.exit_code == 0, r.output
    for flag, value in (("max-triangles", DEFAULT_INPUT_BUDGETS.max_triangles),
                        ("max-placements", DEFAULT_INPUT_BUDGETS.max_placements),
                        ("max-model-mb", f"{DEFAULT_INPUT_BUDGETS.max_model_bytes / 2**20}"),
                        ("max-coordinate", f"{DEFAULT_INPUT_BUDGETS.max_coordinate}")):
        assert f"option {flag}: {value} (default)" in r.output


def test_project_file_sets_the_budgets(proj: Path) -> None:
    toml = proj / "assetpipe.toml"
    toml.write_text("max_coordinate = 0.5\n")
    r = build(proj)
    assert r.exit_code == 1, r.output
    assert f"option max-coordinate: 0.5 ({toml})" in r.output
    assert "has a coordinate beyond +-0.5" in (proj / "r.json").read_text()
    toml.write_text("max_triangles = 2\nmax_model_mb = 1\nmax_placements = 3\n")
    r = build(proj)
    assert r.exit_code == 0, r.output
    assert f"option max-triangles: 2 ({toml})" in r.output and f"option max-placements: 3 ({toml})" in r.output
    toml.write_text('max_triangles = "many"\n')
    r = build(proj)
    assert r.exit_code != 0 and "max_triangles must be a whole number of triangles" in r.output


def test_a_changed_budget_reruns_the_import_and_an_unchanged_one_does_not(proj: Path) -> None:
    assert import_run(build(proj, "--max-triangles", "100")) == "new"
    first = (proj / "out" / "quad.idx").read_bytes()
    r = build(proj, "--max-triangles", "100")
    assert r.exit_code == 0 and import_run(r) is None, r.output  # unchanged: nothing reruns
    (proj / "out" / "quad.json").unlink()  # an output gone: the build runs again, the import comes from the cache
    r = build(proj, "--max-triangles", "100")
    assert r.exit_code == 0 and import_run(r) is None, r.output
    r = build(proj, "--max-triangles", "200")
    assert import_run(r) == "option changed: max_triangles", r.output
    r = build(proj, "--max-coordinate", "1e6", "--max-triangles", "200")
    assert import_run(r) == "option changed: max_coordinate", r.output
    assert (proj / "out" / "quad.idx").read_bytes() == first  # same model: only the key changed


def _textured(proj: Path, width: int, height: int) -> None:
    import cv2
    import numpy as np

    (proj / "art" / "quad.obj").write_text("mtllib quad.mtl\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl a\n"
                                           + QUAD.replace("f 1 2 3\nf 1 3 4", "f 1/1 2/2 3/3\nf 1/1 3/3 4/4"))
    (proj / "art" / "quad.mtl").write_text("newmtl a\nmap_Kd wide.png\n")
    ok, buf = cv2.imencode(".png", np.full((height, width, 3), 90, np.uint8))
    (proj / "art" / "wide.png").write_bytes(buf.tobytes())


def test_an_oversize_texture_is_downscaled_with_a_warning_or_refused(proj: Path) -> None:
    # the build's cap (8192 by default; 20 here so the image stays small)
    _textured(proj, 40, 4)
    r = build(proj, "--max-texture-size", "20")
    assert r.exit_code == 0, r.output
    side = json.loads((proj / "out" / "quad.asset.json").read_text())
    assert ("wide.png: image 'wide.png' is 40x4, larger than the maximum texture size 20: built at 20x2 "
            "(1 top mip level(s) dropped; --max-texture-size 0 keeps the full size, --oversize-textures refuse "
            "refuses such images)") in side["warnings"]
    r = build(proj, "--max-texture-size", "20", "--oversize-textures", "refuse")
    assert r.exit_code == 0 and "option oversize-textures: refuse (command line)" in r.output, r.output
    side = json.loads((proj / "out" / "quad.asset.json").read_text())
    assert not any("built at" in w for w in side["warnings"])
    assert any("skipped" in w and "is 40x4: larger than the maximum texture size 20 (refused" in w
               for w in side["warnings"]), side["warnings"]
    # 0 lifts the cap: the full size, no warning
    r = build(proj, "--max-texture-size", "0")
    assert r.exit_code == 0 and "option max-texture-size: none (command line)" in r.output, r.output
    side = json.loads((proj / "out" / "quad.asset.json").read_text())
    assert not any("wide.png" in w for w in side["warnings"]), side["warnings"]
    # the project file: the same keys
    (proj / "assetpipe.toml").write_text('max_texture_size = 20\noversize_textures = "refuse"\n')
    r = build(proj)
    assert r.exit_code == 0, r.output
    assert f"option oversize-textures: refuse ({proj / 'assetpipe.toml'})" in r.output
    assert f"option max-texture-size: 20 ({proj / 'assetpipe.toml'})" in r.output
    side = json.loads((proj / "out" / "quad.asset.json").read_text())
    assert any("(refused" in w for w in side["warnings"])
