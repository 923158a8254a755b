"""A process-wide renderer: one Vulkan context (and so one debug callback) per process.

The validation layer's Python callback can only be registered once per process, and
device set-up is the expensive part, so every in-process user (tests, the renderer worker,
``batch.validate_model(isolate=False)``) shares this one context and renderer.
"""

from __future__ import annotations

import atexit
from pathlib import Path

from .offscreen import Renderer
from .vk_context import VkContext

_RENDERER: Renderer | None = None


def shared_renderer(width: int = 256, height: int = 256, validation: bool = True,
                    shader_cache: Path | None = None) -> Renderer:
    """The process's renderer, created on first use (validation on by default)."""
    global _RENDERER
    if _RENDERER is None or (validation and not _RENDERER.ctx.validation):
        close_shared()
        ctx = VkContext(validation=validation)
        try:
            _RENDERER = Renderer(ctx, width, height, shader_cache=shader_cache)
        except BaseException:
            ctx.close()
            raise
    return _RENDERER


def close_shared() -> None:
    """Destroy the process's renderer and context (registered at exit)."""
    global _RENDERER
    if _RENDERER is not None:
        r, _RENDERER = _RENDERER, None
        r.close()
        r.ctx.close()


atexit.register(close_shared)
