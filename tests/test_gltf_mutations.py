"""Every value of the fuzzer's sound glTF documents replaced, one at a time, by each of a few
values of other types (``tests/fuzz_inputs.py`` draws such edits at random; here all of them):
the importer reads the model or refuses it with one line naming the file, never an internal
error. Found this way: an integer where a texture reference belongs, a null
KHR_texture_transform offset, a list among morph weights (each an internal error before)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from assetpipe.core.errors import AssetError
from assetpipe.pipelines.import_gltf import import_gltf
from tests.fuzz_inputs import SEED_KINDS, _seed_gltf
from tests.json_edits import value_paths, with_value

# one of each JSON type the schema does not expect somewhere (large numbers, which can ask for
# large allocations, are left to the fuzzer's memory-limited subprocess)
OTHERS = ("x", -1, 1.5, True, None, [], [1], {"a": 1})


@pytest.mark.parametrize("kind", range(SEED_KINDS))
def test_every_value_of_the_wrong_type_is_read_or_refused_in_one_line(tmp_path: Path, kind: int):
    b = _seed_gltf(kind)
    doc = b._json({"uri": "m.bin", "byteLength": len(b.bin)})
    (tmp_path / "m.bin").write_bytes(bytes(b.bin))
    model = tmp_path / "m.gltf"
    model.write_text(json.dumps(doc))
    import_gltf(model)  # the document itself is sound
    failures, refused = [], 0
    for path in [p for p in value_paths(doc) if p[0] != "asset"]:
        for value in OTHERS:
            model.write_text(json.dumps(with_value(doc, path, value)))
            try:
                import_gltf(model)
            except AssetError as exc:
                refused += 1
                if "\n" in str(exc) or "m.gltf" not in str(exc):
                    failures.append((path, value, f"not one line naming the file: {exc}"))
            except Exception as exc:  # noqa: BLE001 - the point: anything else is a bug of ours
                failures.append((path, value, f"{type(exc).__name__}: {exc}"))
    assert not failures, "\n".join(map(str, failures[:20]))
    assert refused > 0  # the edits do reach the checks
