"""Options of the texture step (numpy-free, so the CLI and the no-op build path stay light)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TextureOptions:
    """Options of the texture step (they belong in the step's cache key).

    ``max_size``: if set, textures whose larger side exceeds it lose whole top mip levels
    (each a halving, filtered exactly as the chain's own levels) until both sides are
    <= ``max_size``. ``None`` keeps the source size.
    ``max_pixels``: images above this many pixels are refused (InvalidTextureError).
    """

    max_size: int | None = None
    max_pixels: int = 16384 * 16384

    def __post_init__(self) -> None:
        if self.max_size is not None and self.max_size < 1:
            raise ValueError(f"max_size must be >= 1 or None, not {self.max_size}")

    def cache_key(self) -> dict:
        return {"max_size": self.max_size, "max_pixels": self.max_pixels}


DEFAULT_TEXTURE_OPTIONS = TextureOptions()
