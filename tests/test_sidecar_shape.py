"""The shape of a built model's sidecar as its readers use it (assetpipe/core/sidecar_shape.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from assetpipe.core.sidecar_shape import sidecar_problem

SIDE = json.loads((Path(__file__).parent / "data" / "built" / "cube" / "cube.asset.json").read_text())


def test_a_written_sidecar_has_the_shape():
    assert sidecar_problem(SIDE) is None


@pytest.mark.parametrize("edit, problem", [
    (lambda s: s.update(meshes=None), "meshes is not a list of objects"),
    (lambda s: s["bounds"].update(center="x"), "bounds.center is not 3 numbers"),
    (lambda s: s["vertexLayout"].update(stride="20"), "vertexLayout is not an object with a stride"),
    (lambda s: s["meshes"][0]["lods"][0].update(idxOffset="0"), "meshes[0].lods[0].idxOffset is not an integer"),
    (lambda s: s["sources"][0].update(path=5), "sources[0].path is not a string"),
])
def test_a_value_of_another_type_is_named(edit, problem):
    side = json.loads(json.dumps(SIDE))
    edit(side)
    assert problem in sidecar_problem(side)
    assert sidecar_problem([]) == "not a JSON object"
