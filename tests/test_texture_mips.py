"""Mip chains against float64 references computed here (exact area averages from level 0)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from assetpipe.pipelines.model import (ROLE_BASE_COLOR, ROLE_EMISSIVE, ROLE_METALLIC_ROUGHNESS, ROLE_NORMAL,
                             ROLE_OCCLUSION)
from assetpipe.pipelines.texture_mips import (TextureOptions, build_mip_chain, mip_level_count, mip_sizes,
                                    normal_unit_levels)

# ----------------------------------------------------------------------------- references


def srgb_to_linear64(x):
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb64(y):
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    return np.where(y <= 0.0031308, y * 12.92, 1.055 * y ** (1 / 2.4) - 0.055)


def area_matrix(n_src: int, n_dst: int) -> np.ndarray:
    """(n_dst, n_src) float64: row i averages source texels over [i, i+1) * n_src / n_dst."""
    edges = np.arange(n_dst + 1, dtype=np.float64) * (n_src / n_dst)
    lo, hi = edges[:-1, None], edges[1:, None]
    y = np.arange(n_src, dtype=np.float64)[None, :]
    overlap = np.clip(np.minimum(hi, y + 1) - np.maximum(lo, y), 0.0, None)
    return overlap / overlap.sum(axis=1, keepdims=True)


def area_average(img: np.ndarray, w: int, h: int) -> np.ndarray:
    """Exact area average of (H, W, C) float64 to (h, w, C)."""
    a = area_matrix(img.shape[0], h)
    b = area_matrix(img.shape[1], w)
    return np.einsum("iy,yxc,jx->ijc", a, img, b, optimize=True)


def reference_srgb_levels(rgba8: np.ndarray) -> list[np.ndarray]:
    """Gamma-correct reference in float 8-bit units (RGB only)."""
    lin = srgb_to_linear64(rgba8[..., :3] / 255.0)
    h0, w0 = rgba8.shape[:2]
    return [linear_to_srgb64(area_average(lin, w, h)) * 255.0 for (w, h) in mip_sizes(w0, h0)]


def corpus_rgba(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGBA"))


# ----------------------------------------------------------------------------- sizes

@pytest.mark.parametrize("w,h,count", [(211, 211, 8), (1, 7, 3), (7, 1, 3), (300, 17, 9), (17, 300, 9),
                                       (4096, 1, 13), (1, 4096, 13), (1, 1, 1), (3, 3, 2), (2, 1, 2)])
def test_level_counts_and_sizes(w, h, count):
    rgba = np.random.default_rng(w * 1000 + h).integers(0, 256, (h, w, 4), dtype=np.uint8)
    assert mip_level_count(w, h) == count
    for role in (ROLE_BASE_COLOR, ROLE_NORMAL, ROLE_OCCLUSION):
        chain = build_mip_chain(rgba, role)
        assert len(chain.levels) == count
        for k, lv in enumerate(chain.levels):
            assert lv.shape == (max(1, h >> k), max(1, w >> k), 4)
            assert lv.dtype == np.uint8
        assert chain.levels[-1].shape[:2] == (1, 1)
        assert (chain.levels[0] == rgba).all() or role == ROLE_NORMAL


def test_odd_3x3_to_1x1_averages_all_nine_texels():
    vals = np.array([[0, 255, 0], [255, 0, 255], [0, 255, 0]], dtype=np.uint8)
    rgba = np.zeros((3, 3, 4), np.uint8)
    rgba[..., :3] = vals[..., None]
    rgba[..., 3] = vals  # alpha linear: 4 of 9 texels at 255
    chain = build_mip_chain(rgba, ROLE_OCCLUSION)
    assert chain.levels[1][0, 0, 0] == round(255 * 4 / 9)
    chain = build_mip_chain(rgba, ROLE_EMISSIVE)  # sRGB: 4/9 of full linear intensity
    assert chain.levels[1][0, 0, 0] == round(float(linear_to_srgb64(4 / 9)) * 255)
    # a 2x2 box on the top-left would give 128 (linear) / 188 (sRGB)


def test_checkerboard_level1_is_gamma_correct():
    y, x = np.mgrid[:64, :64]
    rgba = np.full((64, 64, 4), 255, np.uint8)
    rgba[..., :3] = (((x + y) % 2) * 255).astype(np.uint8)[..., None]
    for role in (ROLE_BASE_COLOR, ROLE_EMISSIVE):
        chain = build_mip_chain(rgba, role)
        assert chain.srgb
        for lv in chain.levels[1:]:
            assert lv[..., :3].min() >= 187 and lv[..., :3].max() <= 189
            assert (lv[..., 3] == 255).all()
    lin = build_mip_chain(rgba, ROLE_METALLIC_ROUGHNESS)
    assert not lin.srgb
    assert set(np.unique(lin.levels[1][..., :3])) <= {127, 128}


def _assert_mae(chain, rgba, limit=0.5):
    refs = reference_srgb_levels(rgba)
    maes = []
    for k, (lv, ref) in enumerate(zip(chain.levels, refs)):
        mae = float(np.abs(lv[..., :3].astype(np.float64) - ref).mean())
        maes.append(mae)
        assert mae <= limit, f"level {k} {lv.shape}: MAE {mae:.3f} > {limit}"
    return maes


def test_colour_mae_against_float64_reference_corpus_512(corpus):
    rgba = corpus_rgba(corpus / "models" / "Duck" / "glTF" / "DuckCM.png")
    assert rgba.shape == (512, 512, 4)
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR)
    maes = _assert_mae(chain, rgba)
    assert max(maes[1:]) > 0.1  # the comparison is real: rounding to 8 bits alone gives ~0.25
    assert max(chain.mean_drift) < 1.0  # 8-bit rounding only (one sRGB step near white is ~1 linear unit)


def test_colour_mae_non_power_of_two_corpus_211(corpus):
    rgba = corpus_rgba(corpus / "models" / "BoxTexturedNonPowerOfTwo" / "glTF" / "CesiumLogoFlat.png")
    assert rgba.shape == (211, 211, 4)
    _assert_mae(build_mip_chain(rgba, ROLE_BASE_COLOR), rgba)


def test_colour_mae_odd_non_square_noise():
    rng = np.random.default_rng(7)
    rgba = rng.integers(0, 256, (97, 301, 4), dtype=np.uint8)
    rgba[..., 3] = 255
    _assert_mae(build_mip_chain(rgba, ROLE_BASE_COLOR), rgba)


def test_linear_roles_mae():
    rng = np.random.default_rng(3)
    rgba = rng.integers(0, 256, (123, 77, 4), dtype=np.uint8)
    chain = build_mip_chain(rgba, ROLE_METALLIC_ROUGHNESS)
    h0, w0 = rgba.shape[:2]
    for lv, (w, h) in zip(chain.levels, mip_sizes(w0, h0)):
        ref = area_average(rgba.astype(np.float64), w, h)
        assert np.abs(lv - ref).mean() <= 0.5
        assert np.abs(lv - ref).max() <= 0.51


def test_16bit_source_is_filtered_at_16_bits():
    rng = np.random.default_rng(5)
    rgba16 = rng.integers(0, 65536, (64, 64, 4), dtype=np.uint16)
    rgba16[..., 3] = 65535
    chain = build_mip_chain(rgba16, ROLE_BASE_COLOR)
    lin = srgb_to_linear64(rgba16[..., :3] / 65535.0)
    for lv, (w, h) in zip(chain.levels, mip_sizes(64, 64)):
        ref = linear_to_srgb64(area_average(lin, w, h)) * 255.0
        assert np.abs(lv[..., :3] - ref).mean() <= 0.5
    assert (chain.levels[0][..., 3] == 255).all()


# ----------------------------------------------------------------------------- normals

def _bumpy_normals(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[:h, :w].astype(np.float64)
    # a height field with features at several scales
    hx = 0.8 * np.cos(x / 3.1) * np.sin(y / 5.3) + 0.3 * np.cos(x / 0.9 + y / 1.3)
    hy = 0.8 * np.sin(x / 3.1) * np.cos(y / 5.3) + 0.3 * np.sin(x / 1.1 - y / 0.7)
    n = np.stack([-hx, -hy, np.ones_like(hx)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    rgba = np.full((h, w, 4), 255, np.uint8)
    rgba[..., :3] = np.rint((n + 1) * 127.5)
    return rgba


@pytest.mark.parametrize("h,w", [(256, 256), (211, 211), (37, 300)])
def test_normals_unit_length_every_level(h, w):
    rgba = _bumpy_normals(h, w)
    chain = build_mip_chain(rgba, ROLE_NORMAL)
    assert not chain.srgb
    units = normal_unit_levels(rgba)
    decoded0 = rgba[..., :3] / 255.0 * 2.0 - 1.0
    decoded0 /= np.linalg.norm(decoded0, axis=-1, keepdims=True)
    for k, (lv, u) in enumerate(zip(chain.levels, units)):
        # The vectors the chain quantises are unit length within 1e-3.
        assert np.abs(np.linalg.norm(u[..., :3], axis=-1) - 1.0).max() <= 1e-3
        # Decoded with the same mapping, the 8-bit texels are unit length up to rounding:
        # each component is off by at most 1/255, so | |n| - 1 | <= sqrt(3)/255 (0.0068);
        # exact unit vectors cannot be stored in 8 bits (see the module docstring).
        n = lv[..., :3].astype(np.float64) * (2.0 / 255.0) - 1.0
        length = np.linalg.norm(n, axis=-1)
        assert np.abs(length - 1.0).max() <= np.sqrt(3) / 255 + 1e-6
        assert np.abs(length - 1.0).mean() <= 0.0025
        # Direction: the renormalised exact area average of level 0's unit vectors.
        hk, wk = lv.shape[:2]
        ref = area_average(decoded0, wk, hk)
        ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
        cos = np.sum(ref * n / length[..., None], axis=-1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() <= 0.6, f"level {k}"


# ----------------------------------------------------------------------------- alpha

def _foliage(h: int = 512, w: int = 512, seed: int = 11) -> np.ndarray:
    """Leaf-like alpha: thin soft-edged blobs covering ~22% at alpha >= 0.5; green colour,
    black under alpha 0 (as many exporters write it)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.random((h // 8, w // 8)).astype(np.float32)
    field = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    fine = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.5)
    v = 0.75 * field + 0.25 * fine
    t = np.quantile(v, 0.775)
    alpha = np.clip((v - t) * 12.0 + 0.5, 0.0, 1.0)
    rgba = np.zeros((h, w, 4), np.uint8)
    rgba[..., 0] = np.clip(40 + 60 * field, 0, 255)
    rgba[..., 1] = np.clip(120 + 100 * fine, 0, 255)
    rgba[..., 2] = 30
    rgba[..., 3] = np.rint(alpha * 255)
    rgba[rgba[..., 3] == 0, :3] = 0
    return rgba


def _coverage(lv: np.ndarray, cutoff: float) -> float:
    return float(np.mean(lv[..., 3] / 255.0 >= cutoff))


@pytest.mark.parametrize("cutoff", [0.5, 0.3])
def test_mask_coverage_preserved_down_to_16px(cutoff):
    rgba = _foliage()
    c0 = _coverage(rgba, cutoff)
    assert 0.1 < c0 < 0.4
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR, "MASK", cutoff)
    naive = build_mip_chain(rgba, ROLE_BASE_COLOR, "BLEND", cutoff)
    worst_naive = 0.0
    for k, (lv, nv) in enumerate(zip(chain.levels, naive.levels)):
        if max(lv.shape[:2]) < 16:
            break
        assert abs(_coverage(lv, cutoff) - c0) <= 0.01, f"level {k} {lv.shape}"
        assert chain.coverage[k] == pytest.approx(_coverage(lv, cutoff))
        worst_naive = max(worst_naive, abs(_coverage(nv, cutoff) - c0))
    assert worst_naive > 0.03  # without the scaling coverage does drift: the test can fail


def test_blend_has_no_dark_fringes():
    rgba = _foliage(256, 256)
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR, "BLEND")
    assert chain.alpha_weighted
    # reference: alpha-weighted linear colour average
    lin = srgb_to_linear64(rgba[..., :3] / 255.0)
    a = rgba[..., 3:4] / 255.0
    for lv in chain.levels[1:]:
        hk, wk = lv.shape[:2]
        wsum = area_average(a, wk, hk)
        ref = area_average(lin * a, wk, hk) / np.maximum(wsum, 1e-12)
        ref8 = linear_to_srgb64(ref) * 255.0
        seen = wsum[..., 0] * 255 >= 1.0  # texels with any visible alpha
        err = np.abs(lv[..., :3] - ref8)[seen]
        assert err.mean() <= 0.5 and err.max() <= 3.0
        # alpha itself is the plain linear average
        assert np.abs(lv[..., 3] - wsum[..., 0] * 255).max() <= 0.51
    # the green of the leaves is kept at the edges: a naive filter darkens it
    naive = np.asarray(Image.fromarray(rgba[..., :3]).reduce(2))
    edge = (chain.levels[1][..., 3] > 10) & (chain.levels[1][..., 3] < 200)
    assert chain.levels[1][..., 1][edge].mean() > naive[..., 1][edge].mean() + 20


def test_fully_transparent_footprints_keep_unweighted_colour():
    rgba = np.zeros((4, 4, 4), np.uint8)
    rgba[..., :3] = (200, 50, 10)
    rgba[:2, :2, 3] = 255  # only the top-left 2x2 visible
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR, "BLEND")
    assert tuple(chain.levels[1][1, 1, :3]) == (200, 50, 10)
    assert chain.levels[1][1, 1, 3] == 0
    assert tuple(chain.levels[1][0, 0]) == (200, 50, 10, 255)


def test_opaque_texture_with_mask_reports_full_coverage():
    rgba = np.full((8, 8, 4), 255, np.uint8)
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR, "MASK", 0.5)
    assert not chain.alpha_weighted
    assert chain.coverage == (1.0,) * 4


# ----------------------------------------------------------------------------- options

def test_max_size_drops_whole_levels():
    rng = np.random.default_rng(2)
    rgba = rng.integers(0, 256, (300, 1000, 4), dtype=np.uint8)
    full = build_mip_chain(rgba, ROLE_BASE_COLOR)
    small = build_mip_chain(rgba, ROLE_BASE_COLOR, options=TextureOptions(max_size=256))
    assert small.dropped_levels == 2
    assert small.levels[0].shape == (75, 250, 4)
    assert len(small.levels) == mip_level_count(250, 75)
    for a, b in zip(small.levels, full.levels[2:]):
        assert (a == b).all()
    with pytest.raises(ValueError, match="max_size must be >= 1"):
        TextureOptions(max_size=0)


def test_input_not_modified_and_levels_read_only():
    rgba = np.random.default_rng(4).integers(0, 256, (16, 16, 4), dtype=np.uint8)
    before = rgba.copy()
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR, "BLEND")
    assert (rgba == before).all() and rgba.flags.writeable
    assert not chain.levels[0].flags.writeable


def test_rejects_bad_input():
    with pytest.raises(ValueError, match='RGBA, got'):
        build_mip_chain(np.zeros((4, 4, 3), np.uint8), ROLE_BASE_COLOR)
    with pytest.raises(ValueError, match="unknown texture role 'diffuse'"):
        build_mip_chain(np.zeros((4, 4, 4), np.uint8), "diffuse")
    with pytest.raises(ValueError, match="unknown alpha mode 'ADD'"):
        build_mip_chain(np.zeros((4, 4, 4), np.uint8), ROLE_BASE_COLOR, "ADD")


def test_png_roundtrip_helper_sanity():
    # The corpus helper decodes palette PNGs through Pillow like decode_image does.
    buf = io.BytesIO()
    Image.fromarray(np.zeros((2, 2, 4), np.uint8)).save(buf, "PNG")
    assert corpus_rgba(io.BytesIO(buf.getvalue())).shape == (2, 2, 4)


# ----------------------------------------------------------------------------- dropped levels (#13)

@pytest.mark.parametrize("h,w,max_size,gather", [(300, 1000, 256, 0), (211, 211, 100, 1), (257, 1000, 300, 0),
                                                 (1000, 257, 60, 1), (384, 999, 128, 1), (7, 600, 100, 0),
                                                 (600, 3, 40, 1), (97, 61, 1, 0)])
def test_dropped_levels_equal_the_full_chains_levels_for_every_role(h, w, max_size, gather, monkeypatch):
    # The chain without its top levels is computed from bands of rows of the source (the
    # working copy of level 0 never whole); it must be the full chain's levels byte for byte:
    # integer and fractional ratios from level 0 (211 -> 105, 1000 -> 62 wide, 257 rows),
    # a 1-row level, 8- and 16-bit sources, every filter. Bands of 8192 texels: many bands,
    # band edges inside footprints. gather=0: only fractional levels narrower than 1/32 of the
    # source keep their horizontal pass whole, the others are summed band by band.
    from assetpipe.pipelines import texture_mips

    monkeypatch.setattr(texture_mips, "_BAND_TEXELS", 8192)
    if not gather:
        monkeypatch.setattr(texture_mips, "_GATHER_MIN_BYTES", 0)
    rng = np.random.default_rng(h * 7 + w)
    rgba8 = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    opaque8 = rgba8.copy()
    opaque8[..., 3] = 255
    rgba16 = rng.integers(0, 65536, (h, w, 4), dtype=np.uint16)
    cases = [(rgba8, ROLE_BASE_COLOR, "BLEND"), (rgba8, ROLE_BASE_COLOR, "MASK"), (opaque8, ROLE_BASE_COLOR, "OPAQUE"),
             (opaque8, ROLE_EMISSIVE, "OPAQUE"), (rgba8, ROLE_OCCLUSION, "OPAQUE"), (rgba8, ROLE_NORMAL, "OPAQUE"),
             (rgba16, ROLE_BASE_COLOR, "BLEND"), (rgba16, ROLE_METALLIC_ROUGHNESS, "OPAQUE"),
             (rgba16, ROLE_NORMAL, "OPAQUE")]
    for src, role, mode in cases:
        full = build_mip_chain(src, role, mode, 0.4)
        cut = build_mip_chain(src, role, mode, 0.4, options=TextureOptions(max_size=max_size))
        d = cut.dropped_levels
        assert d >= 1 and max(cut.levels[0].shape[:2]) <= max_size < max(full.levels[d - 1].shape[:2])
        assert len(cut.levels) == len(full.levels) - d
        for k, (a, b) in enumerate(zip(cut.levels, full.levels[d:])):
            assert a.shape == b.shape and (a == b).all(), (role, mode, src.dtype, k + d)
        assert cut.coverage == (None if full.coverage is None else full.coverage[d:])


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
@pytest.mark.parametrize("src_hw,dst_wh", [((257, 120), (60, 128)), ((120, 257), (128, 60)), ((211, 211), (105, 105)),
                                           ((1000, 9), (3, 62)), ((64, 64), (16, 16))])
def test_level_from_bands_equals_opencv_inter_area(dtype, src_hw, dst_wh, monkeypatch):
    # OpenCV's INTER_AREA replayed over bands: integer ratio on one axis and fractional on the
    # other (where OpenCV's generic path runs, not its integer fast path), both fractional,
    # both integer; 3 and 4 channels. Equal bit for bit, not within a tolerance.
    import cv2

    from assetpipe.pipelines import texture_mips

    monkeypatch.setattr(texture_mips, "_BAND_TEXELS", 1000)
    rng = np.random.default_rng(11)
    for channels in (3, 4):
        if dtype == np.uint16:
            src = rng.integers(0, 65536, src_hw + (channels,), dtype=np.uint16)
        else:
            src = rng.random(src_hw + (channels,), dtype=np.float32) * 2 - 1
        ref = cv2.resize(src, dst_wh, interpolation=cv2.INTER_AREA)
        got = texture_mips._level_from_source0(src, lambda band: band.copy(), dst_wh)
        assert got.dtype == ref.dtype and got.shape == ref.shape and (got == ref).all(), (channels, src_hw, dst_wh)


_MIPS_PEAK_SCRIPT = """
import sys
from pathlib import Path
import numpy as np
from assetpipe.pipelines.texture_mips import TextureOptions, build_mip_chain
def hwm():
    return next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmHWM"))
n, cap = int(sys.argv[1]), int(sys.argv[2])
rgba = np.empty((n, n, 4), np.uint8)
rgba[...] = np.random.default_rng(0).integers(0, 256, (n, 1, 4), dtype=np.uint8)
rgba[..., 3] = 255
Path("/proc/self/clear_refs").write_text("5")  # reset the peak RSS (Linux >= 4.0)
before = hwm()
chain = build_mip_chain(rgba, sys.argv[3], options=TextureOptions(max_size=cap))
print(before, hwm(), chain.levels[0].shape[0])
"""


@pytest.mark.parametrize("role", [ROLE_BASE_COLOR, ROLE_NORMAL])
def test_dropping_levels_never_makes_a_working_copy_of_the_full_image(role):
    # 6000^2 capped at 2048: levels 0 and 1 dropped; 187^2, 93^2 and 46^2 are filtered from
    # level 0 with fractional ratios. Measured growth of the peak RSS in build_mip_chain over
    # the RGBA8 source (a fresh process, peak reset after the source is made): 2.97x before
    # (the 16-bit copy of level 0 is 2x, level 1 0.5x more), 0.66x now (baseColor).
    import os
    import subprocess
    import sys

    n, cap = 6000, 2048
    out = subprocess.run([sys.executable, "-c", _MIPS_PEAK_SCRIPT, str(n), str(cap), role], capture_output=True,
                         text=True, check=True, env=os.environ)
    before, after, size = map(int, out.stdout.split())
    assert size == 1500
    rgba = n * n * 4
    # What may be held now: dropped level 1 in its working form (3000^2: 16-bit colour 0.5x,
    # float32 normals 1.0x), kept level 2 (1/4 of that), the 8-bit kept levels (1/16 x 4/3),
    # bands of 2^20 texels in float32 (16 MiB, a few at once). A full-size working copy of
    # level 0 alone is 2x (16-bit) or 4x (float32).
    working = (3000 * 3000 * (8 if role != ROLE_NORMAL else 16)) * 1.25
    assert after - before <= working + rgba / 12 + 64 * 2**20, (after - before) / rgba


def test_compiled_normal_unit_and_encode_equal_the_numpy_expressions():
    """_unit and _encode_normals are compiled; they equal, bit for bit, the numpy expressions
    they replaced (random vectors, tiny and zero vectors, alpha outside [0, 1])."""
    from assetpipe.pipelines.texture_mips import _encode_normals, _unit

    def unit0(w):
        xyz = w[..., :3]
        length = np.sqrt(np.einsum("...i,...i->...", xyz, xyz))
        ok = length > 1e-12
        out = np.empty_like(w)
        np.divide(xyz, np.where(ok, length, 1.0)[..., None], out=out[..., :3])
        if not ok.all():
            out[~ok, :3] = (0.0, 0.0, 1.0)
        out[..., 3] = w[..., 3]
        return out

    def enc0(u):
        out = np.empty(u.shape[:2] + (4,), dtype=np.uint8)
        out[..., :3] = np.rint(np.clip((u[..., :3] + 1.0) * 127.5, 0.0, 255.0))
        out[..., 3] = np.rint(np.clip(u[..., 3], 0.0, 1.0) * 255.0)
        return out

    rng = np.random.default_rng(5)
    w = (rng.random((64, 48, 4)) * 2 - 1).astype(np.float32)
    w[::7, ::5, :3] = 0
    w[1::9, ::3, :3] *= np.float32(1e-7)
    w[..., 3] = (rng.random((64, 48)) * 1.4 - 0.2).astype(np.float32)
    a = unit0(w)
    assert np.array_equal(a.view(np.uint32), _unit(w).view(np.uint32))
    assert np.array_equal(enc0(a), _encode_normals(a))
    assert np.array_equal(enc0(w), _encode_normals(w))


@pytest.mark.parametrize("alpha_mode", ["BLEND", "MASK", "OPAQUE"])
def test_compiled_premultiplied_levels_equal_the_numpy_expressions(alpha_mode):
    """An 8-bit baseColor with alpha is premultiplied and each level finished by compiled
    kernels; the levels and coverage equal, bit for bit, the numpy expressions they replaced
    (random colour, alpha 0 in patches, 255 elsewhere, everything between; odd sizes)."""
    from assetpipe.pipelines import texture_mips as tm

    def chain0(rgba, cutoff):
        """The numpy path (as before the kernels), from _premultiplied_chain."""
        w16 = tm._to_work16(rgba, True)
        sizes = mip_sizes(rgba.shape[1], rgba.shape[0])
        pres = tm._chain(tm._premultiply(w16), sizes)
        straights = tm._chain(w16[..., :3].copy(), sizes)
        cutoff8 = tm._cutoff_threshold8(cutoff) if alpha_mode == "MASK" else None
        target = float(np.count_nonzero(rgba[..., 3] >= cutoff8)) / rgba[..., 3].size if cutoff8 else 0.0
        out, cov = [rgba], [target]
        for pre_k, straight_k in zip(pres[1:], straights[1:]):
            alpha = pre_k[..., 3]
            empty = alpha <= (0.5 / 65535.0)
            colour = np.divide(pre_k[..., :3], alpha[..., None], out=np.zeros(alpha.shape + (3,), np.float32),
                               where=~empty[..., None])
            colour16 = np.rint(np.clip(colour, 0.0, 1.0) * 65535.0).astype(np.uint16)
            colour16[empty] = straight_k[empty]
            lv = np.empty(alpha.shape + (4,), dtype=np.uint8)
            lv[..., :3] = tm._SRGB8_FROM_LIN16[colour16]
            if cutoff8 is not None:
                kth = np.partition(alpha.reshape(-1), alpha.size - round(target * alpha.size))
                k = round(target * alpha.size)
                if 0 < k and 0 < target < 1 and kth[alpha.size - k] > 0:
                    alpha = alpha * np.float32((cutoff8 - 0.5) / 255.0 / float(kth[alpha.size - k]) * (1.0 + 1e-6))
            lv[..., 3] = np.rint(np.clip(alpha, 0.0, 1.0) * 255.0).astype(np.uint8)
            cov.append(float(np.count_nonzero(lv[..., 3] >= cutoff8)) / alpha.size if cutoff8 else None)
            out.append(lv)
        return out, cov

    rng = np.random.default_rng(11)
    rgba = rng.integers(0, 256, (77, 130, 4), dtype=np.uint8)
    rgba[..., 3] = np.where(rng.random((77, 130)) < 0.3, 255, rgba[..., 3])
    rgba[10:30, 40:90, 3] = 0  # fully transparent patches: their footprints keep the straight colour
    rgba[50:, :20, 3] = 0
    chain = build_mip_chain(rgba, ROLE_BASE_COLOR, alpha_mode, 0.4)
    ref, cov = chain0(rgba, 0.4)
    assert chain.alpha_weighted and len(chain.levels) == len(ref)
    for got, want in zip(chain.levels, ref):
        assert np.array_equal(got, want)
    if alpha_mode == "MASK":
        assert chain.coverage == tuple(cov) and len(set(cov)) > 1


def test_the_linear_16_to_8_table_equals_the_opencv_conversion():
    """The premultiplied kernel's linear encoding table rounds every 16-bit value as
    _u16_to_u8 (OpenCV) does, so a linear role's levels would not change by taking it."""
    from assetpipe.pipelines import texture_mips as tm

    x = np.arange(65536, dtype=np.uint16)
    assert np.array_equal(tm._LIN8_FROM_LIN16, tm._u16_to_u8(x).reshape(-1))


def test_channel_histograms_count_as_opencv_does():
    """The mean-drift histograms, one pass for the four channels: OpenCV's calcHist counts for
    each channel (any size, a strided view too)."""
    import cv2

    from assetpipe.pipelines.texture_mips import _channel_histograms

    rng = np.random.default_rng(1)
    for h, w in ((1, 1), (3, 17), (200, 203), (64, 512)):
        lv = (rng.random((h, w, 4)) * 255).astype(np.uint8)
        for view in (lv, lv[:, ::2]):
            got = _channel_histograms(view)
            for c in range(4):
                want = cv2.calcHist([np.ascontiguousarray(view)], [c], None, [256], [0, 256]).reshape(-1)
                assert np.array_equal(got[c], want.astype(np.int64))
