"""Renders of simple models against the golden PNGs (python -m renderer.goldens --update)."""

from __future__ import annotations

import pytest

from assetpipe.renderer.goldens import GOLDEN_DIR, REPO, compare_model

pytestmark = pytest.mark.vulkan


def test_cube_matches_goldens() -> None:
    outcomes = compare_model("cube", REPO / "tests" / "data" / "built" / "cube" / "cube.json")
    assert len(outcomes) == 2
    for o in outcomes:
        assert o.ok, f"{o.name}: {o.message} (goldens in {GOLDEN_DIR})"


@pytest.mark.parametrize("name", ["BoxTextured", "AlphaBlendModeTest", "TextureSettingsTest", "VertexColorTest"])
def test_corpus_models_match_goldens(name: str, tmp_path, corpus) -> None:  # noqa: ANN001
    from assetpipe.renderer.goldens import build_corpus_model

    built = build_corpus_model(name, tmp_path / name)
    assert built is not None, f"assetpipe build failed for {name}"
    for o in compare_model(name, built):
        assert o.ok, f"{o.name}: {o.message} (update with python -m renderer.goldens --update)"
