"""Renders of simple models against the golden PNGs (python -m renderer.goldens --update)."""

from __future__ import annotations

import pytest

from renderer.goldens import GOLDEN_DIR, REPO, compare_model

pytestmark = pytest.mark.vulkan


def test_cube_matches_goldens() -> None:
    outcomes = compare_model("cube", REPO / "tests" / "data" / "built" / "cube" / "cube.json")
    assert len(outcomes) == 2
    for o in outcomes:
        assert o.ok, f"{o.name}: {o.message} (goldens in {GOLDEN_DIR})"
