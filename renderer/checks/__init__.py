"""The validation checks, one module each, behind one interface (:class:`~renderer.checks.base.Check`).

:data:`REGISTRY` is the order the runner runs and reports them in; ``--checks``, the reports
and a baseline name them by ``Check.name``. A new check: a module with a ``Check`` subclass
and ``CHECK = ...``, added here.
"""

from __future__ import annotations

from . import bounds, load, lods, roles, silhouette, source, textures, uvs, vulkan
from .base import Check, Context

REGISTRY: tuple[Check, ...] = (load.CHECK, vulkan.CHECK, bounds.CHECK, silhouette.CHECK, source.CHECK,
                               uvs.CHECK, lods.CHECK, textures.CHECK, roles.CHECK)
BY_NAME: dict[str, Check] = {c.name: c for c in REGISTRY}
NAMES: tuple[str, ...] = tuple(BY_NAME)

__all__ = ["BY_NAME", "Check", "Context", "NAMES", "REGISTRY"]
