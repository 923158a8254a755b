"""The checks' shared KTX2 reading (renderer/checks/ktx2_levels.py) and the roles check's area reduction."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from assetpipe.core.ktx2 import VK_FORMAT_BC7_UNORM_BLOCK, block_level_shape, write_ktx2
from assetpipe.renderer.checks.ktx2_levels import open_ktx2
from assetpipe.renderer.checks.roles import _reduce
from assetpipe.renderer.checks.textures import SRGB_TO_LINEAR, linear_to_srgb_code


def _rgba_chain(w: int, h: int) -> list[np.ndarray]:
    rng = np.random.default_rng(w * 7 + h)
    n = int(np.floor(np.log2(max(w, h)))) + 1
    return [rng.integers(0, 256, (max(h >> k, 1), max(w >> k, 1), 4), dtype=np.uint8) for k in range(n)]


def test_one_parse_per_model_cache(tmp_path: Path) -> None:
    p = tmp_path / "t.ktx2"
    chain = _rgba_chain(64, 32)
    p.write_bytes(write_ktx2(chain, 37))
    cache: dict = {}
    a = open_ktx2(p, cache)
    assert open_ktx2(tmp_path / "." / "t.ktx2", cache) is a  # the same file, however it is named
    assert open_ktx2(p, {}) is not a  # another model's cache reads it again
    assert (a.width, a.height, a.count, a.stored, a.block) == (64, 32, 7, 4, None)
    np.testing.assert_array_equal(a.level(2), chain[2])
    assert a.nearest(16) == 2 and a.nearest(64) == 0 and a.nearest(0) == a.count - 1


def test_block_levels_decoded_once_and_on_demand(tmp_path: Path) -> None:
    shapes = [block_level_shape(8, 8, k, 16) for k in range(4)]
    blocks = [np.zeros(s, np.uint8) for s in shapes]
    p = tmp_path / "bc7.ktx2"
    p.write_bytes(write_ktx2(blocks, VK_FORMAT_BC7_UNORM_BLOCK, width=8, height=8))
    img = open_ktx2(p, {})
    assert img.block is not None and not img._decoded
    lv = img.level(1)
    assert lv.shape == (4, 4, 4) and lv.dtype == np.uint8 and set(img._decoded) == {1}
    assert img.level(1) is lv


def test_missing_file_raises_oserror_and_is_not_cached(tmp_path: Path) -> None:
    cache: dict = {}
    with pytest.raises(OSError, match="No such file"):
        open_ktx2(tmp_path / "none.ktx2", cache)
    assert cache == {}


@pytest.mark.parametrize("role, fmt", [("baseColor", 43), ("metallicRoughness", 37), ("normal", 37)])
def test_reduce_matches_a_float64_area_average(role: str, fmt: int) -> None:
    """The 16-bit path against float64 box means of a 256x128 image reduced 8x: a smooth image
    with noise (what textures look like), so normal vectors' means stay long (> 0.5)."""
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:128, 0:256]
    base = np.stack([x / 255 * 200, y / 127 * 100 + 60, np.full_like(x, 230.0)], -1)
    rgb = np.clip(base + rng.normal(0, 20, base.shape), 0, 255).astype(np.uint8)
    rgba = np.concatenate([rgb, np.full((128, 256, 1), 255, np.uint8)], -1)
    got = _reduce(rgba, (32, 16), role, fmt)
    blocks = lambda a: a.reshape(16, 8, 32, 8, 3).mean(axis=(1, 3))  # noqa: E731
    if role == "normal":
        m = blocks(rgb.astype(np.float64) * 2 / 255 - 1)
        want = (m / np.linalg.norm(m, axis=-1, keepdims=True) + 1) * 127.5
    elif fmt == 43:
        want = linear_to_srgb_code(blocks(SRGB_TO_LINEAR.astype(np.float64)[rgb]))
    else:
        want = blocks(rgb.astype(np.float64))
    # 16-bit means round to 1/65535 of full scale; through the sRGB curve's steepest part (12.92x)
    # that is 12.92 * 255 / 65535 = 0.05 of a code; 0.06 allows float32 on top
    assert np.abs(got - want).max() < 0.06
