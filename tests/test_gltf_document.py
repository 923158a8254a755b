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


def test_a_wrapped_list_or_object_is_made_once():
    """Reading ``doc.accessors[i]`` for each of many accessors wraps the list once, not once a
    read (the importer reads a large model's accessors thousands of times)."""
    doc = GltfObject(GOOD)
    assert doc.accessors is doc.accessors and doc.meshes[0] is doc.meshes[0]
    assert doc.meshes[0].primitives[0].attributes is doc.meshes[0].primitives[0].attributes
    assert doc.accessors[0].count == 1 and doc.accessors[0].byteOffset is None


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


# -- materials, texture references and extensions (fuzz seed 28: an int where a texture
# reference belongs reached the importer as an AttributeError) ----------------------------------

MATERIAL_DOC = {
    "asset": {"version": "2.0"}, "textures": [{"source": 0}], "images": [{"uri": "a.png"}],
    "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "texCoord": 0},
                                            "baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.5},
                   "normalTexture": {"index": 0, "scale": 1.0}, "emissiveFactor": [0, 0, 0],
                   "extensions": {"KHR_materials_pbrSpecularGlossiness": {
                       "diffuseTexture": {"index": 0, "extensions": {"KHR_texture_transform": {
                           "offset": [0, 0], "scale": [2, 2], "rotation": 0.5, "texCoord": 0}}},
                       "diffuseFactor": [1, 1, 1, 1], "specularFactor": [1, 1, 1], "glossinessFactor": 1}}}],
    "buffers": [{"byteLength": 4}], "bufferViews": [{"buffer": 0, "byteLength": 4}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "extensions": {
        "KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}}}]}],
    "extensionsUsed": ["KHR_draco_mesh_compression", "KHR_texture_transform"],
}


def _pbr(d):
    return d["materials"][0]["pbrMetallicRoughness"]


def _sg(d):
    return d["materials"][0]["extensions"]["KHR_materials_pbrSpecularGlossiness"]


@pytest.mark.parametrize("edit,phrase", [
    (lambda d: _pbr(d).update(baseColorTexture=1000000000),
     r"pbrMetallicRoughness\.baseColorTexture is not a texture reference"),
    (lambda d: _pbr(d).update(metallicRoughnessTexture=[1]), r"metallicRoughnessTexture is not a texture reference"),
    (lambda d: _pbr(d)["baseColorTexture"].update(index="0"), r"baseColorTexture\.index is missing or not a texture index"),
    (lambda d: _pbr(d)["baseColorTexture"].pop("index"), r"baseColorTexture\.index is missing"),
    (lambda d: _pbr(d)["baseColorTexture"].update(texCoord=-1), r"baseColorTexture\.texCoord is not a non-negative integer"),
    (lambda d: _pbr(d).update(baseColorFactor="red"), r"baseColorFactor is not 4 numbers"),
    (lambda d: _pbr(d).update(baseColorFactor=[1, 1, 1]), r"baseColorFactor is not 4 numbers"),
    (lambda d: _pbr(d).update(roughnessFactor=[1]), r"roughnessFactor is not a number"),
    (lambda d: d["materials"][0].update(emissiveFactor=["a", 1, 1]), r"materials\[0\]\.emissiveFactor is not 3 numbers"),
    (lambda d: d["materials"][0]["normalTexture"].update(scale="x"), r"normalTexture\.scale is not a number"),
    (lambda d: d["materials"][0].update(extensions=[1]), r"materials\[0\]\.extensions is not an object"),
    (lambda d: d["materials"][0]["extensions"].update(KHR_materials_pbrSpecularGlossiness="x"),
     r"KHR_materials_pbrSpecularGlossiness is not an object"),
    (lambda d: _sg(d).update(diffuseTexture=3), r"diffuseTexture is not a texture reference"),
    (lambda d: _sg(d).update(diffuseFactor="x"), r"diffuseFactor is not 4 numbers"),
    (lambda d: _sg(d)["diffuseTexture"]["extensions"].update(KHR_texture_transform="x"),
     r"KHR_texture_transform is not an object"),
    (lambda d: _sg(d)["diffuseTexture"]["extensions"]["KHR_texture_transform"].update(offset=[1, 2, 3]),
     r"KHR_texture_transform\.offset is not 2 numbers"),
    (lambda d: _sg(d)["diffuseTexture"]["extensions"]["KHR_texture_transform"].update(rotation=[1]),
     r"KHR_texture_transform\.rotation is not a number"),
    (lambda d: _sg(d)["diffuseTexture"]["extensions"]["KHR_texture_transform"].update(texCoord="a"),
     r"KHR_texture_transform\.texCoord is not a non-negative integer"),
    (lambda d: d["meshes"][0]["primitives"][0].update(extensions=[1]), r"primitives\[0\]\.extensions is not an object"),
    (lambda d: d["meshes"][0]["primitives"][0]["extensions"].update(KHR_draco_mesh_compression="x"),
     r"KHR_draco_mesh_compression is not an object"),
    (lambda d: d["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"].update(bufferView="a"),
     r"KHR_draco_mesh_compression\.bufferView is missing or not a buffer view index"),
    (lambda d: d["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"].update(
        attributes={"POSITION": "a"}), r"KHR_draco_mesh_compression\.attributes is not an object of attribute ids"),
    (lambda d: d["bufferViews"][0].update(extensions=[1]), r"bufferViews\[0\]\.extensions is not an object"),
    (lambda d: d["textures"][0].update(extensions={"KHR_texture_basisu": {"source": "x"}}),
     r"textures\[0\]\.extensions\.KHR_texture_basisu\.source is not an image index"),
    (lambda d: d.update(extensionsRequired=[1]), r"'extensionsRequired' is not a list of extension names"),
    (lambda d: d["meshes"][0].update(weights=[0.5, [1]]), r"meshes\[0\]\.weights is not a list of numbers"),
])
def test_materials_and_extensions_are_checked_before_the_importer_reads_them(tmp_path, edit, phrase):
    doc = json.loads(json.dumps(MATERIAL_DOC))
    assert check_structure(doc) is None
    edit(doc)
    problem = check_structure(doc)
    assert problem is not None and __import__("re").search(phrase, problem), problem
    path = tmp_path / "bad.gltf"
    path.write_text(json.dumps(doc))
    with pytest.raises(AssetError, match="has a malformed glTF structure") as err:
        import_gltf(path)
    assert "bad.gltf" in str(err.value) and "\n" not in str(err.value)


def test_a_texture_transform_property_given_as_null_counts_as_absent():
    import numpy as np

    from assetpipe.pipelines.import_gltf import _uv_transform

    assert np.array_equal(_uv_transform({"offset": None, "rotation": None, "scale": None}), np.eye(3))
    assert np.array_equal(_uv_transform({}), np.eye(3))
