"""One reading of a built model's KTX2 files for every check that looks at them.

``textures`` walks every level of every texture, ``roles`` the level nearest 256 px of the same
files: both go through :func:`open_ktx2`, which reads and parses a file once per model (kept
in the model's :attr:`Context.cache <renderer.checks.base.Context.cache>`) and decodes a
block-compressed level (BC / ETC2 / EAC, on the CPU) only when a check asks for it, once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..loader import map_file, read_ktx2


@dataclass(eq=False)
class Ktx2Levels:
    """A parsed KTX2 and its levels as ``(h, w, 4)`` uint8 RGBA (block levels decoded on demand)."""

    name: str
    image: Any  # assetpipe.core.ktx2.Ktx2Image
    _decoded: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def width(self) -> int:
        return int(self.image.width)

    @property
    def height(self) -> int:
        return int(self.image.height)

    @property
    def vk_format(self) -> int:
        return int(self.image.vk_format)

    @property
    def srgb(self) -> bool:
        return bool(self.image.srgb)

    @property
    def block(self) -> Any:
        """The block format (``assetpipe.core.ktx2.BlockFormat``) or None for RGBA8."""
        return self.image.block_format

    @property
    def count(self) -> int:
        return len(self.image.levels)

    @property
    def stored(self) -> int:
        """Channels the format stores (4 for RGBA8; 2 for BC5 / EAC RG11...)."""
        if self.block is None:
            return 4
        from assetpipe.core.ktx2 import stored_channels  # noqa: PLC0415

        return len(stored_channels(self.vk_format))

    def level(self, k: int) -> np.ndarray:
        """Level ``k`` as RGBA texels; raises ValueError when its blocks do not decode."""
        if k not in self._decoded:
            lv = np.asarray(self.image.levels[k])
            if self.block is not None:
                from assetpipe.core.ktx2 import decode_level  # noqa: PLC0415

                lv = decode_level(lv, self.vk_format, max(self.width >> k, 1), max(self.height >> k, 1))
            self._decoded[k] = lv
        return self._decoded[k]

    def nearest(self, px: int) -> int:
        """The first level no larger than ``px`` on its longer side (the last level if none is)."""
        return next((k for k in range(self.count) if max(self.width >> k, self.height >> k) <= px),
                    self.count - 1)


def ktx2_cache_key(path: Path) -> str:
    """The key of the KTX2 at ``path`` in a validation's per-model cache."""
    return f"ktx2:{Path(path).resolve()}"


def open_ktx2(path: Path, cache: dict[str, Any] | None = None) -> Ktx2Levels:
    """The KTX2 at ``path``, parsed once per ``cache``. Raises OSError when it cannot be read and
    whatever the project's reader raises when it does not parse (neither is cached)."""
    key = ktx2_cache_key(path)
    if cache is not None and key in cache:
        return cache[key]
    # read as the loader reads it: a large file mapped, its levels views (only what is sampled
    # is read)
    out = Ktx2Levels(name=str(path), image=read_ktx2(map_file(Path(path)), copy=False))
    if cache is not None:
        cache[key] = out
    return out
