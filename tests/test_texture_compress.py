"""Block-compressed textures (BC7/BC5/BC4, ETC2/EAC): formats per role, every level decoded
(texture2ddecoder, independent of the etcpak encoder) and compared with the uncompressed chain
the same step builds; the goals of issue 16; KTX2 files read by a second reader (ktx-parse);
uploads on lavapipe."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from assetpipe.core.errors import InvalidTextureError
from assetpipe.core.hashing import digest_bytes
from assetpipe.core.ktx2 import BLOCK_FORMATS, block_level_shape, decode_level, read_ktx2
from assetpipe.pipelines.model import (ROLE_BASE_COLOR, ROLE_EMISSIVE, ROLE_METALLIC_ROUGHNESS, ROLE_NORMAL,
                                       ROLE_OCCLUSION, ImageSource)
from assetpipe.pipelines.texture_compress import (choose_format, compress_level, level_quality, pad_to_blocks,
                                                  rebuild_normal_z)
from assetpipe.pipelines.texture_mips import mip_level_count
from assetpipe.pipelines.texture_options import TextureOptions
from assetpipe.pipelines.texture_process import process_texture

# The goals of issue 16 (benchmarks/textures.py measures them on the corpus), on level 0:
COLOUR_DB = 36.0  # colour >= 36 dB PSNR against our uncompressed level 0
PHOTO_LEVEL0_DB = 38.0  # photographic content
NORMAL_DEG = 2.0  # normal maps: mean angular error <= 2 degrees
# etcpak's ETC2 RGB/RGBA does not reach 36 dB on this content (32.7 dB measured on level 0, and
# 25.5 dB on the corpus' UV.png; see the report of issue 16): its level 0 is held to 30 dB, a
# regression floor, not the goal.
ETC2_LEVEL0_DB = 30.0
# RMS error (8-bit units) of one flat colour in the format: BC4/BC5/BC7 endpoints hold 7-8 bits
# (BC7's mode 6 shares a p-bit, so alpha can come out 254): 1 unit; ETC2/EAC base colours hold
# 4-5 bits per channel plus a table offset: etcpak was off by up to 7.2 units RMS (the 1x1 level
# of the corpus' CesiumMan.jpg: 31.0 dB), 8 allowed.
FLAT_RMS = {131: 1.0, 132: 1.0, 134: 1.0, 161: 8.0}


def photo(h: int, w: int, seed: int = 7, alpha: bool = False) -> np.ndarray:
    """(h, w, 4) uint8 with a photographic-like spectrum: gradients + noise at several scales."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:h, :w].astype(np.float32)
    y, x = y / h, x / w
    img = np.stack([0.2 + 0.6 * x, 0.25 + 0.5 * y, 0.5 + 0.3 * np.sin(6 * x + 4 * y)], axis=-1)
    for cells, amp in ((4, 0.2), (16, 0.08)):
        noise = rng.standard_normal((cells, cells, 3)).astype(np.float32)
        img += amp * cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    img += 0.008 * rng.standard_normal((h, w, 3)).astype(np.float32)  # texel-level grain (about 2 units)
    out = np.full((h, w, 4), 255, np.uint8)
    out[..., :3] = np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
    if alpha:
        out[..., 3] = np.clip((0.3 + 0.7 * x) * 255, 0, 255).astype(np.uint8)
    return out


def normal_map(h: int, w: int, seed: int = 3) -> np.ndarray:
    """(h, w, 4) uint8 tangent-space normals of a smooth random height field (z > 0)."""
    rng = np.random.default_rng(seed)
    height = cv2.resize(rng.standard_normal((6, 6)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    gy, gx = np.gradient(height * 4.0)
    n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    out = np.full((h, w, 4), 255, np.uint8)
    out[..., :3] = np.clip(np.rint((n * 0.5 + 0.5) * 255), 0, 255).astype(np.uint8)
    return out


def png_source(rgba: np.ndarray, name: str = "t.png") -> ImageSource:
    buf = io.BytesIO()
    Image.fromarray(rgba).save(buf, "PNG")
    data = buf.getvalue()
    return ImageSource(name=name, data=data, mime="image/png", origin=f"/models/{name}", digest=digest_bytes(data))


def content(role: str, h: int, w: int, alpha: bool = False) -> np.ndarray:
    return normal_map(h, w) if role == ROLE_NORMAL else photo(h, w, alpha=alpha)


EXPECTED = {  # (codec, role, alpha) -> vkFormat
    ("bc", ROLE_BASE_COLOR, False): 146, ("bc", ROLE_BASE_COLOR, True): 146, ("bc", ROLE_EMISSIVE, False): 146,
    ("bc", ROLE_METALLIC_ROUGHNESS, False): 145, ("bc", ROLE_NORMAL, False): 141, ("bc", ROLE_OCCLUSION, False): 139,
    ("etc2", ROLE_BASE_COLOR, False): 148, ("etc2", ROLE_BASE_COLOR, True): 152, ("etc2", ROLE_EMISSIVE, False): 148,
    ("etc2", ROLE_METALLIC_ROUGHNESS, False): 147, ("etc2", ROLE_NORMAL, False): 155,
    ("etc2", ROLE_OCCLUSION, False): 153,
}


@pytest.mark.parametrize("zstd", [False, True])
@pytest.mark.parametrize("codec,role,alpha", sorted(EXPECTED))
def test_every_level_decodes_close_to_the_uncompressed_chain(codec, role, alpha, zstd):
    h, w = 72, 90  # not multiples of 4 below level 2; 7 levels down to 1x1
    src = png_source(content(role, h, w, alpha))
    alpha_mode = "BLEND" if alpha else "OPAQUE"
    plain = process_texture(src, role, alpha_mode, 0.5, TextureOptions())
    opts = TextureOptions(compression=codec, supercompression="zstd" if zstd else "none")
    res = process_texture(src, role, alpha_mode, 0.5, opts)
    ref = read_ktx2(plain.ktx2).levels
    img = read_ktx2(res.ktx2, "compressed.ktx2")
    vk = EXPECTED[(codec, role, alpha)]
    assert img.vk_format == res.vk_format == vk
    assert img.supercompression == (2 if zstd else 0)
    assert img.srgb == (role in (ROLE_BASE_COLOR, ROLE_EMISSIVE)) == res.srgb
    assert (img.width, img.height) == (w, h) and len(img.levels) == res.levels == mip_level_count(w, h) == len(ref)
    fmt = BLOCK_FORMATS[vk]
    for k, (blocks, lv) in enumerate(zip(img.levels, ref)):
        lh, lw = lv.shape[:2]
        assert blocks.shape == block_level_shape(w, h, k, fmt.block_bytes) == ((lh + 3) // 4, (lw + 3) // 4,
                                                                            fmt.block_bytes)
        got = decode_level(blocks, vk, lw, lh)
        q = level_quality(lv, got, vk, role)
        # Every level: better than one flat colour (direction) per 4x4 block, the simplest block
        # code. Coarse levels hold a lot of content per block, so the level-0 goals do not apply
        # to them (BC7 gives 25-35 dB on the 4x4-16x16 levels of corpus label textures).
        check_against_flat_blocks(lv, q, vk, role, k)
        if k == 0 and role == ROLE_NORMAL:
            assert q <= NORMAL_DEG, f"level 0: {q:.2f} degrees"
        elif k == 0 and fmt.model == 161 and role not in (ROLE_OCCLUSION,):  # ETC2 colour
            assert q >= ETC2_LEVEL0_DB, f"level 0: {q:.2f} dB"
        elif k == 0:
            assert q >= PHOTO_LEVEL0_DB, f"level 0: {q:.2f} dB"


def check_against_flat_blocks(level: np.ndarray, q: float, vk: int, role: str, k: int) -> None:
    """``q`` (the quality of a decoded level) is no worse than one flat colour (direction) per
    4x4 block, the simplest block code: catches wrong blocks, order, swizzle or level."""
    flat = block_mean_quality(level, vk, role)
    if role == ROLE_NORMAL:  # slack: x and y are quantised (to 8 bits in BC5), 0.5 degrees
        assert q <= flat + 0.5, f"level {k}: {q:.2f} degrees, flat blocks {flat:.2f}"
    else:  # RMS error: flat blocks' plus what storing a flat colour costs in the format (the
        # triangle inequality: an encoder that stored the flat blocks would be within this)
        rms, rms_flat = 255.0 / 10 ** (q / 20), 255.0 / 10 ** (flat / 20)
        assert rms <= rms_flat + FLAT_RMS[BLOCK_FORMATS[vk].model], f"level {k}: {q:.2f} dB, flat blocks {flat:.2f}"


def block_mean_quality(level: np.ndarray, vk: int, role: str) -> float:
    """The quality of replacing every 4x4 block of ``level`` by its mean (edge blocks: their
    texels in the level)."""
    h, w = level.shape[:2]
    padded = pad_to_blocks(level).astype(np.float64)
    ph, pw = padded.shape[:2]
    wt = np.zeros((ph, pw, 1))
    wt[:h, :w] = 1.0
    sums = (padded * wt).reshape(ph // 4, 4, pw // 4, 4, 4).sum(axis=(1, 3))
    counts = wt.reshape(ph // 4, 4, pw // 4, 4, 1).sum(axis=(1, 3))
    means = np.repeat(np.repeat(sums / counts, 4, axis=0), 4, axis=1)[:h, :w]
    flat = np.clip(np.rint(means), 0, 255).astype(np.uint8)
    if role == ROLE_NORMAL:  # a flat block of the mean vector, stored as x, y like the format
        flat[..., 2] = 0
    return level_quality(level, flat, vk, role)


def test_decoder_is_independent_and_cropping_is_right():
    """decode_level (texture2ddecoder, BGRA swizzled back) against etcpak's input on a tile whose
    texels are all distinct per 4x4 block, so a wrong crop, swizzle or block order shows."""
    import texture2ddecoder

    rgba = photo(10, 13)
    fmt = choose_format("bc", ROLE_BASE_COLOR, True, False)
    blocks = compress_level(rgba, fmt)
    assert blocks.shape == (3, 4, 16)
    ours = decode_level(blocks, fmt.vk_format, 13, 10)
    raw = np.frombuffer(texture2ddecoder.decode_bc7(blocks.tobytes(), 16, 12), np.uint8).reshape(12, 16, 4)
    assert (ours == raw[:10, :13][..., [2, 1, 0, 3]]).all()
    # the padding repeats the edge; the kept texels are close to the input
    assert (pad_to_blocks(rgba)[10:, :13] == rgba[9]).all()
    assert level_quality(rgba, ours, fmt.vk_format, ROLE_BASE_COLOR) >= block_mean_quality(rgba, fmt.vk_format,
                                                                                         ROLE_BASE_COLOR)


def test_normal_z_is_rebuilt_like_the_shader():
    n = normal_map(8, 8)
    xy_only = n.copy()
    xy_only[..., 2] = 0
    v = rebuild_normal_z(xy_only)
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-5) and (v[..., 2] >= 0).all()
    stored = n[..., :3].astype(np.float32) * 2 / 255 - 1
    stored /= np.linalg.norm(stored, axis=-1, keepdims=True)
    # 8-bit x, y quantisation alone: 1 degree on average (near-horizontal normals lose most:
    # z = sqrt(1 - x^2 - y^2) is steep there)
    assert np.degrees(np.arccos(np.clip((v * stored).sum(-1), -1, 1))).mean() < 1.0


def test_max_size_applies_before_compression():
    src = png_source(photo(64, 128))
    res = process_texture(src, ROLE_BASE_COLOR, options=TextureOptions(max_size=16, compression="bc"))
    img = read_ktx2(res.ktx2)
    assert (img.width, img.height, len(img.levels)) == (16, 8, 5)
    assert [lv.shape[:2] for lv in img.levels] == [(2, 4), (1, 2), (1, 1), (1, 1), (1, 1)]
    plain = read_ktx2(process_texture(src, ROLE_BASE_COLOR, options=TextureOptions(max_size=16)).ktx2).levels
    fmt = BLOCK_FORMATS[img.vk_format]
    # the encoder is deterministic: the blocks are exactly those of the capped uncompressed levels
    assert all((compress_level(lv, fmt) == blocks).all() for lv, blocks in zip(plain, img.levels))


def test_codec_and_settings_are_in_the_options_key():
    keys = {json.dumps(TextureOptions(compression=c, supercompression=s).cache_key(), sort_keys=True)
            for c in ("none", "bc", "etc2") for s in ("none", "zstd")}
    assert len(keys) == 6
    with pytest.raises(ValueError, match="texture compression must be one of none, bc, etc2"):
        TextureOptions(compression="astc")
    with pytest.raises(ValueError, match="supercompression must be none or zstd"):
        TextureOptions(supercompression="lz4")


def test_default_output_is_unchanged_rgba8():
    src = png_source(photo(20, 30))
    res = process_texture(src, ROLE_BASE_COLOR)
    assert res.vk_format == 43 and read_ktx2(res.ktx2).supercompression == 0


def test_zstd_sizes_and_corruption():
    src = png_source(photo(64, 64))
    raw = process_texture(src, ROLE_BASE_COLOR, options=TextureOptions(compression="bc")).ktx2
    z = process_texture(src, ROLE_BASE_COLOR, options=TextureOptions(compression="bc", supercompression="zstd")).ktx2
    a, b = read_ktx2(raw), read_ktx2(z)
    assert all((x == y).all() for x, y in zip(a.levels, b.levels))
    bad = bytearray(z)
    bad[-20] ^= 0xFF  # inside level 0's Zstandard frame
    with pytest.raises(InvalidTextureError, match="level 0: Zstandard data does not decode|level 0: Zstandard data decodes to"):
        read_ktx2(bytes(bad), "bad.ktx2")


# ----------------------------------------------------------------------------- ktx-parse

def _ktx_parse() -> Path | None:
    import os

    repo = Path(__file__).resolve().parents[1]
    for c in (os.environ.get("ASSETPIPE_KTX_PARSE"), repo / ".venv" / "node" / "node_modules" / "ktx-parse"):
        if c and (Path(c) / "package.json").is_file():
            return Path(c)
    return None


_SCRIPT = r"""
import { read, write } from %(module)s;
import { readFileSync } from 'fs';
const src = new Uint8Array(readFileSync(process.argv[2]));
const c = read(src);
const d = c.dataFormatDescriptor[0];
const again = write(c, { keepWriter: true });
console.log(JSON.stringify({
  vkFormat: c.vkFormat, typeSize: c.typeSize, w: c.pixelWidth, h: c.pixelHeight, levelCount: c.levelCount,
  scheme: c.supercompressionScheme,
  dfd: { colorModel: d.colorModel, transferFunction: d.transferFunction, texelBlockDimension: d.texelBlockDimension,
         bytesPlane: d.bytesPlane, samples: d.samples },
  levels: c.levels.map(l => ({ n: l.levelData.byteLength, u: l.uncompressedByteLength })),
  rewrittenIdentical: again.length === src.length && again.every((v, i) => v === src[i]) }));
"""


@pytest.mark.parametrize("codec,role,alpha,zstd", [("bc", ROLE_BASE_COLOR, False, False), ("bc", ROLE_NORMAL, False, True),
                                                  ("bc", ROLE_OCCLUSION, False, False),
                                                  ("etc2", ROLE_BASE_COLOR, True, True),
                                                  ("etc2", ROLE_NORMAL, False, False)])
def test_ktx_parse_reads_block_formats(tmp_path, codec, role, alpha, zstd):
    node, pkg = shutil.which("node"), _ktx_parse()
    if node is None or pkg is None:
        pytest.fail("needs node and ktx-parse (scripts/setup.sh: npm install --prefix .venv/node ktx-parse@2.0.0)")
    script = tmp_path / "p.mjs"
    script.write_text(_SCRIPT % {"module": json.dumps((pkg / "dist" / "index.mjs").as_uri())})
    res = process_texture(png_source(content(role, 30, 45, alpha)), role, "BLEND" if alpha else "OPAQUE", 0.5,
                          TextureOptions(compression=codec, supercompression="zstd" if zstd else "none"))
    path = tmp_path / "t.ktx2"
    path.write_bytes(res.ktx2)
    out = subprocess.run([node, str(script), str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    fmt = BLOCK_FORMATS[res.vk_format]
    assert (got["vkFormat"], got["typeSize"], got["w"], got["h"]) == (res.vk_format, 1, 45, 30)
    assert got["levelCount"] == res.levels and got["scheme"] == (2 if zstd else 0)
    d = got["dfd"]
    assert d["colorModel"] == fmt.model and d["transferFunction"] == (2 if fmt.srgb else 1)
    assert d["texelBlockDimension"] == [3, 3, 0, 0]
    assert d["bytesPlane"] == [fmt.block_bytes, 0, 0, 0, 0, 0, 0, 0]
    assert [(s["bitOffset"], s["bitLength"], s["channelType"]) for s in d["samples"]] == \
        [(off, fmt.sample_bits - 1, ch) for off, ch in fmt.samples]
    assert all(s["sampleLower"] == 0 and s["sampleUpper"] == 0xFFFFFFFF for s in d["samples"])
    for k, lv in enumerate(got["levels"]):
        bh, bw, nb = block_level_shape(45, 30, k, fmt.block_bytes)
        assert lv["u"] == bh * bw * nb
        assert (lv["n"] < lv["u"] + 64) if zstd else (lv["n"] == lv["u"])
    assert got["rewrittenIdentical"]  # same layout, padding and ordering as ktx-parse's writer


# ----------------------------------------------------------------------------- lavapipe

@pytest.mark.vulkan
@pytest.mark.parametrize("codec", ["bc", "etc2"])
def test_compressed_build_validates_on_lavapipe(tmp_path, codec):
    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions
    from assetpipe.renderer.batch import validate_model
    from assetpipe.renderer.validate import ValidateOptions

    repo = Path(__file__).resolve().parents[1]
    opts = BuildOptions(lod=None, texture=TextureOptions(compression=codec, supercompression="zstd"))
    report = run_build([repo / "examples" / "crate" / "crate.gltf"], tmp_path / "out", opts, jobs=1)
    assert not report.failed
    model = tmp_path / "out" / "crate.json"
    side = json.loads((tmp_path / "out" / "crate.asset.json").read_text())
    fmts = {t["vkFormat"] for m in side.get("materials", []) for t in (m.get("textures") or {}).values()}
    assert fmts == {146 if codec == "bc" else 148}
    r = validate_model(model, ValidateOptions(source_root=str(repo / "examples")), isolate=False)
    failed = [c for c in r.checks if c.status == "fail"]
    assert failed == [], [(c.name, c.messages) for c in failed]
    texture = next(c for c in r.checks if c.name == "textures")
    assert texture.status == "pass"
    cpu = [n for n in r.notes if "decoded on the CPU" in n]
    if codec == "bc":  # lavapipe samples BC formats
        assert cpu == []
    else:  # and not ETC2: said plainly, drawn from CPU-decoded levels
        assert len(cpu) == 1 and "ETC2_R8G8B8_SRGB_BLOCK) is not supported for sampling by llvmpipe" in cpu[0]


# ----------------------------------------------------------------------------- corpus

def _corpus_uses(corpus: Path):
    from assetpipe.model_import import import_model

    seen = set()
    files = sorted(list((corpus / "models").rglob("*.gltf")) + list((corpus / "models").rglob("*.glb"))
                   + list((corpus / "models").rglob("*.obj")))
    for f in files:
        for mat in import_model(f).materials:
            for role, ref in mat.textures().items():
                alpha = mat.alpha_mode if role == ROLE_BASE_COLOR else "OPAQUE"
                cutoff = mat.alpha_cutoff if alpha == "MASK" else 0.5
                if (ref.image.digest, role, alpha, cutoff) not in seen:
                    seen.add((ref.image.digest, role, alpha, cutoff))
                    yield ref.image, role, alpha, cutoff


@pytest.mark.corpus
@pytest.mark.parametrize("codec", ["bc", "etc2"])
def test_corpus_every_level_of_every_texture(corpus, codec):
    """Every texture a corpus material uses, every level decoded against the uncompressed build.

    bc: the goals on level 0 (>= 36 dB; >= 38 dB for the JPEG sources, camera and scanned
    content), normal maps <= 2 degrees on every level. etc2: normal maps <= 2 degrees on every
    level; colour only against flat blocks, because etcpak's ETC2 misses the 36 dB goal
    (25.5 dB on UV.png level 0, see benchmarks/textures.py).
    """
    count = 0
    for image, role, alpha, cutoff in _corpus_uses(corpus):
        ref = read_ktx2(process_texture(image, role, alpha, cutoff).ktx2).levels
        img = read_ktx2(process_texture(image, role, alpha, cutoff, TextureOptions(compression=codec)).ktx2)
        assert len(img.levels) == len(ref)
        for k, (blocks, lv) in enumerate(zip(img.levels, ref)):
            q = level_quality(lv, decode_level(blocks, img.vk_format, lv.shape[1], lv.shape[0]), img.vk_format, role)
            where = f"{image.name} ({role}, {alpha}) level {k}"
            check_against_flat_blocks(lv, q, img.vk_format, role, k)
            if role == ROLE_NORMAL:
                assert q <= NORMAL_DEG, f"{where}: {q:.2f} degrees"
            elif codec == "bc" and k == 0:
                goal = PHOTO_LEVEL0_DB if image.mime == "image/jpeg" else COLOUR_DB
                assert q >= goal, f"{where}: {q:.2f} dB"
        count += 1
    assert count >= 30  # 36 uses in the shared corpus today


def test_cli_option(tmp_path):
    from click.testing import CliRunner

    from assetpipe.cli import main

    repo = Path(__file__).resolve().parents[1]
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["build", str(repo / "examples" / "crate" / "crate.gltf"), "-o", str(out), "-q",
                                  "--no-lod", "--texture-compression", "etc2", "--texture-zstd"])
    assert r.exit_code == 0, r.output
    tex = json.loads((out / "crate.asset.json").read_text())["materials"][0]["textures"]["baseColor"]
    img = read_ktx2((out / tex["ktx2"]).read_bytes())
    assert tex["vkFormat"] == img.vk_format == 148 and img.supercompression == 2
    r = CliRunner().invoke(main, ["build", "x.gltf", "--texture-compression", "astc"])
    assert r.exit_code == 2 and "'astc' is not one of 'none', 'bc', 'etc2'" in r.output


@pytest.mark.parametrize("codec, role, alpha", [("etc2", ROLE_BASE_COLOR, True), ("etc2", ROLE_BASE_COLOR, False),
                                                ("bc", ROLE_BASE_COLOR, True), ("etc2", ROLE_NORMAL, False)])
def test_compressing_leaves_the_level_unchanged(codec, role, alpha):
    """etcpak's ETC2 RGBA encoder writes into the buffer it is given: the chain's level (the
    reference of every check, and the source of later steps) must come back as it was."""
    rng = np.random.default_rng(7)
    level = rng.integers(0, 256, (64, 64, 4), dtype=np.uint8)
    if not alpha:
        level[..., 3] = 255
    before = level.copy()
    compress_level(level, choose_format(codec, role, srgb=role == ROLE_BASE_COLOR, has_alpha=alpha))
    np.testing.assert_array_equal(level, before)


def test_eac_r11_blocks_are_the_red_half_of_eac_rg11():
    """EAC R11 comes from etcpak's compress_eac_r, whose buffer holds the R11 blocks in its first
    half: they must be the R halves of EAC RG11's blocks of the same texels (block order too)."""
    level = np.random.default_rng(3).integers(0, 256, (36, 72, 4), dtype=np.uint8)
    r11 = compress_level(level, BLOCK_FORMATS[153])
    rg11 = compress_level(level, BLOCK_FORMATS[155])
    assert r11.shape == (9, 18, 8)
    np.testing.assert_array_equal(r11, rg11[..., :8])


def _cpu_flags() -> set[str]:
    """This CPU's feature flags from /proc/cpuinfo (independent of archspec, which etcpak uses)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    return set(next((ln.split(":", 1)[1].split() for ln in text.splitlines() if ln.startswith("flags")), []))


def test_etc_encoders_run_in_etcpak_simd_build():
    """etcpak 0.9.15's wheel names its SIMD modules so that Python >= 3.8 cannot import them and
    etcpak falls back to its portable build (EAC 33x slower): texture_compress loads the SIMD
    build this CPU runs. On a CPU with AVX2 (or AVX-512 BW/VL) the ETC2/EAC encoders must come
    from it."""
    import etcpak

    from assetpipe.pipelines.texture_compress import etc_module, etcpak_variant

    flags = _cpu_flags()
    folder = Path(etcpak.__file__).parent
    if {"avx512bw", "avx512vl"} <= flags and list(folder.glob("_etcpak_avx512.*.so")):
        expected = "avx512"
    elif "avx2" in flags and list(folder.glob("_etcpak_avx2.*.so")):
        expected = "avx2"
    elif "sse4_1" in flags and list(folder.glob("_etcpak_sse41.*.so")):
        expected = "sse41"
    else:
        expected = "none"
    assert etcpak_variant() == expected
    assert etc_module() is etc_module()  # loaded once per process
    assert callable(etc_module().compress_eac_rg)


# Level 0 of the corpus' textures, etcpak's AVX2 ETC2/EAC build against its portable one
# (benchmarks/textures.py, one run each way): normal maps and occlusion unchanged, colour from
# -1.67 dB (Correct.png, flat label colours; the checker textures -1.5 to -1.6 dB) to +0.53 dB;
# 2 dB allowed.
SIMD_VS_PORTABLE_DB = 2.0


@pytest.mark.parametrize("codec, role, alpha", [("etc2", ROLE_BASE_COLOR, False), ("etc2", ROLE_BASE_COLOR, True),
                                                ("etc2", ROLE_NORMAL, False), ("etc2", ROLE_OCCLUSION, False)])
def test_simd_etc_encoders_match_the_portable_build(codec, role, alpha):
    """The SIMD build's ETC2/EAC blocks decode as close to the level as etcpak's portable
    build's do (the encoders are the same algorithm vectorised; their choices may differ)."""
    import etcpak

    level = pad_to_blocks(content(role, 64, 64, alpha))
    fmt = choose_format(codec, role, srgb=role == ROLE_BASE_COLOR, has_alpha=alpha)
    simd = compress_level(level, fmt)
    fn = {148: etcpak.compress_etc2_rgb, 152: etcpak.compress_etc2_rgba, 155: etcpak.compress_eac_rg,
          153: etcpak.compress_eac_r}[fmt.vk_format]
    portable = np.frombuffer(fn(level.tobytes(), 64, 64), np.uint8)[: simd.size]
    q_simd = level_quality(level, decode_level(simd, fmt.vk_format, 64, 64), fmt.vk_format, role)
    q_port = level_quality(level, decode_level(portable, fmt.vk_format, 64, 64), fmt.vk_format, role)
    if role == ROLE_NORMAL:  # degrees; unchanged on the corpus' normal maps; 6% (0.5 dB of RMS) allowed
        assert q_simd <= q_port * 1.06 + 0.01, (q_simd, q_port)
    else:
        assert q_simd >= q_port - SIMD_VS_PORTABLE_DB, (q_simd, q_port)


def test_bc7_settings_keep_mode_1():
    """The build's BC7 settings (4 mode-1 partitions, no least squares: BC7 is most of the `bc`
    build's time) lose little against etcpak's full search (64 partitions, least squares) on
    photographic content, and much less than leaving mode 1 out, which costs 2.5 dB here."""
    import etcpak

    from assetpipe.pipelines.texture_compress import _bc7_params

    level = photo(128, 128)

    def quality(params) -> float:
        data = np.frombuffer(etcpak.compress_bc7(level.tobytes(), 128, 128, params), np.uint8)
        return level_quality(level, decode_level(data, 146, 128, 128), 146, ROLE_BASE_COLOR)

    def params(partitions: int, least_squares: bool):
        p = etcpak.BC7CompressBlockParams()
        p.init_linear_weights()
        p.m_max_partitions, p.m_try_least_squares = partitions, least_squares
        return p

    ours, full, no_mode1 = quality(_bc7_params()), quality(params(64, True)), quality(params(0, False))
    assert ours >= PHOTO_LEVEL0_DB
    # 1.38 dB: the largest level-0 loss among the corpus' photographic (JPEG) textures
    # (CesiumMan.jpg 49.48 -> 48.10 dB; the worst one, SpiderTex.jpg, 40.28 -> 39.47). Flat-colour
    # label textures lose more (up to 6.4 dB, uv0.png 86.1 -> 79.7) at 42 dB and above.
    assert ours >= full - 1.38, (ours, full)
    assert ours > no_mode1 + 1.0, (ours, no_mode1)


def test_etcpak_build_cap_and_override_choose_the_etc2_encoder(monkeypatch):
    """ASSETPIPE_ETCPAK_BUILD caps the builds this process may use (a farm client keys ETC2 by a
    build every worker runs; a test worker stands for a weaker CPU); use_etcpak_build makes a
    worker encode with the build its task's key names. Each build's blocks are its own."""
    from assetpipe.core.errors import ConfigError
    from assetpipe.pipelines.texture_compress import (ETCPAK_BUILD_ENV, etc_module, etcpak_builds, etcpak_variant,
                                                      use_etcpak_build)
    from assetpipe.steps import texture_key_libs

    builds = etcpak_builds()
    assert builds[-1] == "none" and etcpak_variant() == builds[0]
    rng = np.random.default_rng(7)
    level = rng.integers(0, 256, (16, 16, 4), dtype=np.uint8)
    level[..., 3] = 255
    fmt = choose_format("etc2", ROLE_BASE_COLOR, True, False)
    blocks = {}
    for b in builds:
        with use_etcpak_build(b):
            assert etcpak_variant() == b and etc_module().__spec__.name == f"etcpak._etcpak_{b}"
            assert texture_key_libs({}, {"compression": "etc2"}) == {"etcpak-build": b}
            blocks[b] = compress_level(level, fmt).tobytes()
        assert etcpak_variant() == builds[0]  # the override ends with its block
    if len(builds) > 1:  # the portable build's heuristics differ from the SIMD ones on noise
        assert blocks["none"] != blocks[builds[0]]
    monkeypatch.setenv(ETCPAK_BUILD_ENV, "none")
    assert etcpak_builds() == ("none",) and etcpak_variant() == "none"
    assert compress_level(level, fmt).tobytes() == blocks["none"]
    assert texture_key_libs({}, {"compression": "etc2"}) == {"etcpak-build": "none"}
    with pytest.raises(ConfigError, match=r"etcpak build avx2 does not run here \(this CPU runs none\)"):
        with use_etcpak_build("avx2"):
            pass
    monkeypatch.setenv(ETCPAK_BUILD_ENV, "avx3")
    with pytest.raises(ConfigError, match=r"ASSETPIPE_ETCPAK_BUILD='avx3' is not an etcpak build"):
        etcpak_builds()


def test_benchmark_best_per_block_is_at_least_as_good_as_each_encoder():
    """benchmarks/textures.py section 7 measures 'the better of two encoders per block' (choosing
    between library outputs): the blocks it picks decode at least as close as either input's, and
    each block is one of the inputs' blocks."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from textures import best_per_block

    from assetpipe.pipelines.texture_compress import etcpak_builds, psnr, use_etcpak_build

    rng = np.random.default_rng(3)
    level = np.zeros((32, 32, 4), np.uint8)
    level[..., :3] = rng.integers(0, 256, (32, 32, 3))
    level[8:24, 8:24, :3] = np.linspace(0, 255, 16, dtype=np.uint8)[None, :, None]  # smooth part
    level[..., 3] = 255
    fmt = choose_format("etc2", ROLE_BASE_COLOR, True, False)
    cands = []
    for build in (etcpak_builds()[0], "none"):
        with use_etcpak_build(build):
            cands.append(compress_level(level, fmt).reshape(-1))
    best = best_per_block(level, cands, fmt.vk_format)
    q = [psnr(level[..., :3], decode_level(c, fmt.vk_format, 32, 32)[..., :3]) for c in cands + [best]]
    assert q[2] >= max(q[:2]), q
    blocks = best.reshape(-1, 8)
    assert all((blocks[i] == cands[0].reshape(-1, 8)[i]).all() or (blocks[i] == cands[1].reshape(-1, 8)[i]).all()
               for i in range(blocks.shape[0]))
