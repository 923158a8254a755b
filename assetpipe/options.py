"""The build's options: one frozen dataclass per step, gathered in :class:`BuildOptions`.

The CLI reads its defaults from these module-level defaults. ``lod=None`` builds LOD0 only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from assetpipe.pipelines.budgets import DEFAULT_INPUT_BUDGETS, InputBudgets
from assetpipe.pipelines.lod_options import DEFAULT_LOD_OPTIONS, LodOptions
from assetpipe.pipelines.mesh_options import DEFAULT_MESH_OPTIONS, MeshOptions
from assetpipe.pipelines.texture_options import DEFAULT_TEXTURE_OPTIONS, TextureOptions


@dataclass(frozen=True)
class BuildOptions:
    mesh: MeshOptions = DEFAULT_MESH_OPTIONS
    lod: LodOptions | None = DEFAULT_LOD_OPTIONS
    texture: TextureOptions = DEFAULT_TEXTURE_OPTIONS
    budgets: InputBudgets = DEFAULT_INPUT_BUDGETS  # what one model file may declare (import step)

    def to_json(self) -> dict:
        return {"mesh": dataclasses.asdict(self.mesh),
                "lod": dataclasses.asdict(self.lod) if self.lod is not None else None,
                "texture": dataclasses.asdict(self.texture), "budgets": dataclasses.asdict(self.budgets)}


DEFAULT_BUILD_OPTIONS = BuildOptions()
