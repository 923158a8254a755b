"""A minimal KTX2 reader used only while :mod:`assetpipe.ktx2` is absent.

Reads what assetpipe writes: a 2D, single-layer, single-face texture without
supercompression in an uncompressed 4-byte RGBA format (R8G8B8A8 UNORM/SRGB). The
project's reader (``assetpipe.ktx2.read_ktx2``) replaces it as soon as it exists; see
:func:`renderer.loader.read_ktx2`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"
RGBA8_FORMATS = {37, 43}  # VK_FORMAT_R8G8B8A8_UNORM, VK_FORMAT_R8G8B8A8_SRGB


@dataclass
class Ktx2Image:
    """The interface of ``assetpipe.ktx2.Ktx2Image`` that the renderer uses."""

    vk_format: int
    width: int
    height: int
    levels: list[np.ndarray] = field(default_factory=list)  # (h, w, 4) uint8, level 0 first


def read_ktx2(data: bytes) -> Ktx2Image:
    """Parse ``data``; raises ValueError on anything this minimal reader does not handle."""
    if len(data) < 80 or data[:12] != IDENTIFIER:
        raise ValueError("not a KTX2 file (bad identifier or too short)")
    (vk_format, type_size, width, height, depth, layers, faces, level_count,
     scheme) = struct.unpack_from("<9I", data, 12)
    if scheme != 0:
        raise ValueError(f"supercompression scheme {scheme} is not supported")
    if vk_format not in RGBA8_FORMATS:
        raise ValueError(f"vkFormat {vk_format} is not supported by the fallback reader")
    if depth not in (0, 1) or layers > 1 or faces != 1:
        raise ValueError("only 2D single-layer single-face textures are supported")
    count = max(level_count, 1)
    index = struct.unpack_from(f"<{3 * count}Q", data, 80)
    levels = []
    for i in range(count):
        offset, length = index[3 * i], index[3 * i + 1]
        w, h = max(width >> i, 1), max(height >> i, 1)
        if length != w * h * 4 or offset + length > len(data):
            raise ValueError(f"level {i}: {length} bytes at {offset} do not hold {w}x{h} RGBA8 "
                             f"within a {len(data)}-byte file")
        levels.append(np.frombuffer(data, np.uint8, length, offset).reshape(h, w, 4).copy())
    return Ktx2Image(vk_format=vk_format, width=width, height=height, levels=levels)
