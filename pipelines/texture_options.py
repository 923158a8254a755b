"""Options of the texture step (numpy-free, so the CLI and the no-op build path stay light)."""

from __future__ import annotations

from dataclasses import dataclass

TEXTURE_CODECS = ("none", "bc", "etc2")
"""``--texture-compression`` values: ``none`` (RGBA8, as before), ``bc`` (BC7/BC5/BC4),
``etc2`` (ETC2/EAC); see :mod:`assetpipe.pipelines.texture_compress`."""


@dataclass(frozen=True)
class TextureOptions:
    """Options of the texture step (they belong in the step's cache key).

    ``max_size``: if set, textures whose larger side exceeds it lose whole top mip levels
    (each a halving, filtered exactly as the chain's own levels) until both sides are
    <= ``max_size``. ``None`` keeps the source size.
    ``max_pixels``: images above this many pixels are refused (InvalidTextureError).
    ``compression``: one of :data:`TEXTURE_CODECS`; the KTX2 holds that codec's block format
    per role, every level compressed from the uncompressed chain (after ``max_size``).
    ``supercompression``: ``"none"`` or ``"zstd"`` (KTX2 scheme 2, at ``zstd_level``).
    """

    max_size: int | None = None
    max_pixels: int = 16384 * 16384
    compression: str = "none"
    supercompression: str = "none"
    # 3: the corpus' BC blocks to 0.407 of their size at 30 MB/s; level 19 gives 0.368 at 0.8 MB/s
    # (slower than the BC7 encoder itself); benchmarks/textures.py, section 'zstd levels'.
    zstd_level: int = 3

    def __post_init__(self) -> None:
        if self.max_size is not None and self.max_size < 1:
            raise ValueError(f"max_size must be >= 1 or None, not {self.max_size}")
        if self.compression not in TEXTURE_CODECS:
            raise ValueError(f"texture compression must be one of {', '.join(TEXTURE_CODECS)}, not {self.compression!r}")
        if self.supercompression not in ("none", "zstd"):
            raise ValueError(f"texture supercompression must be none or zstd, not {self.supercompression!r}")
        if not 1 <= self.zstd_level <= 22:
            raise ValueError(f"zstd_level must be 1..22, not {self.zstd_level}")

    def cache_key(self) -> dict:
        return {"max_size": self.max_size, "max_pixels": self.max_pixels, "compression": self.compression,
                "supercompression": self.supercompression, "zstd_level": self.zstd_level}


DEFAULT_TEXTURE_OPTIONS = TextureOptions()
