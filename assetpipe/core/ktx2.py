"""A small, spec-checked KTX 2.0 writer and reader for 2D mip chains: uncompressed RGBA8, and
the BC4/BC5/BC7 and ETC2/EAC block formats (optionally Zstandard-supercompressed).

Khronos KTX 2.0 file layout (all little-endian)::

    identifier   12 bytes  «KTX 20»\\r\\n\\x1A\\n
    header       9 x UInt32: vkFormat, typeSize, pixelWidth, pixelHeight, pixelDepth,
                 layerCount, faceCount, levelCount, supercompressionScheme
    index        UInt32 dfdByteOffset, dfdByteLength, kvdByteOffset, kvdByteLength,
                 UInt64 sgdByteOffset, sgdByteLength
    level index  levelCount x (UInt64 byteOffset, byteLength, uncompressedByteLength),
                 entry 0 = level 0 (the largest)
    DFD          UInt32 dfdTotalSize + one Basic Data Format Descriptor block
    KVD          (UInt32 keyAndValueByteLength, key NUL value, padding to 4) x N, sorted by key
    levels       stored smallest first (level levelCount-1 first), each preceded by
                 mipPadding so its byteOffset is a multiple of lcm(texel block size, 4)

What we write: 2D textures (pixelDepth 0, layerCount 0, faceCount 1), no supercompression,
``VK_FORMAT_R8G8B8A8_SRGB`` (43) or ``VK_FORMAT_R8G8B8A8_UNORM`` (37), typeSize 1, a Basic
DFD (colour model RGBSDA, primaries BT.709, transfer sRGB or linear, straight alpha, 4
samples of 8 bits; the alpha sample of the sRGB format carries the LINEAR qualifier), and the
key/values ``KTXorientation = "rd"`` (rows go down, columns right: row 0 is the top row as in
glTF / Vulkan) and ``KTXwriter = "assetpipe"``.

Block formats (:data:`BLOCK_FORMATS`: BC4, BC5, BC7 UNORM/sRGB, ETC2 RGB8/RGBA8 UNORM/sRGB,
EAC R11/RG11): typeSize 1, every level stored as ``ceil(w / 4) x ceil(h / 4)`` blocks (down to
the 1x1 level, which is one block), levels aligned to ``lcm(block bytes, 4)``; the DFD is the
one Khronos' ``createDFDCompressed`` writes: colour model BC4 (131), BC5 (132), BC7 (134) or
ETC2 (161), texelBlockDimension 3x3 (4x4 texels), bytesPlane0 = block bytes, one sample per
64/128-bit half of the block (BC5 red/green, ETC2 RGBA8 alpha then colour, EAC RG11 red/green),
lower 0, upper 0xFFFFFFFF, transfer sRGB for the ``*_SRGB`` formats else linear.

Supercompression: scheme 0 (none) or 2 (Zstandard, the ``zstandard`` package, imported only
then): each level is one Zstandard frame (with its content checksum, so a corrupted level is
caught), ``byteLength`` its compressed size and
``uncompressedByteLength`` the level's raw size; no supercompression global data; levels are
not padded (alignment 1), as the specification requires for supercompressed files.

The reader accepts exactly those families (any key/values) and validates every field and offset
it reads; malformed data raises :class:`assetpipe.core.errors.InvalidTextureError` with the
problem in one line.
"""

from __future__ import annotations

import math
import mmap
import os
import struct
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from assetpipe.core.errors import InvalidTextureError

KTX2_IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"
VK_FORMAT_R8G8B8A8_UNORM = 37
VK_FORMAT_R8G8B8A8_SRGB = 43
VK_FORMAT_BC4_UNORM_BLOCK = 139
VK_FORMAT_BC5_UNORM_BLOCK = 141
VK_FORMAT_BC7_UNORM_BLOCK = 145
VK_FORMAT_BC7_SRGB_BLOCK = 146
VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK = 147
VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK = 148
VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK = 151
VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK = 152
VK_FORMAT_EAC_R11_UNORM_BLOCK = 153
VK_FORMAT_EAC_R11G11_UNORM_BLOCK = 155
RGBA8_VK_FORMATS = (VK_FORMAT_R8G8B8A8_UNORM, VK_FORMAT_R8G8B8A8_SRGB)

SUPERCOMPRESSION_NONE = 0
SUPERCOMPRESSION_ZSTD = 2

KHR_DF_MODEL_BC4, KHR_DF_MODEL_BC5, KHR_DF_MODEL_BC7, KHR_DF_MODEL_ETC2 = 131, 132, 134, 161
# channel ids within those models (khr_df.h)
_CH_BC_FIRST, _CH_BC5_GREEN = 0, 1
_CH_ETC2_RED, _CH_ETC2_GREEN, _CH_ETC2_COLOR, _CH_ETC2_ALPHA = 0, 1, 2, 15


@dataclass(frozen=True)
class BlockFormat:
    """A 4x4 block-compressed vkFormat: its name, bytes per block, whether it is sRGB, and the
    DFD it takes: colour model and ``(bitOffset, channelId)`` per 64/128-bit sample."""

    vk_format: int
    name: str
    block_bytes: int
    srgb: bool
    model: int
    samples: tuple[tuple[int, int], ...]

    @property
    def sample_bits(self) -> int:
        return self.block_bytes * 8 // len(self.samples)


BLOCK_FORMATS: dict[int, BlockFormat] = {f.vk_format: f for f in (
    BlockFormat(VK_FORMAT_BC4_UNORM_BLOCK, "BC4_UNORM_BLOCK", 8, False, KHR_DF_MODEL_BC4, ((0, _CH_BC_FIRST),)),
    BlockFormat(VK_FORMAT_BC5_UNORM_BLOCK, "BC5_UNORM_BLOCK", 16, False, KHR_DF_MODEL_BC5,
                ((0, _CH_BC_FIRST), (64, _CH_BC5_GREEN))),
    BlockFormat(VK_FORMAT_BC7_UNORM_BLOCK, "BC7_UNORM_BLOCK", 16, False, KHR_DF_MODEL_BC7, ((0, _CH_BC_FIRST),)),
    BlockFormat(VK_FORMAT_BC7_SRGB_BLOCK, "BC7_SRGB_BLOCK", 16, True, KHR_DF_MODEL_BC7, ((0, _CH_BC_FIRST),)),
    BlockFormat(VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK, "ETC2_R8G8B8_UNORM_BLOCK", 8, False, KHR_DF_MODEL_ETC2,
                ((0, _CH_ETC2_COLOR),)),
    BlockFormat(VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK, "ETC2_R8G8B8_SRGB_BLOCK", 8, True, KHR_DF_MODEL_ETC2,
                ((0, _CH_ETC2_COLOR),)),
    BlockFormat(VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK, "ETC2_R8G8B8A8_UNORM_BLOCK", 16, False, KHR_DF_MODEL_ETC2,
                ((0, _CH_ETC2_ALPHA), (64, _CH_ETC2_COLOR))),
    BlockFormat(VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK, "ETC2_R8G8B8A8_SRGB_BLOCK", 16, True, KHR_DF_MODEL_ETC2,
                ((0, _CH_ETC2_ALPHA), (64, _CH_ETC2_COLOR))),
    BlockFormat(VK_FORMAT_EAC_R11_UNORM_BLOCK, "EAC_R11_UNORM_BLOCK", 8, False, KHR_DF_MODEL_ETC2,
                ((0, _CH_ETC2_RED),)),
    BlockFormat(VK_FORMAT_EAC_R11G11_UNORM_BLOCK, "EAC_R11G11_UNORM_BLOCK", 16, False, KHR_DF_MODEL_ETC2,
                ((0, _CH_ETC2_RED), (64, _CH_ETC2_GREEN))),
)}
_STORED = {  # the channels each block format stores
    VK_FORMAT_BC4_UNORM_BLOCK: "r", VK_FORMAT_EAC_R11_UNORM_BLOCK: "r",
    VK_FORMAT_BC5_UNORM_BLOCK: "rg", VK_FORMAT_EAC_R11G11_UNORM_BLOCK: "rg",
    VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK: "rgb", VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK: "rgb",
    VK_FORMAT_BC7_UNORM_BLOCK: "rgba", VK_FORMAT_BC7_SRGB_BLOCK: "rgba",
    VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK: "rgba", VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK: "rgba",
}


def stored_channels(vk_format: int) -> str:
    """``"r"``, ``"rg"``, ``"rgb"`` or ``"rgba"``: the channels a block format stores."""
    return _STORED[vk_format]


SRGB_VK_FORMATS = frozenset([VK_FORMAT_R8G8B8A8_SRGB] + [f.vk_format for f in BLOCK_FORMATS.values() if f.srgb])
SUPPORTED_VK_FORMATS = RGBA8_VK_FORMATS + tuple(BLOCK_FORMATS)

# Khronos Data Format Specification constants
KHR_DF_VENDORID_KHRONOS = 0
KHR_DF_KHR_DESCRIPTORTYPE_BASICFORMAT = 0
KHR_DF_VERSIONNUMBER_1_3 = 2
KHR_DF_MODEL_RGBSDA = 1
KHR_DF_PRIMARIES_BT709 = 1
KHR_DF_TRANSFER_LINEAR = 1
KHR_DF_TRANSFER_SRGB = 2
KHR_DF_FLAG_ALPHA_STRAIGHT = 0
KHR_DF_CHANNEL_RGBSDA_RED, KHR_DF_CHANNEL_RGBSDA_GREEN, KHR_DF_CHANNEL_RGBSDA_BLUE = 0, 1, 2
KHR_DF_CHANNEL_RGBSDA_ALPHA = 15
KHR_DF_SAMPLE_DATATYPE_LINEAR = 0x10

_HEADER = struct.Struct("<9I4I2Q")  # 36 + 16 + 16 = 68 bytes after the identifier
_LEVEL = struct.Struct("<3Q")
_HEADER_END = len(KTX2_IDENTIFIER) + _HEADER.size  # 80
_TEXEL_BYTES = 4  # R8G8B8A8
_BASIC_BLOCK_HEADER = 24
_SAMPLE_BYTES = 16
WRITER = "assetpipe"


@dataclass(frozen=True, eq=False)
class Ktx2Image:
    """What :func:`read_ktx2` found.

    ``levels[k]``: ``(max(1, height >> k), max(1, width >> k), 4)`` uint8, level 0 first; for a
    block format (:data:`BLOCK_FORMATS`) the level's raw blocks (after any supercompression is
    undone) as ``(ceil(h / 4), ceil(w / 4), block_bytes)`` uint8, rows of blocks top to bottom.
    ``supercompression``: 0 (none) or 2 (Zstandard).
    ``dfd``: the Basic DFD fields (``color_model``, ``color_primaries``, ``transfer_function``,
    ``flags``, ``texel_block_dimension``, ``bytes_plane``, ``samples`` as tuples of
    ``(bit_offset, bit_length, channel_type, sample_position, lower, upper)``).
    ``kv``: key/value data; values are bytes with a trailing NUL stripped when present.
    """

    vk_format: int
    width: int
    height: int
    levels: tuple[np.ndarray, ...]
    dfd: dict = field(default_factory=dict)
    kv: dict[str, bytes] = field(default_factory=dict)
    supercompression: int = SUPERCOMPRESSION_NONE

    @property
    def srgb(self) -> bool:
        return self.vk_format in SRGB_VK_FORMATS

    @property
    def block_format(self) -> BlockFormat | None:
        return BLOCK_FORMATS.get(self.vk_format)


def _pad(n: int, align: int) -> int:
    return (-n) % align


def _basic_dfd(vk_format: int) -> bytes:
    """dfdTotalSize + the Basic DFD block for R8G8B8A8_{SRGB,UNORM}."""
    srgb = vk_format == VK_FORMAT_R8G8B8A8_SRGB
    n_samples = 4
    block_size = _BASIC_BLOCK_HEADER + _SAMPLE_BYTES * n_samples
    words = [
        (KHR_DF_KHR_DESCRIPTORTYPE_BASICFORMAT << 17) | KHR_DF_VENDORID_KHRONOS,
        (block_size << 16) | KHR_DF_VERSIONNUMBER_1_3,
        KHR_DF_MODEL_RGBSDA | (KHR_DF_PRIMARIES_BT709 << 8)
        | ((KHR_DF_TRANSFER_SRGB if srgb else KHR_DF_TRANSFER_LINEAR) << 16)
        | (KHR_DF_FLAG_ALPHA_STRAIGHT << 24),
        0,                 # texelBlockDimension0..3 = 0 (1x1x1x1)
        _TEXEL_BYTES,      # bytesPlane0 = 4, bytesPlane1..3 = 0
        0,                 # bytesPlane4..7 = 0
    ]
    channels = (KHR_DF_CHANNEL_RGBSDA_RED, KHR_DF_CHANNEL_RGBSDA_GREEN, KHR_DF_CHANNEL_RGBSDA_BLUE,
                KHR_DF_CHANNEL_RGBSDA_ALPHA)
    for i, ch in enumerate(channels):
        ctype = ch | (KHR_DF_SAMPLE_DATATYPE_LINEAR if (srgb and ch == KHR_DF_CHANNEL_RGBSDA_ALPHA) else 0)
        words += [(8 * i) | ((8 - 1) << 16) | (ctype << 24), 0, 0, 255]
    block = struct.pack(f"<{len(words)}I", *words)
    return struct.pack("<I", 4 + len(block)) + block


def _block_dfd(fmt: BlockFormat) -> bytes:
    """dfdTotalSize + the Basic DFD block of a 4x4 block format (as createDFDCompressed)."""
    block_size = _BASIC_BLOCK_HEADER + _SAMPLE_BYTES * len(fmt.samples)
    words = [
        (KHR_DF_KHR_DESCRIPTORTYPE_BASICFORMAT << 17) | KHR_DF_VENDORID_KHRONOS,
        (block_size << 16) | KHR_DF_VERSIONNUMBER_1_3,
        fmt.model | (KHR_DF_PRIMARIES_BT709 << 8)
        | ((KHR_DF_TRANSFER_SRGB if fmt.srgb else KHR_DF_TRANSFER_LINEAR) << 16)
        | (KHR_DF_FLAG_ALPHA_STRAIGHT << 24),
        3 | (3 << 8),      # texelBlockDimension0/1 = 4 - 1 (4x4 texels), 2/3 = 0
        fmt.block_bytes,   # bytesPlane0, bytesPlane1..3 = 0
        0,                 # bytesPlane4..7 = 0
    ]
    for bit_offset, channel in fmt.samples:
        words += [bit_offset | ((fmt.sample_bits - 1) << 16) | (channel << 24), 0, 0, 0xFFFFFFFF]
    block = struct.pack(f"<{len(words)}I", *words)
    return struct.pack("<I", 4 + len(block)) + block


def _dfd_for(vk_format: int) -> bytes:
    fmt = BLOCK_FORMATS.get(vk_format)
    return _block_dfd(fmt) if fmt is not None else _basic_dfd(vk_format)


def block_level_shape(width: int, height: int, k: int, block_bytes: int) -> tuple[int, int, int]:
    """``(ceil(h / 4), ceil(w / 4), block_bytes)`` of level ``k`` of a 4x4 block format."""
    h, w = max(1, height >> k), max(1, width >> k)
    return ((h + 3) // 4, (w + 3) // 4, block_bytes)


# ----------------------------------------------------------------------------- block decoding

def _decoder(vk_format: int):
    # texture2ddecoder (Perfare's decoders): independent of the encoder; it returns BGRA.
    # (etcpak's own decompress_* crashed the interpreter here, etcpak 0.9.15.)
    import texture2ddecoder as t2d  # noqa: PLC0415

    return {
        VK_FORMAT_BC4_UNORM_BLOCK: t2d.decode_bc4,
        VK_FORMAT_BC5_UNORM_BLOCK: t2d.decode_bc5,
        VK_FORMAT_BC7_UNORM_BLOCK: t2d.decode_bc7,
        VK_FORMAT_BC7_SRGB_BLOCK: t2d.decode_bc7,
        VK_FORMAT_ETC2_R8G8B8_UNORM_BLOCK: t2d.decode_etc2,
        VK_FORMAT_ETC2_R8G8B8_SRGB_BLOCK: t2d.decode_etc2,
        VK_FORMAT_ETC2_R8G8B8A8_UNORM_BLOCK: t2d.decode_etc2a8,
        VK_FORMAT_ETC2_R8G8B8A8_SRGB_BLOCK: t2d.decode_etc2a8,
        VK_FORMAT_EAC_R11_UNORM_BLOCK: t2d.decode_eacr,
        VK_FORMAT_EAC_R11G11_UNORM_BLOCK: t2d.decode_eacrg,
    }[vk_format]


def decode_level(blocks: np.ndarray, vk_format: int, width: int, height: int) -> np.ndarray:
    """Blocks of one level -> ``(height, width, 4)`` uint8 RGBA (cropped from the padded blocks).

    Decoded with ``texture2ddecoder`` (imported only here), a decoder independent of the
    encoder. Channels a format does not store decode as GPUs sample them: G = B = 0 for BC4/EAC R11,
    B = 0 for BC5/EAC RG11, A = 255 for those and for ETC2 RGB8. Normal maps (BC5/EAC RG11):
    ``assetpipe.pipelines.texture_compress.rebuild_normal_z`` rebuilds z.
    """
    fmt = BLOCK_FORMATS[vk_format]
    bh, bw = (height + 3) // 4, (width + 3) // 4
    if blocks.size != bh * bw * fmt.block_bytes:
        raise ValueError(f"{blocks.size} bytes of {fmt.name} blocks for {width}x{height}")
    raw = _decoder(vk_format)(np.ascontiguousarray(blocks).tobytes(), bw * 4, bh * 4)
    bgra = np.frombuffer(raw, dtype=np.uint8).reshape(bh * 4, bw * 4, 4)[:height, :width]
    rgba = bgra[..., [2, 1, 0, 3]]
    kind = _STORED[vk_format]
    if kind == "r":
        rgba[..., 1:3] = 0
    if kind == "rg":
        rgba[..., 2] = 0
    if kind != "rgba":
        rgba[..., 3] = 255
    return rgba


def _kvd(entries: dict[str, bytes]) -> bytes:
    out = bytearray()
    for key in sorted(entries, key=lambda k: k.encode("utf-8")):
        kv = key.encode("utf-8") + b"\x00" + entries[key]
        out += struct.pack("<I", len(kv)) + kv + b"\x00" * _pad(len(kv), 4)
    return bytes(out)


def expected_level_shapes(width: int, height: int, count: int) -> list[tuple[int, int]]:
    """``[(h, w), ...]`` of ``count`` levels below a ``width`` x ``height`` level 0."""
    return [(max(1, height >> k), max(1, width >> k)) for k in range(count)]


def write_ktx2(levels: Sequence[np.ndarray], vk_format: int, kv: dict[str, bytes] | None = None, *,
               width: int | None = None, height: int | None = None,
               supercompression: int = SUPERCOMPRESSION_NONE, zstd_level: int = 3) -> bytes:
    """Serialise a mip chain as KTX 2.0.

    ``levels``: level 0 first. For RGBA8 (``vk_format`` 43 sRGB or 37 UNORM): each
    ``(max(1, H >> k), max(1, W >> k), 4)`` uint8 RGBA rows top to bottom. For a block format
    (:data:`BLOCK_FORMATS`): each level's blocks as :func:`block_level_shape` gives, and
    ``width``/``height`` (level 0's size in texels) are required. 1 to
    ``floor(log2(max(W, H))) + 1`` levels. ``kv``: extra key/values (bytes values, written as
    given); the ``KTXorientation`` and ``KTXwriter`` entries are always ours.
    ``supercompression``: 0 (none) or 2 (Zstandard at ``zstd_level``, one frame per level).
    Deterministic: the same input gives the same bytes.
    """
    if vk_format not in SUPPORTED_VK_FORMATS:
        raise ValueError(f"vk_format {vk_format} is not supported ({', '.join(map(str, SUPPORTED_VK_FORMATS))})")
    if supercompression not in (SUPERCOMPRESSION_NONE, SUPERCOMPRESSION_ZSTD):
        raise ValueError(f"supercompression scheme {supercompression} is not supported (0 or 2)")
    if not levels:
        raise ValueError("no levels")
    fmt = BLOCK_FORMATS.get(vk_format)
    first = levels[0]
    if fmt is None:
        if first.ndim != 3 or first.shape[2] != 4 or first.dtype != np.uint8:
            raise ValueError(f"level 0 must be (H, W, 4) uint8, got {first.shape} {first.dtype}")
        height, width = int(first.shape[0]), int(first.shape[1])
    elif width is None or height is None:
        raise ValueError(f"{fmt.name}: width and height are required for a block format")
    if width < 1 or height < 1:
        raise ValueError("empty level 0")
    max_levels = max(width, height).bit_length()
    if len(levels) > max_levels:
        raise ValueError(f"{len(levels)} levels for {width}x{height}: at most {max_levels}")
    for k, lv in enumerate(levels):
        if fmt is None:
            shape = (max(1, height >> k), max(1, width >> k), 4)
        else:
            shape = block_level_shape(width, height, k, fmt.block_bytes)
        if lv.shape != shape or lv.dtype != np.uint8:
            raise ValueError(f"level {k} is {lv.shape} {lv.dtype}, expected {shape} uint8")

    n = len(levels)
    entries = dict(kv or {})
    entries["KTXorientation"] = b"rd\x00"
    entries["KTXwriter"] = WRITER.encode("utf-8") + b"\x00"
    dfd = _dfd_for(vk_format)
    kvd = _kvd(entries)
    level_index_end = _HEADER_END + _LEVEL.size * n
    dfd_offset = level_index_end
    kvd_offset = dfd_offset + len(dfd)
    pos = kvd_offset + len(kvd)
    align = _level_align(vk_format, supercompression)
    compress = None
    if supercompression == SUPERCOMPRESSION_ZSTD:
        import zstandard  # noqa: PLC0415 - only supercompressed builds need it

        compress = zstandard.ZstdCompressor(level=zstd_level, write_content_size=True,
                                              write_checksum=True).compress

    offsets, lengths, raw_lengths = [0] * n, [0] * n, [0] * n
    chunks: list = []
    for k in range(n - 1, -1, -1):  # smallest level first in the file
        padding = _pad(pos, align)
        chunks.append(b"\x00" * padding)
        pos += padding
        offsets[k] = pos
        # the level's own buffer (joined once below, not copied first)
        data = memoryview(np.ascontiguousarray(levels[k]).reshape(-1))
        raw_lengths[k] = data.nbytes
        if compress is not None:
            data = compress(data)
        lengths[k] = len(data) if compress is not None else data.nbytes
        chunks.append(data)
        pos += len(data)

    header = KTX2_IDENTIFIER + _HEADER.pack(
        vk_format, 1, width, height, 0, 0, 1, n, supercompression,
        dfd_offset, len(dfd), kvd_offset if kvd else 0, len(kvd), 0, 0)
    index = b"".join(_LEVEL.pack(offsets[k], lengths[k], raw_lengths[k]) for k in range(n))
    return b"".join([header, index, dfd, kvd] + chunks)


def _level_align(vk_format: int, supercompression: int) -> int:
    """Level alignment: lcm(texel block bytes, 4) without supercompression, else 1."""
    if supercompression != SUPERCOMPRESSION_NONE:
        return 1
    fmt = BLOCK_FORMATS.get(vk_format)
    size = fmt.block_bytes if fmt is not None else _TEXEL_BYTES
    return size * 4 // math.gcd(size, 4)


# ----------------------------------------------------------------------------- reader

def _bad(name: str, problem: str) -> InvalidTextureError:
    return InvalidTextureError(name, f"invalid KTX2 file: {problem}")


def read_ktx2(data: bytes, name: str = "<ktx2>", copy: bool = True) -> Ktx2Image:
    """Parse and validate a KTX 2.0 file written as :func:`write_ktx2` writes them.

    ``name`` names the file in errors. ``copy=False``: levels stored without supercompression
    are read-only views of ``data`` (any buffer: bytes, or an ``mmap`` of the file, whose
    pages are then read only where a level is used). Raises :class:`InvalidTextureError` for anything
    malformed (truncated, wrong identifier, unsupported header values, DFD not matching the
    vkFormat, offsets out of range or misaligned or overlapping, levels not stored smallest
    first, bad key/value data).
    """
    buf = memoryview(data)
    size = len(buf)
    if size < _HEADER_END:
        raise _bad(name, f"{size} bytes is shorter than the 80-byte header")
    if bytes(buf[:12]) != KTX2_IDENTIFIER:
        raise _bad(name, "missing the KTX 2.0 identifier")
    (vk_format, type_size, width, height, depth, layers, faces, level_count, scheme,
     dfd_off, dfd_len, kvd_off, kvd_len, sgd_off, sgd_len) = _HEADER.unpack_from(buf, 12)
    if vk_format not in SUPPORTED_VK_FORMATS:
        raise _bad(name, f"vkFormat {vk_format} is not supported (37 R8G8B8A8_UNORM, 43 R8G8B8A8_SRGB, or "
                         f"one of the block formats {', '.join(map(str, BLOCK_FORMATS))})")
    fmt = BLOCK_FORMATS.get(vk_format)
    if type_size != 1:
        raise _bad(name, f"typeSize {type_size}, expected 1 for an 8-bit format")
    if width == 0 or height == 0:
        raise _bad(name, f"pixelWidth/pixelHeight {width}x{height}: a 2D texture needs both")
    if depth != 0 or layers != 0 or faces != 1:
        raise _bad(name, f"pixelDepth {depth}, layerCount {layers}, faceCount {faces}: only 2D (0, 0, 1) is supported")
    if scheme not in (SUPERCOMPRESSION_NONE, SUPERCOMPRESSION_ZSTD):
        raise _bad(name, f"supercompressionScheme {scheme} is not supported (0 none or 2 Zstandard)")
    max_levels = max(width, height).bit_length()
    stored = max(level_count, 1)
    if stored > max_levels:
        raise _bad(name, f"levelCount {level_count} exceeds {max_levels} for {width}x{height}")
    if sgd_off != 0 or sgd_len != 0:
        raise _bad(name, "supercompression global data present (none is used by schemes 0 and 2)")
    index_end = _HEADER_END + _LEVEL.size * stored
    if index_end > size:
        raise _bad(name, "truncated in the level index")

    # DFD
    if dfd_off != index_end:
        raise _bad(name, f"dfdByteOffset {dfd_off}, expected {index_end} (right after the level index)")
    if dfd_len < 4 or dfd_off + dfd_len > size:
        raise _bad(name, f"DFD of {dfd_len} bytes at {dfd_off} exceeds the file ({size} bytes)")
    dfd = _read_dfd(buf[dfd_off:dfd_off + dfd_len], vk_format, name)

    # KVD
    kv: dict[str, bytes] = {}
    if kvd_len:
        if kvd_off != dfd_off + dfd_len:
            raise _bad(name, f"kvdByteOffset {kvd_off}, expected {dfd_off + dfd_len} (right after the DFD)")
        if kvd_off + kvd_len > size:
            raise _bad(name, "truncated in the key/value data")
        kv = _read_kvd(buf[kvd_off:kvd_off + kvd_len], name)
    elif kvd_off != 0:
        raise _bad(name, f"kvdByteOffset {kvd_off} with kvdByteLength 0")
    data_start = (kvd_off + kvd_len) if kvd_len else dfd_off + dfd_len

    # levels
    if fmt is None:
        shapes = [s + (_TEXEL_BYTES,) for s in expected_level_shapes(width, height, stored)]
        what = "RGBA8"
    else:
        shapes = [block_level_shape(width, height, k, fmt.block_bytes) for k in range(stored)]
        what = fmt.name
    align = _level_align(vk_format, scheme)
    decompress = None
    if scheme == SUPERCOMPRESSION_ZSTD:
        import zstandard  # noqa: PLC0415 - only supercompressed files need it

        decompress = zstandard.ZstdDecompressor().decompress
    entries = [_LEVEL.unpack_from(buf, _HEADER_END + _LEVEL.size * k) for k in range(stored)]
    levels = []
    for k in range(stored - 1, -1, -1):  # file order: smallest first
        off, length, ulength = entries[k]
        shape = shapes[k]
        expected = shape[0] * shape[1] * shape[2]
        h, w = max(1, height >> k), max(1, width >> k)
        if ulength != expected:
            raise _bad(name, f"level {k} uncompressedByteLength {ulength}, expected {expected} for {w}x{h} {what}")
        if decompress is None and length != ulength:
            raise _bad(name, f"level {k} byteLength {length} differs from uncompressedByteLength {ulength}")
        if off % align:
            raise _bad(name, f"level {k} byteOffset {off} is not a multiple of {align}")
        if off < data_start or off + length > size:
            raise _bad(name, f"level {k} data [{off}, {off + length}) lies outside the file's level data "
                             f"[{data_start}, {size})")
        data_start = off + length  # the next (larger) level must follow: smallest first, no overlap
        if decompress is None:
            raw = np.frombuffer(buf, dtype=np.uint8, count=length, offset=off)
            if copy:
                raw = raw.copy()
        else:
            try:
                out = decompress(bytes(buf[off:off + length]), max_output_size=ulength)
            except Exception as exc:  # noqa: BLE001 - zstandard.ZstdError and friends: bad data
                raise _bad(name, f"level {k}: Zstandard data does not decode ({exc})") from None
            if len(out) != ulength:
                raise _bad(name, f"level {k}: Zstandard data decodes to {len(out)} bytes, "
                                 f"uncompressedByteLength says {ulength}")
            raw = np.frombuffer(out, dtype=np.uint8).copy()
        levels.append(raw.reshape(shape))
    if data_start != size:
        raise _bad(name, f"{size - data_start} unexpected bytes after level 0")
    levels.reverse()
    return Ktx2Image(vk_format=vk_format, width=width, height=height, levels=tuple(levels), dfd=dfd, kv=kv,
                     supercompression=scheme)


def map_file(path) -> bytes | mmap.mmap:
    """The bytes of a file, mapped read-only when it is large (pages are read when touched);
    small and empty files are read. A mapped file truncated in place meanwhile would fault on
    the pages past its new end; the build replaces files by rename, which leaves the mapped
    one intact (the validator runs each model in a worker that reports a crash)."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size < MAP_MIN_BYTES:
            return f.read()
        return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)


#: files from this size on are mapped by :func:`map_file` (a 4096^2 RGBA8 chain is 89 MB, of which
#: a validation run reads the few levels it draws and samples)
MAP_MIN_BYTES = 1 << 20


def _read_dfd(b: memoryview, vk_format: int, name: str) -> dict:
    total = struct.unpack_from("<I", b, 0)[0]
    if total != len(b):
        raise _bad(name, f"dfdTotalSize {total} differs from dfdByteLength {len(b)}")
    if len(b) < 4 + _BASIC_BLOCK_HEADER:
        raise _bad(name, "DFD too short for a basic descriptor block")
    w0, w1, w2, w3, w4, w5 = struct.unpack_from("<6I", b, 4)
    vendor, dtype = w0 & 0x1FFFF, w0 >> 17
    version, block_size = w1 & 0xFFFF, w1 >> 16
    if vendor != KHR_DF_VENDORID_KHRONOS or dtype != KHR_DF_KHR_DESCRIPTORTYPE_BASICFORMAT:
        raise _bad(name, f"DFD block is vendor {vendor} type {dtype}, expected a Khronos basic block (0, 0)")
    if version != KHR_DF_VERSIONNUMBER_1_3:
        raise _bad(name, f"DFD versionNumber {version}, expected 2")
    if block_size < _BASIC_BLOCK_HEADER or (block_size - _BASIC_BLOCK_HEADER) % _SAMPLE_BYTES \
            or 4 + block_size != len(b):
        raise _bad(name, f"DFD descriptorBlockSize {block_size} does not fit dfdByteLength {len(b)}")
    model, primaries, transfer, flags = w2 & 0xFF, (w2 >> 8) & 0xFF, (w2 >> 16) & 0xFF, w2 >> 24
    tbd = tuple((w3 >> (8 * i)) & 0xFF for i in range(4))
    planes = tuple((w4 >> (8 * i)) & 0xFF for i in range(4)) + tuple((w5 >> (8 * i)) & 0xFF for i in range(4))
    n_samples = (block_size - _BASIC_BLOCK_HEADER) // _SAMPLE_BYTES
    samples = []
    for i in range(n_samples):
        s0, s1, lower, upper = struct.unpack_from("<4I", b, 4 + _BASIC_BLOCK_HEADER + _SAMPLE_BYTES * i)
        samples.append((s0 & 0xFFFF, (s0 >> 16) & 0xFF, s0 >> 24,
                        tuple((s1 >> (8 * j)) & 0xFF for j in range(4)), lower, upper))
    dfd = {"color_model": model, "color_primaries": primaries, "transfer_function": transfer,
           "flags": flags, "texel_block_dimension": tbd, "bytes_plane": planes,
           "samples": tuple(samples)}
    want = _read_dfd_expected(vk_format)
    for key, value in want.items():
        if dfd[key] != value:
            raise _bad(name, f"DFD {key} is {dfd[key]}, expected {value} for vkFormat {vk_format}")
    return dfd


_EXPECTED_DFD: dict[int, dict] = {}


def _read_dfd_expected(vk_format: int) -> dict:
    """The DFD fields :func:`_dfd_for` writes for ``vk_format`` (parsed back, cached)."""
    if vk_format not in _EXPECTED_DFD:
        raw = _dfd_for(vk_format)
        w2, w3, w4, w5 = struct.unpack_from("<4I", raw, 12)
        samples = []
        for i in range((len(raw) - 4 - _BASIC_BLOCK_HEADER) // _SAMPLE_BYTES):
            s0, s1, lower, upper = struct.unpack_from("<4I", raw, 28 + 16 * i)
            samples.append((s0 & 0xFFFF, (s0 >> 16) & 0xFF, s0 >> 24,
                            tuple((s1 >> (8 * j)) & 0xFF for j in range(4)), lower, upper))
        _EXPECTED_DFD[vk_format] = {
            "color_model": w2 & 0xFF, "color_primaries": (w2 >> 8) & 0xFF,
            "transfer_function": (w2 >> 16) & 0xFF, "flags": w2 >> 24,
            "texel_block_dimension": tuple((w3 >> (8 * i)) & 0xFF for i in range(4)),
            "bytes_plane": tuple((w4 >> (8 * i)) & 0xFF for i in range(4)) + tuple((w5 >> (8 * i)) & 0xFF
                                                                                    for i in range(4)),
            "samples": tuple(samples)}
    return _EXPECTED_DFD[vk_format]


def _read_kvd(b: memoryview, name: str) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    pos, end = 0, len(b)
    last_key: bytes | None = None
    while pos < end:
        if pos + 4 > end:
            raise _bad(name, "truncated key/value length")
        length = struct.unpack_from("<I", b, pos)[0]
        pos += 4
        if length == 0 or pos + length > end:
            raise _bad(name, f"key/value entry of {length} bytes overruns the key/value data")
        entry = bytes(b[pos:pos + length])
        nul = entry.find(b"\x00")
        if nul <= 0:
            raise _bad(name, "key/value entry without a NUL-terminated key")
        key_bytes = entry[:nul]
        try:
            key = key_bytes.decode("utf-8")
        except UnicodeDecodeError:
            raise _bad(name, f"key {key_bytes!r} is not UTF-8") from None
        if last_key is not None and key_bytes <= last_key:
            raise _bad(name, f"key/value entries not sorted or repeated at {key!r}")
        last_key = key_bytes
        value = entry[nul + 1:]
        if key.startswith("KTX") and value.endswith(b"\x00"):
            value = value[:-1]
        out[key] = value
        pos += length + _pad(length, 4)
    if pos != end:
        raise _bad(name, "key/value data padding overruns kvdByteLength")
    return out
