"""Team defaults from assetpipe.toml / [tool.assetpipe]: found from the inputs upward, overridden by
flags, explained by --explain; bad files are one clear error."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from assetpipe.cli import main
from assetpipe.project_config import ProjectConfigError, find_project_file, load_project_file, project_config_for

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def proj(tmp_path):
    shutil.copytree(REPO / "examples" / "pyramid", tmp_path / "proj" / "art" / "pyramid")
    return tmp_path


def build(proj: Path, *args: str):
    r = CliRunner().invoke(main, ["build", str(proj / "proj" / "art"), "-o", str(proj / "out"),
                                  "--cache", str(proj / "cache"), "--json", str(proj / "r.json"), *args])
    return r


def layout_of(proj: Path) -> list[str]:
    side = json.loads((proj / "out" / "pyramid.asset.json").read_text())
    return [a["name"] for a in side["vertexLayout"]["attributes"]]


def test_assetpipe_toml_sets_the_options_and_flags_override_it(proj):
    (proj / "proj" / "assetpipe.toml").write_text('layout = ["position", "uv0", "normal"]\nlod = false\njobs = 1\n')
    r = build(proj, "--explain")
    assert r.exit_code == 0, r.output
    assert layout_of(proj) == ["position", "uv0", "normal"]
    where = str(proj / "proj" / "assetpipe.toml")
    assert f"option layout: position,uv0,normal ({where})" in r.output
    assert f"option no-lod: True ({where})" in r.output
    assert "option simplifier: meshopt-attr (default)" in r.output
    r = build(proj, "--layout", "position,uv0", "--explain")
    assert r.exit_code == 0 and layout_of(proj) == ["position", "uv0"]
    assert "option layout: position,uv0 (command line)" in r.output


def test_pyproject_tool_table_is_found_from_the_inputs_upward(proj):
    (proj / "pyproject.toml").write_text('[project]\nname = "game"\n\n[tool.assetpipe]\nlayout = "position,normal"\n')
    (proj / "proj" / "pyproject.toml").write_text('[project]\nname = "no-table-here"\n')  # skipped: no [tool.assetpipe]
    assert find_project_file(proj / "proj" / "art" / "pyramid" / "pyramid.obj") == proj / "pyproject.toml"
    r = build(proj, "-j", "1")
    assert r.exit_code == 0, r.output
    assert layout_of(proj) == ["position", "normal"]


def test_cache_is_relative_to_the_project_file(proj):
    (proj / "proj" / "assetpipe.toml").write_text('cache = "../team-cache"\n')
    cfg = project_config_for([proj / "proj" / "art"])
    assert cfg.as_cli()["cache_dir"] == proj / "team-cache"


@pytest.mark.parametrize("text, message", [
    ("colour = 1\n", "unknown key 'colour'"),
    ("jobs = true\n", "jobs must be a whole number of worker processes, not True"),
    ("lod = 'no'\n", "lod must be true or false"),
    ("layout = [\n", "invalid TOML"),
])
def test_a_bad_project_file_is_one_clear_error(proj, text, message):
    f = proj / "proj" / "assetpipe.toml"
    f.write_text(text)
    with pytest.raises(ProjectConfigError, match=f"^{re.escape(str(f))}: .*{re.escape(message)}"):
        load_project_file(f)
    r = build(proj)
    assert r.exit_code == 1 and message in r.output and str(f) in r.output


def test_inputs_under_different_project_files_are_refused(tmp_path):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "assetpipe.toml").write_text("jobs = 1\n")
    with pytest.raises(ProjectConfigError, match="the inputs lie under different project files"):
        project_config_for([tmp_path / "a", tmp_path / "b"])


@pytest.mark.parametrize("key, field", [("lod_balance", "balance_meshes"), ("lod_move", "move_vertices")])
def test_lod_switches_from_the_project_file_and_the_flag(proj, key, field):
    """lod_balance (--lod-balance/--no-lod-balance) reaches LodOptions.balance_meshes, lod_move
    (--lod-move/--no-lod-move) LodOptions.move_vertices (what it does to the levels:
    tests/test_lod_model.py); the default is LodOptions' own."""
    from assetpipe.cli import _build_options
    from assetpipe.options import DEFAULT_BUILD_OPTIONS

    assert getattr(_build_options("position,uv0", None, False, None, False, None).lod, field) \
        is getattr(DEFAULT_BUILD_OPTIONS.lod, field)
    assert getattr(_build_options("position,uv0", None, False, None, False, None, **{key: False}).lod, field) is False
    flag = key.replace("_", "-")
    (proj / "proj" / "assetpipe.toml").write_text(f"{key} = false\njobs = 1\n")
    r = build(proj, "--explain")
    assert r.exit_code == 0, r.output
    assert f"option {flag}: False ({proj / 'proj' / 'assetpipe.toml'})" in r.output
    r = build(proj, f"--{flag}", "--explain")
    assert r.exit_code == 0 and f"option {flag}: True (command line)" in r.output
    (proj / "proj" / "assetpipe.toml").write_text(f'{key} = "no"\n')
    r = build(proj)
    assert r.exit_code != 0 and key in r.output


@pytest.mark.parametrize("text, message", [
    ("jobs = 0\n", ": jobs: 0 is not in the range 1<=x<=256"),
    ("jobs = 99999999999999999999\n", ": jobs: 99999999999999999999 is not in the range 1<=x<=256"),
    ("max_model_mb = inf\n", ": max_model_mb: inf is not a finite number"),
    ("max_coordinate = nan\n", ": max_coordinate: nan is not a finite number"),
    ("simplifier = 'fast'\n", ": simplifier: 'fast' is not one of"),
    ("layout = [1, 2]\n", "layout must be vertex attributes"),
    ("lod_ratios = '1,1/0'\n", "the ratio '1/0' divides by zero"),
    ("lod_screen_sizes = [400, 'x']\n", "lod_screen_sizes must be on-screen sizes"),
    ("cache = ''\n", "cache must be a folder, relative to the project file, not an empty string"),
])
def test_project_file_values_pass_the_options_own_checks(proj, text, message):
    # (the first seven were tracebacks or taken as given: the file's values skipped the options'
    # ranges and choices, which a flag goes through)
    f = proj / "proj" / "assetpipe.toml"
    f.write_text(text)
    r = build(proj)
    assert r.exit_code in (1, 2), r.output
    assert isinstance(r.exception, SystemExit), r.exception
    assert message in r.output, r.output
    assert str(f) in r.output or "lod_ratios" in text  # a ratio's error is the command line's own
