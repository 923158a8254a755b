"""renderer/ref_mips.py: the reference's mip chains. The compiled per-texel rounding equals the
numpy expressions it replaced, bit for bit, and the chain follows the module's rules."""

from __future__ import annotations

import numpy as np
import pytest

from assetpipe.renderer.ref_mips import (
    LIN16_TO_SRGB8, SRGB8_TO_LIN16, _colour8, _data8, _normal8, level_count, mip_chain)


def _cases():
    rng = np.random.default_rng(7)
    uniform = rng.integers(0, 65536, (96, 80, 4), dtype=np.uint16)
    flat = uniform.copy()
    flat[..., :3] = 32767  # averaged codes of opposite normals: a (near) zero vector
    near = uniform.copy()
    near[..., :3] = rng.integers(32700, 32800, (96, 80, 3))
    edges = np.array([[[0, 0, 0, 0], [65535, 65535, 65535, 65535], [128, 257, 32768, 385]]], np.uint16)
    return [uniform, flat, near, edges]


@pytest.mark.parametrize("case", range(4))
def test_colour_rounding_is_the_numpy_expression(case):
    cur = _cases()[case]
    want = np.empty(cur.shape, np.uint8)
    want[..., :3] = LIN16_TO_SRGB8[cur[..., :3]]
    want[..., 3] = np.rint(cur[..., 3] / 257.0)
    got = _colour8(cur.reshape(-1, 4), LIN16_TO_SRGB8).reshape(cur.shape)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("case", range(4))
def test_normal_rounding_is_the_numpy_expression(case):
    cur = _cases()[case]
    v = cur[..., :3].astype(np.float32) * np.float32(2 / 65535) - 1
    v /= np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
    want = np.empty(cur.shape, np.uint8)
    want[..., :3] = np.rint((v + 1) * 127.5).clip(0, 255)
    want[..., 3] = np.rint(cur[..., 3] / 257.0)
    got = _normal8(cur.reshape(-1, 4)).reshape(cur.shape)
    assert np.array_equal(got, want)


def test_data_rounding_is_the_numpy_expression():
    every = np.arange(65536, dtype=np.uint16)  # all values: the integer form is exact
    assert np.array_equal(_data8(every), np.rint(every / 257.0).astype(np.uint8))


def test_chain_sizes_and_colour_averaging_in_linear_light():
    # a 2x2 checker of black and white (sRGB codes): its 1x1 level is the linear mean, 0.5,
    # coded in sRGB (188), not the code mean (128)
    im = np.zeros((4, 4, 4), np.uint8)
    im[::2, ::2] = im[1::2, 1::2] = 255
    im[..., 3] = 255
    chain = mip_chain(im, "baseColor")
    assert [lv.shape[:2] for lv in chain] == [(4, 4), (2, 2), (1, 1)] and len(chain) == level_count(4, 4)
    half = int(np.argmin(np.abs(SRGB8_TO_LIN16.astype(np.int64) - 32768)))
    assert chain[-1][0, 0, 0] == LIN16_TO_SRGB8[32768] and abs(int(chain[-1][0, 0, 0]) - half) <= 1
    assert chain[-1][0, 0, 3] == 255
    data = mip_chain(im, "occlusion")
    assert data[-1][0, 0, 0] in (127, 128)  # data roles average the codes


def test_normal_chain_renormalises():
    im = np.zeros((2, 2, 4), np.uint8)
    im[..., 3] = 255
    im[0, :, :3] = (255, 128, 128)  # +x
    im[1, :, :3] = (128, 128, 255)  # +z
    v = mip_chain(im, "normal")[-1][0, 0, :3].astype(np.float64) / 127.5 - 1
    assert abs(np.linalg.norm(v) - 1) < 0.02 and abs(v[0] - v[2]) < 0.02  # unit, halfway
