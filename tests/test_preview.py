"""The contact sheet."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from assetpipe.renderer.preview import VIEWS, make_preview

pytestmark = pytest.mark.vulkan
CUBE = Path(__file__).parent / "data" / "built" / "cube" / "cube.json"


def test_preview_has_views_lods_and_mips(tmp_path: Path) -> None:
    out = make_preview(CUBE, tmp_path / "cube.png", view_px=128, texture_px=64)
    img = np.asarray(Image.open(out).convert("RGB"))
    h, w, _ = img.shape
    assert w >= len(VIEWS) * 128 and h > 2 * 128 + 64
    # the cube's texture colours are on the sheet (red, green, blue, yellow quadrants)
    for colour in ((220, 40, 40), (40, 200, 60), (50, 80, 230), (240, 220, 40)):
        assert (np.abs(img.astype(int) - colour).max(axis=-1) <= 2).sum() > 50, colour
