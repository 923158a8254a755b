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
    with pytest.raises(AssetError) as err:
        import_gltf(path)
    assert "bad.gltf" in str(err.value) and "malformed glTF structure" in str(err.value)
    assert "\n" not in str(err.value)
