"""The glTF document view: attribute access like pygltflib's, and a structure check that turns
malformed documents into one clear line."""

from __future__ import annotations

import json

import pytest

from assetpipe.core.errors import AssetError
from assetpipe.pipelines.gltf_document import GltfObject, check_structure
from assetpipe.pipelines.import_gltf import import_gltf

GOOD = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4}],
        "bufferViews": [{"buffer": 0, "byteLength": 4}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 1, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "extensions": {"X": {"a": 1}}}]}]}


def test_view_reads_values_and_missing_keys_as_none():
    doc = GltfObject(GOOD)
    assert doc.accessors[0].componentType == 5126 and doc.accessors[0].byteOffset is None
    prim = doc.meshes[0].primitives[0]
    assert prim.attributes.POSITION == 0 and getattr(prim.attributes, "NORMAL") is None
    assert prim.extensions == {"X": {"a": 1}}  # extensions stay plain dicts
    assert doc.scenes is None and doc.asset.version == "2.0"


def test_a_sound_document_passes():
    assert check_structure(GOOD) is None


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d.update(accessors=5), "'accessors' is not an array"),
    (lambda d: d["accessors"].append(3), "accessors[1] is not an object"),
    (lambda d: d["accessors"][0].pop("count"), "accessors[0] has no 'count'"),
    (lambda d: d["accessors"][0].update(count="7"), "accessors[0].count has the wrong type"),
    (lambda d: d["accessors"][0].update(normalized=1), "accessors[0].normalized has the wrong type"),
    (lambda d: d["bufferViews"][0].update(buffer=True), "bufferViews[0].buffer has the wrong type"),
    (lambda d: d["meshes"][0]["primitives"].append("x"), "meshes[0].primitives[1] is not an object"),
    (lambda d: d["meshes"][0]["primitives"][0].update(indices=[1]), "primitives[0].indices has the wrong type"),
    (lambda d: d.update(scene="0"), "'scene' has the wrong type"),
])
def test_malformed_structures_are_one_clear_line(tmp_path, mutate, words):
    doc = json.loads(json.dumps(GOOD))
    mutate(doc)
    assert words in check_structure(doc)
    path = tmp_path / "bad.gltf"
    path.write_text(json.dumps(doc))
    with pytest.raises(AssetError, match='has a malformed glTF structure') as err:
        import_gltf(path)
    assert "bad.gltf" in str(err.value) and "malformed glTF structure" in str(err.value)
    assert "\n" not in str(err.value)


# -- hostile JSON (#13) ---------------------------------------------------------------------------

from assetpipe.pipelines.gltf_document import JsonError, load_json  # noqa: E402


@pytest.mark.parametrize("text,phrase", [
    ('{"a": NaN}', "non-standard JSON number NaN"),
    ('{"a": [-Infinity]}', "non-standard JSON number -Infinity"),
    ('{"a": 1e400}', "the number 1e400 in its JSON, which overflows a double"),
    ("[" * 100_000 + "]" * 100_000, "nests its JSON deeper than can be read"),
    ('{"a": ', "is not valid glTF JSON"),
])
def test_load_json_refuses_what_python_json_would_accept_or_crash_on(text, phrase):
    with pytest.raises(JsonError, match=phrase):
        load_json(text)


def test_load_json_reads_ordinary_numbers():
    assert load_json('{"a": [1, -2.5, 1e-300, 3.4e38]}') == {"a": [1, -2.5, 1e-300, 3.4e38]}


@pytest.mark.parametrize("edit,phrase", [
    (lambda d: d["nodes"].append({"children": [0, "x"]}), r"nodes\[1\]\.children is not a list of node indices"),
    (lambda d: d["nodes"].append({"scale": [1, 2]}), r"nodes\[1\]\.scale is not 3 numbers"),
    (lambda d: d["nodes"].append({"matrix": [1] * 15 + ["x"]}), r"nodes\[1\]\.matrix is not 16 numbers"),
    (lambda d: d["meshes"][0]["primitives"][0]["attributes"].__setitem__("NORMAL", "x"),
     r"attributes\.NORMAL is not an accessor index"),
    (lambda d: d["accessors"][0].__setitem__("sparse", {"count": 1, "indices": {}}),
     r"accessors\[0\]\.sparse\.indices\.bufferView is missing"),
    (lambda d: d["meshes"][0]["primitives"][0].__setitem__("indices", -1), r"primitives\[0\]\.indices is negative"),
])
def test_structure_check_covers_nested_values(edit, phrase):
    doc = json.loads(json.dumps(GOOD))
    doc.setdefault("nodes", []).append({"mesh": 0})
    doc.setdefault("meshes", [{"primitives": [{"attributes": {"POSITION": 0}}]}])
    doc.setdefault("accessors", [{"componentType": 5126, "count": 1, "type": "VEC3", "bufferView": 0}])
    assert check_structure(doc) is None
    edit(doc)
    problem = check_structure(doc)
    assert problem is not None and __import__("re").search(phrase, problem), problem
