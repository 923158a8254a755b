"""Options of the mesh-processing step (numpy-free, so the CLI and the no-op build path stay light)."""

from __future__ import annotations

from dataclasses import dataclass

# Attribute names a layout may list, with their float32 component counts.
ATTRIBUTE_COMPONENTS = {"position": 3, "uv0": 2, "normal": 3, "tangent": 4, "uv1": 2, "color": 4}
SEED_LAYOUT = ("position", "uv0")


@dataclass(frozen=True)
class MeshOptions:
    """Options of the mesh-processing step (defaults are the seed format's)."""

    layout: tuple[str, ...] = SEED_LAYOUT
    weld: bool = True
    drop_degenerate: bool = True
    optimize: bool = True
    # a triangle whose doubled area is below this fraction of the squared bounding diagonal is
    # degenerate (zero area up to float rounding)
    degenerate_area_tolerance: float = 1e-14
    # write positions relative to the model's bounding-box centre (the offset goes into the
    # sidecar's ``positionOffset``): float32 keeps ~7 digits, so a model far from its origin
    # loses its shape; engines recentre (docs/FORMAT.md, "Precision")
    recenter: bool = False

    def __post_init__(self):
        unknown = [a for a in self.layout if a not in ATTRIBUTE_COMPONENTS]
        if len(set(self.layout)) != len(self.layout):
            raise ValueError(f"layout names an attribute twice: {self.layout}")
        if unknown or not self.layout or self.layout[0] != "position":
            raise ValueError(f"layout must start with 'position' and use {sorted(ATTRIBUTE_COMPONENTS)}; got {self.layout}")

    @property
    def stride(self) -> int:
        return 4 * sum(ATTRIBUTE_COMPONENTS[a] for a in self.layout)


DEFAULT_MESH_OPTIONS = MeshOptions()
