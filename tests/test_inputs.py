"""Finding model files and giving each a unique, safe, deterministic id."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from assetpipe.core.errors import ConfigError
from assetpipe.inputs import assign_ids, discover_inputs


def _touch(root: Path, *rels: str) -> list[Path]:
    out = []
    for rel in rels:
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
        out.append(p)
    return out


# -- discovery --------------------------------------------------------------------------------

def test_discovery_is_recursive_sorted_and_case_insensitive_on_suffix(tmp_path):
    _touch(tmp_path, "b/z.gltf", "a/deep/er/m.GLB", "a/c.Obj", "top.obj", "a/x.bin", "a/tex.png",
           "notes.txt", "b/y.mtl", "a/gltf")
    found = discover_inputs([tmp_path])
    rel = [p.relative_to(tmp_path).as_posix() for p in found]
    assert rel == ["a/c.Obj", "a/deep/er/m.GLB", "b/z.gltf", "top.obj"]


def test_discovery_ignores_folders_named_like_models(tmp_path):
    (tmp_path / "weird.gltf").mkdir()
    _touch(tmp_path, "weird.gltf/inner.glb")
    assert [p.name for p in discover_inputs([tmp_path])] == ["inner.glb"]


def test_discovery_removes_duplicates_keeping_first_occurrence(tmp_path):
    a, b = _touch(tmp_path, "m/a.gltf", "m/b.obj")
    # named twice, named and inside a named folder, and by a different spelling of the same path
    found = discover_inputs([b, tmp_path / "m", tmp_path / "m" / ".." / "m" / "a.gltf", a])
    assert found == [b, a]


def test_discovery_keeps_argument_order_between_inputs(tmp_path):
    a, z = _touch(tmp_path, "a.obj", "z.obj")
    assert discover_inputs([z, a]) == [z, a]


def test_non_model_file_is_a_config_error(tmp_path):
    (p,) = _touch(tmp_path, "readme.txt")
    with pytest.raises(ConfigError, match=re.escape(str(p)) + ": not a model file"):
        discover_inputs([p])


def test_missing_path_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="no such file or folder"):
        discover_inputs([tmp_path / "nope.gltf"])


def test_empty_folder_finds_nothing(tmp_path):
    assert discover_inputs([tmp_path]) == []


# -- ids --------------------------------------------------------------------------------------

def test_ids_are_stems_when_unique(tmp_path):
    srcs = _touch(tmp_path, "a/Duck.gltf", "b/Box.glb", "Cube.obj")
    assert assign_ids(srcs) == dict(zip(srcs, ["Duck", "Box", "Cube"]))


def test_clashes_resolved_by_parent_folders(tmp_path):
    srcs = _touch(tmp_path, "a/Box.gltf", "b/Box.gltf", "x/Duck.gltf")
    ids = assign_ids(srcs)
    assert ids == dict(zip(srcs, ["a_Box", "b_Box", "Duck"]))


def test_clashes_go_up_as_many_folders_as_needed(tmp_path):
    srcs = _touch(tmp_path, "p/a/Box.gltf", "q/a/Box.gltf", "q/b/Box.gltf")
    ids = assign_ids(srcs)
    assert ids == dict(zip(srcs, ["p_a_Box", "q_a_Box", "b_Box"]))


def test_case_insensitive_clashes(tmp_path):
    srcs = _touch(tmp_path, "a/Box.gltf", "b/box.obj")
    ids = assign_ids(srcs)
    assert ids == dict(zip(srcs, ["a_Box", "b_box"]))
    assert len({i.lower() for i in ids.values()}) == 2


def test_same_stem_in_one_folder_is_told_apart_by_suffix(tmp_path):
    # Box.gltf and Box.obj side by side: no folder tells them apart. Their ids must still be
    # short, deterministic (not built from the absolute path) and leave other ids alone.
    srcs = _touch(tmp_path, "m/Box.gltf", "m/Box.obj", "m/Duck.gltf")
    ids = assign_ids(srcs)
    assert len(set(ids.values())) == 3
    assert ids[srcs[2]] == "Duck"
    assert ids[srcs[0]] == "Box_gltf" and ids[srcs[1]] == "Box_obj"
    assert str(tmp_path.name) not in "".join(ids.values())


def test_unsafe_characters_replaced(tmp_path):
    srcs = _touch(tmp_path, "My Model (v2).gltf", "caf\u00e9.obj", "#$%.glb", "a.b-c_d.gltf")
    ids = assign_ids(srcs)
    assert ids == dict(zip(srcs, ["My_Model_v2", "caf", "model", "a.b-c_d"]))
    for i in ids.values():
        assert re.fullmatch(r"[A-Za-z0-9._-]+", i)


def test_ids_are_unique_and_deterministic(tmp_path):
    rels = [f"{d}/{s}.gltf" for d in ("a", "b", "c") for s in ("Box", "box", "Duck", "x y")]
    srcs = _touch(tmp_path, *rels)
    ids = assign_ids(srcs)
    assert len({i.lower() for i in ids.values()}) == len(srcs)
    assert assign_ids(list(reversed(srcs))) == ids
    # a relative spelling of the same files gives the same ids
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        rel_srcs = [Path(r) for r in rels]
        assert [assign_ids(rel_srcs)[p] for p in rel_srcs] == [ids[p] for p in srcs]
    finally:
        os.chdir(cwd)


def test_names_differing_only_in_case_in_one_folder(tmp_path):
    srcs = _touch(tmp_path, "m/Box.gltf", "m/box.gltf", "m/Duck.obj")
    if len({p.name for p in (tmp_path / "m").iterdir()}) < 3:
        pytest.skip("case-insensitive file system")
    ids = assign_ids(srcs)
    assert ids == dict(zip(srcs, ["Box_gltf_0", "box_gltf_1", "Duck"]))


def test_ids_are_safe_file_names_even_for_dot_names(tmp_path):
    """#13: ``...obj`` was skipped in a folder but given the id ``..`` when named directly."""
    srcs = _touch(tmp_path, "...obj", "..gltf", ".hidden.obj", "_x_.glb", "a..b.obj")
    # a folder finds what naming finds (pathlib's suffix rule in both)
    assert sorted(p.name for p in discover_inputs([tmp_path])) == sorted(p.name for p in srcs)
    assert [p.name for p in discover_inputs([tmp_path / "...obj"])] == ["...obj"]
    ids = assign_ids(srcs)
    assert len({i.lower() for i in ids.values()}) == len(srcs)
    for i in ids.values():
        assert re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", i) and not i.endswith(".") and i not in (".", ".."), i
    assert {ids[srcs[0]], ids[srcs[1]]} == {"model_0", "model_1"}  # stems ".." and ".": nothing safe left
    assert ids[srcs[2]] == "hidden" and ids[srcs[3]] == "x" and ids[srcs[4]] == "a..b"
    # a path separator in a stem cannot reach an id either
    assert "/" not in "".join(assign_ids([tmp_path / "a" / "b.obj"]).values())


def test_discovery_walks_a_folder_reached_again_once(tmp_path):
    # a link to its own folder and a link to the folder above: the walk went 40 links deep and
    # raised ELOOP (with two such links it would have walked 2^40 paths)
    _touch(tmp_path, "art/a.obj", "art/sub/b.gltf")
    os.symlink(".", tmp_path / "art" / "again")
    os.symlink("..", tmp_path / "art" / "sub" / "up")
    os.symlink("/nonexistent-assetpipe", tmp_path / "art" / "dangling.obj")
    found = discover_inputs([tmp_path / "art"])
    assert [p.relative_to(tmp_path).as_posix() for p in found] == ["art/a.obj", "art/sub/b.gltf"]
