"""Options of the texture step (numpy-free, so the CLI and the no-op build path stay light)."""

from __future__ import annotations

from dataclasses import dataclass

TEXTURE_CODECS = ("none", "bc", "etc2")
"""``--texture-compression`` values: ``none`` (RGBA8, as before), ``bc`` (BC7/BC5/BC4),
``etc2`` (ETC2/EAC); see :mod:`assetpipe.pipelines.texture_compress`."""

OVERSIZE_POLICIES = ("downscale", "refuse")
"""``--oversize-textures`` values: what happens to an image larger than ``max_size``."""

DEFAULT_MAX_TEXTURE_SIZE = 8192
"""The default ``max_size`` (pixels, the larger side). Vulkan guarantees only 4096
(``maxImageDimension2D``'s required minimum); 16384 is the usual desktop limit but a 16384^2
RGBA8 chain is 1.33 GiB of GPU memory for one texture, against 341 MiB at 8192^2, and 8K is
the largest size texture sets are commonly authored at. A larger source (a 419 KB PNG can
decode to 12000x12000) loses whole top mip levels down to <= 8192 with a warning, or is
refused with ``oversize="refuse"``; ``max_size=None`` (CLI ``--max-texture-size 0``) lifts the
cap, leaving only ``max_pixels``."""


@dataclass(frozen=True)
class TextureOptions:
    """Options of the texture step (they belong in the step's cache key).

    ``max_size``: textures whose larger side exceeds it lose whole top mip levels (each a
    halving, filtered exactly as the chain's own levels) until both sides are <= ``max_size``,
    with a warning naming the image, its size and the size built. Default
    :data:`DEFAULT_MAX_TEXTURE_SIZE` (8192: why, there); ``None`` keeps the source size.
    ``oversize``: ``"downscale"`` (as above) or ``"refuse"``: an image larger than ``max_size``
    is refused (InvalidTextureError, from its header, before decoding), as ``max_pixels`` does.
    ``max_pixels``: images above this many pixels are refused (InvalidTextureError).
    ``compression``: one of :data:`TEXTURE_CODECS`; the KTX2 holds that codec's block format
    per role, every level compressed from the uncompressed chain (after ``max_size``).
    ``supercompression``: ``"none"`` or ``"zstd"`` (KTX2 scheme 2, at ``zstd_level``).
    """

    max_size: int | None = DEFAULT_MAX_TEXTURE_SIZE
    max_pixels: int = 16384 * 16384
    compression: str = "none"
    supercompression: str = "none"
    # 1: the corpus' BC blocks to 0.433 of their size at 384 MB/s, level 3 to 0.406 at 200 MB/s
    # (the 2x time for 6% smaller files is 0.04x of the uncompressed build's time, the size goal
    # has a 2x margin); level 19 gives 0.366 at 1.9 MB/s (slower than the BC7 encoder itself);
    # benchmarks/textures.py, section 'zstd levels'.
    zstd_level: int = 1
    oversize: str = "downscale"

    def __post_init__(self) -> None:
        if self.max_size is not None and self.max_size < 1:
            raise ValueError(f"max_size must be >= 1 or None, not {self.max_size}")
        if self.compression not in TEXTURE_CODECS:
            raise ValueError(f"texture compression must be one of {', '.join(TEXTURE_CODECS)}, not {self.compression!r}")
        if self.supercompression not in ("none", "zstd"):
            raise ValueError(f"texture supercompression must be none or zstd, not {self.supercompression!r}")
        if self.oversize not in OVERSIZE_POLICIES:
            raise ValueError(f"oversize must be one of {', '.join(OVERSIZE_POLICIES)}, not {self.oversize!r}")
        if not 1 <= self.zstd_level <= 22:
            raise ValueError(f"zstd_level must be 1..22, not {self.zstd_level}")

    def cache_key(self) -> dict:
        return {"max_size": self.max_size, "max_pixels": self.max_pixels, "compression": self.compression,
                "supercompression": self.supercompression, "zstd_level": self.zstd_level, "oversize": self.oversize}


DEFAULT_TEXTURE_OPTIONS = TextureOptions()
