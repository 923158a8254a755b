"""GPU block compression of a finished mip chain: BC4/BC5/BC7 and ETC2/EAC, per texture role.

Pure: uint8 RGBA levels in, block data out. Every level is compressed from the level the mip
step built (gamma-correct, alpha-weighted, coverage-preserving, renormalised; see
:mod:`assetpipe.pipelines.texture_mips`), never from a chain of its own. The block encoders
are ``etcpak`` (chosen by measurement, see ``benchmarks/textures.py``): this module writes no
block encoder.

Formats per codec and role (:func:`choose_format`):

============================  ======================  ============================================
role                          ``bc``                  ``etc2``
============================  ======================  ============================================
baseColor, emissive           BC7_SRGB (146)          ETC2_R8G8B8_SRGB (148) when every alpha is
                                                      255, else ETC2_R8G8B8A8_SRGB (152)
metallicRoughness             BC7_UNORM (145)         ETC2_R8G8B8_UNORM (147)
normal                        BC5_UNORM (141): x, y   EAC_R11G11_UNORM (155): x, y
occlusion (R, stored alone)   BC4_UNORM (139)         EAC_R11_UNORM (153)
============================  ======================  ============================================

Normal maps keep x and y (R, G); the shader rebuilds ``z = sqrt(max(0, 1 - x^2 - y^2))``
(tangent-space normals point out of the surface, z >= 0). Occlusion keeps R (glTF reads
occlusion from R).

Level sizes follow the chain (``max(1, W >> k)``), stored as ``ceil(w / 4) x ceil(h / 4)``
blocks: a level whose side is not a multiple of 4 is padded by repeating its last row/column
before encoding (the padding texels are never sampled), so the small levels down to 1x1 are
one block each.
"""

from __future__ import annotations

import contextlib
import contextvars
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from assetpipe.core.ktx2 import (BLOCK_FORMATS, VK_FORMAT_BC4_UNORM_BLOCK, VK_FORMAT_BC5_UNORM_BLOCK,
                                 VK_FORMAT_BC7_SRGB_BLOCK, VK_FORMAT_BC7_UNORM_BLOCK,
                                 VK_FORMAT_EAC_R11_UNORM_BLOCK, VK_FORMAT_EAC_R11G11_UNORM_BLOCK,
                                 VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK, VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK,
                                 VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK, VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK,
                                 BlockFormat, block_level_shape, decode_level, stored_channels)
from assetpipe.core.errors import ConfigError
from assetpipe.pipelines.model import (ROLE_BASE_COLOR, ROLE_EMISSIVE, ROLE_METALLIC_ROUGHNESS, ROLE_NORMAL,
                                       ROLE_OCCLUSION)
from assetpipe.pipelines.texture_options import TEXTURE_CODECS  # noqa: F401 (re-exported)

__all__ = ["TEXTURE_CODECS", "CompressedChain", "choose_format", "compress_chain", "compress_level", "decode_level",
           "decode_normals", "etc_module", "etcpak_builds", "etcpak_variant", "level_quality", "mean_angle_degrees",
           "pad_to_blocks", "psnr", "rebuild_normal_z", "stored_channels", "use_etcpak_build"]

def choose_format(codec: str, role: str, srgb: bool, has_alpha: bool) -> BlockFormat:
    """The block format for ``role`` under ``codec`` (``"bc"`` or ``"etc2"``), see the table above.

    ``srgb``: the chain's colour is sRGB-encoded (baseColor, emissive). ``has_alpha``: some
    texel of the chain has alpha below 255 (ETC2 then keeps alpha; BC7 always does).
    """
    if codec == "bc":
        if role == ROLE_NORMAL:
            vk = VK_FORMAT_BC5_UNORM_BLOCK
        elif role == ROLE_OCCLUSION:
            vk = VK_FORMAT_BC4_UNORM_BLOCK
        else:
            vk = VK_FORMAT_BC7_SRGB_BLOCK if srgb else VK_FORMAT_BC7_UNORM_BLOCK
    elif codec == "etc2":
        if role == ROLE_NORMAL:
            vk = VK_FORMAT_EAC_R11G11_UNORM_BLOCK
        elif role == ROLE_OCCLUSION:
            vk = VK_FORMAT_EAC_R11_UNORM_BLOCK
        elif role in (ROLE_BASE_COLOR, ROLE_EMISSIVE) and has_alpha:
            vk = VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK if srgb else VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK
        elif role == ROLE_METALLIC_ROUGHNESS or not srgb:
            vk = VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK
        else:
            vk = VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK
    else:
        raise ValueError(f"texture codec {codec!r} compresses nothing (bc or etc2)")
    return BLOCK_FORMATS[vk]


@dataclass(frozen=True, eq=False)
class CompressedChain:
    """``levels[k]``: level k's blocks, ``(ceil(h / 4), ceil(w / 4), block_bytes)`` uint8."""

    format: BlockFormat
    width: int
    height: int
    levels: tuple[np.ndarray, ...]


def pad_to_blocks(level: np.ndarray) -> np.ndarray:
    """``(h, w, 4)`` uint8 -> ``(ceil4(h), ceil4(w), 4)``, C-contiguous, edges repeated."""
    h, w = level.shape[:2]
    if h % 4 == 0 and w % 4 == 0:
        return np.ascontiguousarray(level)
    return np.pad(level, ((0, -h % 4), (0, -w % 4), (0, 0)), mode="edge")


_SIMD_VARIANTS = (("avx512", ("avx512bw", "avx512vl")), ("avx2", ("avx2",)), ("sse41", ("sse4_1",)))
"""etcpak's x86 builds, best first, with the CPU features each needs (as etcpak's __init__)."""

ETCPAK_BUILD_ORDER = ("avx512", "avx2", "sse41", "neon", "none")
"""Every etcpak build name, best first (``neon``: ARM; ``none``: the portable build, runs anywhere)."""

ETCPAK_BUILD_ENV = "ASSETPIPE_ETCPAK_BUILD"
"""Environment variable: the best etcpak build this process may use for ETC2/EAC (``avx512``,
``avx2``, ``sse41``, ``neon`` or ``none``), as if the CPU lacked the better ones. On a farm's
coordinator it makes the ETC2 keys name a build every worker runs; on a worker it stands for a
weaker CPU (tests/test_farm.py)."""

_modules: dict[str, object] = {}
_override: contextvars.ContextVar[str | None] = contextvars.ContextVar("etcpak_build", default=None)


def _module_for(name: str):
    """The etcpak extension module of build ``name``, or None when it does not load here."""
    import sys  # noqa: PLC0415

    if name in _modules:
        return _modules[name]
    full = f"etcpak._etcpak_{name}"
    module = sys.modules.get(full)  # etcpak imported it itself (its portable build, or a fixed wheel)
    if module is None:
        import etcpak  # noqa: PLC0415 - a native library, loaded only when compressing

        module = sys.modules.get(full)
        if module is None:
            module = _load_by_path(etcpak, name)
    _modules[name] = module
    return module


def _load_by_path(etcpak, name: str):
    import importlib.machinery  # noqa: PLC0415
    import importlib.util  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    full = f"etcpak._etcpak_{name}"
    for path in sorted(Path(etcpak.__file__).parent.glob(f"_etcpak_{name}.*.so")):
        try:
            loader = importlib.machinery.ExtensionFileLoader(full, str(path))
            spec = importlib.util.spec_from_file_location(full, str(path), loader=loader)
            module = importlib.util.module_from_spec(spec)
            loader.exec_module(module)
        except (ImportError, OSError):
            continue
        if hasattr(module, "compress_eac_rg") and hasattr(module, "BC7CompressBlockParams"):
            return module
    return None


def etcpak_builds() -> tuple[str, ...]:
    """The etcpak builds this process can encode ETC2/EAC with, best first, always ending with
    ``none`` (portable): the SIMD builds whose CPU features this CPU has and whose module loads,
    capped by :data:`ETCPAK_BUILD_ENV`. Raises ConfigError for an unknown cap."""
    import os  # noqa: PLC0415

    import etcpak  # noqa: PLC0415

    cap = os.environ.get(ETCPAK_BUILD_ENV, "").strip() or None
    if cap is not None and cap not in ETCPAK_BUILD_ORDER:
        raise ConfigError(f"{ETCPAK_BUILD_ENV}={cap!r} is not an etcpak build ({', '.join(ETCPAK_BUILD_ORDER)})")
    try:
        features = set(etcpak.local_host.features)  # archspec's view of this CPU, as etcpak's __init__
    except Exception:  # noqa: BLE001 - no feature list: only what etcpak loaded itself
        features = set()
    out = [name for name, needs in _SIMD_VARIANTS if set(needs) <= features and _module_for(name) is not None]
    import sys  # noqa: PLC0415

    if "etcpak._etcpak_neon" in sys.modules:
        out.append("neon")
    for name, _ in _SIMD_VARIANTS:  # a build etcpak loaded itself runs here whatever archspec says
        if name not in out and f"etcpak._etcpak_{name}" in sys.modules:
            out.append(name)
    out = sorted(set(out), key=ETCPAK_BUILD_ORDER.index) + ["none"]
    if cap is not None:
        out = [n for n in out if ETCPAK_BUILD_ORDER.index(n) >= ETCPAK_BUILD_ORDER.index(cap)]
    return tuple(out)


@contextlib.contextmanager
def use_etcpak_build(name: str):
    """Within this block (this thread or task), ETC2/EAC are encoded by etcpak build ``name``:
    a farm worker encodes with the build its task's key names, not with its own best one (the
    blocks differ between builds). Raises ConfigError when this process cannot run ``name``."""
    if name not in etcpak_builds():
        raise ConfigError(f"etcpak build {name} does not run here (this CPU runs {', '.join(etcpak_builds())})")
    token = _override.set(name)
    try:
        yield
    finally:
        _override.reset(token)


def etc_module():
    """The etcpak extension module the ETC2/EAC encoders run in: the build :func:`etcpak_variant`
    names (BC4/BC5/BC7 use ``etcpak`` as it imports itself, see below).

    etcpak picks ``_etcpak_avx512``/``_avx2``/``_sse41`` by CPU feature and falls back to its
    portable ``_etcpak_none`` on ImportError. Its 0.9.15 wheel is tagged ``cp37-abi3`` (stable
    ABI, every Python >= 3.7), but only the portable module has the ``.abi3.so`` suffix; the
    SIMD modules are named ``.cpython-37m-x86_64-linux-gnu.so``, which no Python >= 3.8 imports,
    so etcpak silently runs its portable build. The SIMD files use only stable-ABI symbols
    (``nm -D``: the same 23 as the portable one), so they are loaded here by path. On
    Avocado_normal.png (2048^2) the AVX2 build encodes EAC RG11 in 0.045 s instead of 1.49 s
    (CPU) and ETC2 RGB in 0.021 s instead of 0.064 s; the whole `etc2` build of the corpus went
    from 3.0x to 1.1x the CPU time of the uncompressed build. Its blocks differ (the same
    method, vectorised, with its own heuristics): on the corpus' level 0s normal maps and
    occlusion are unchanged, colour within -1.67 dB (Correct.png, 31.45 -> 29.78; the checker
    textures -1.5 to -1.6 dB) and +0.53 dB (Arrow.png), the same 18 of 34 textures at >= 36 dB
    (benchmarks/textures.py, one run each way). Because the blocks differ, the texture step's
    key names the build (``assetpipe.steps.texture_key_libs``) and a farm worker encodes with
    the build the key names (:func:`use_etcpak_build`). BC7 and BC4/BC5 stay on etcpak's own
    module: BC7 (bc7enc, scalar) is no faster there, and the AVX2 module's
    ``init_linear_weights`` BC7 came out at 34.4 dB instead of 41.1 dB on a test texture; BC4/BC5
    take 0.02 s per 2048^2 anyway.
    """
    name = etcpak_variant()
    module = _module_for(name)
    if module is None:  # pragma: no cover - etcpak_builds lists only builds that load
        raise ConfigError(f"etcpak build {name} does not load")
    return module


def etcpak_variant() -> str:
    """Which etcpak build encodes ETC2/EAC here and now: the one :func:`use_etcpak_build` set,
    else the best of :func:`etcpak_builds` (``avx512``, ``avx2``, ``sse41``, ``neon`` or
    ``none``, portable)."""
    return _override.get() or etcpak_builds()[0]


BC7_MAX_PARTITIONS = 4
"""Mode-1 partitions etcpak's BC7 encoder tries (0..64); see :func:`_bc7_params`."""

BC7_LEAST_SQUARES = False
"""Whether etcpak's BC7 encoder refines endpoints by least squares; see :func:`_bc7_params`."""


def _bc7_params():
    import etcpak  # noqa: PLC0415

    p = etcpak.BC7CompressBlockParams()
    # Plain RGB error weights instead of etcpak's perceptual default ([128, 64, 16, 32], YCbCr):
    # on the corpus colour textures about 3x faster and 0.5-2.3 dB higher RGB PSNR (the goal's
    # metric); uber level 0 (etcpak's default). Mode 1 tries 4 of its 64 partitions and the
    # least-squares endpoint refinement is off: BC7 is most of the `bc` build's time, and on
    # the corpus' colour level 0s this is 0.64x the CPU time of 8 partitions with least squares
    # (the previous setting; 0.39x of all 64), PSNR mean 53.95 dB (was 54.84), worst 39.47 dB
    # (SpiderTex.jpg; was 40.05; goals 38 photographic, 36 all). 2 partitions without least
    # squares: 0.56x, worst 39.25 dB; no mode 1 at all: 0.34x, worst 36.44 dB
    # (benchmarks/textures.py, section 5).
    p.init_linear_weights()
    p.m_max_partitions = BC7_MAX_PARTITIONS
    p.m_try_least_squares = BC7_LEAST_SQUARES
    return p


def _encoder(vk_format: int):
    import etcpak  # noqa: PLC0415 - a native library, loaded only when compressing

    etc = etc_module()

    if vk_format in (VK_FORMAT_BC7_UNORM_BLOCK, VK_FORMAT_BC7_SRGB_BLOCK):
        params = _bc7_params()
        return lambda data, w, h: etcpak.compress_bc7(data, w, h, params)
    return {
        VK_FORMAT_BC4_UNORM_BLOCK: etcpak.compress_bc4,
        VK_FORMAT_BC5_UNORM_BLOCK: etcpak.compress_bc5,
        VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK: etc.compress_etc2_rgb,
        VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK: etc.compress_etc2_rgb,
        VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK: etc.compress_etc2_rgba,
        VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK: etc.compress_etc2_rgba,
        VK_FORMAT_EAC_R11_UNORM_BLOCK: _eac_r11,
        VK_FORMAT_EAC_R11G11_UNORM_BLOCK: etc.compress_eac_rg,
    }[vk_format]


def _eac_r11(data: bytes, w: int, h: int) -> bytes:
    """EAC R11 blocks from etcpak's ``compress_eac_r``. etcpak 0.9.15's binding returns a
    buffer of 16 bytes per block of which the first half holds the 8-byte R11 blocks in order
    (byte-identical to the R half of ``compress_eac_rg``'s blocks, at half its time: 0.28 s vs
    0.57 s CPU on 1024x1024); the rest is not written by the encoder and is dropped."""
    return etc_module().compress_eac_r(data, w, h)[: w * h // 2]


def compress_level(level: np.ndarray, fmt: BlockFormat) -> np.ndarray:
    """One ``(h, w, 4)`` uint8 RGBA level -> its blocks ``(ceil(h / 4), ceil(w / 4), bytes)``."""
    if level.ndim != 3 or level.shape[2] != 4 or level.dtype != np.uint8:
        raise ValueError(f"a level must be (h, w, 4) uint8, got {level.shape} {level.dtype}")
    h, w = level.shape[:2]
    padded = pad_to_blocks(level)
    ph, pw = padded.shape[:2]
    # etcpak holds the GIL while it encodes (a thread running it lets no Python run), so
    # threads over strips of a level gain nothing: one call per level; levels of many textures
    # run in parallel in the build's worker processes. Always a fresh copy (tobytes): etcpak's
    # ETC1/ETC2/EAC encoders (every build) swap R and B in the buffer they are given, even a
    # `bytes` object, so a second encoder given the same buffer encodes blue as red.
    data = _encoder(fmt.vk_format)(padded.tobytes(), pw, ph)
    shape = (ph // 4, pw // 4, fmt.block_bytes)
    out = np.frombuffer(data, dtype=np.uint8)
    if out.size != shape[0] * shape[1] * shape[2]:  # pragma: no cover - the library's contract
        raise RuntimeError(f"{fmt.name} encoder returned {out.size} bytes for {w}x{h}")
    return out.reshape(shape)


def compress_chain(levels: Sequence[np.ndarray], fmt: BlockFormat) -> CompressedChain:
    """Compress every level of a chain (level 0 first) to ``fmt``."""
    height, width = int(levels[0].shape[0]), int(levels[0].shape[1])
    out = tuple(compress_level(lv, fmt) for lv in levels)
    for k, blocks in enumerate(out):
        assert blocks.shape == block_level_shape(width, height, k, fmt.block_bytes)
    return CompressedChain(format=fmt, width=width, height=height, levels=out)


# ----------------------------------------------------------------------------- decoding

def rebuild_normal_z(rgba: np.ndarray) -> np.ndarray:
    """Decoded two-channel normal map ``(h, w, 4)`` uint8 -> unit vectors ``(h, w, 3)`` float32,
    z rebuilt as the shader does: ``z = sqrt(max(0, 1 - x^2 - y^2))``."""
    xy = rgba[..., :2].astype(np.float32) * (2.0 / 255.0) - 1.0
    z = np.sqrt(np.maximum(0.0, 1.0 - (xy * xy).sum(axis=-1)))
    v = np.concatenate([xy, z[..., None]], axis=-1)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def decode_normals(rgba: np.ndarray) -> np.ndarray:
    """An uncompressed RGBA8 normal level -> unit vectors ``(h, w, 3)`` float32."""
    v = rgba[..., :3].astype(np.float32) * (2.0 / 255.0) - 1.0
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def mean_angle_degrees(a: np.ndarray, b: np.ndarray) -> float:
    """Mean angle in degrees between two ``(h, w, 3)`` unit vector fields."""
    d = np.clip((a.astype(np.float64) * b).sum(axis=-1), -1.0, 1.0)
    return float(np.degrees(np.arccos(d)).mean())


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two uint8 arrays of one shape (inf when identical)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0.0 else 10.0 * float(np.log10(255.0 ** 2 / mse))


def level_quality(reference: np.ndarray, decoded: np.ndarray, vk_format: int, role: str) -> float:
    """How close a decoded level is to the uncompressed level it was made from.

    Normal maps: mean angular error in degrees (reference decoded as stored, decoded with z
    rebuilt). Everything else: PSNR in dB over the channels the format stores (R for BC4/EAC
    R11, RGB for ETC2 RGB8, RGB plus A when the reference has alpha below 255 for RGBA formats).
    """
    if role == ROLE_NORMAL:
        return mean_angle_degrees(decode_normals(reference), rebuild_normal_z(decoded))
    kind = stored_channels(vk_format)
    if kind == "r":
        n = 1
    elif kind == "rg":
        n = 2
    elif kind == "rgb" or not bool((reference[..., 3] < 255).any()):
        n = 3
    else:
        n = 4
    return psnr(reference[..., :n], decoded[..., :n])
