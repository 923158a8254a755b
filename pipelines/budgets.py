"""Input budgets: how much a model file may ask us to allocate or compute (issue #13).

A few bytes of glTF JSON can declare a 1e9-element accessor or a node hierarchy that places
a mesh 2^24 times; a 16 MB OBJ can hold 2 million faces. The importers check what a file
*declares* against these budgets **before** allocating anything, and refuse with one line
naming the file and the figure (an :class:`~assetpipe.core.errors.AssetError`).

Numpy-free, so the CLI and the no-op build path stay light. The defaults are module-level
(:data:`DEFAULT_INPUT_BUDGETS`); a build may pass its own :class:`InputBudgets`.
Image decoding has its own limit in :class:`pipelines.texture_options.TextureOptions`
(``max_pixels``, checked from the image header: see :mod:`pipelines.texture_decode`).
"""

from __future__ import annotations

from dataclasses import dataclass

GIB = 1024 ** 3


@dataclass(frozen=True)
class InputBudgets:
    """What one model may declare.

    ``max_model_bytes``: the decoded geometry of a glTF model, estimated from the declared
    accessor counts: every attribute, morph target and index array as the 8-byte-per-value
    arrays the importer makes, times the number of times its mesh is placed by the node
    hierarchy. (An OBJ declares nothing up front: its size is its text, parsed in chunks of
    lines so the parsing temporaries stay bounded; :mod:`pipelines.import_obj`.)
    ``max_placements``: meshes placed by glTF nodes (a hierarchy sharing subtrees multiplies
    them; counted without walking the paths).
    ``max_triangles``: triangles of a model after triangulation, counted before they are made.
    ``max_coordinate``: the largest absolute position coordinate after node transforms.
    1e18 keeps every float32 difference, cross product and squared distance of written
    positions finite (``(2e18)^2 * 3 = 1.2e37 < FLT_MAX = 3.4e38``); a coordinate beyond it
    (``v 1e39 0 0``, a node ``scale [1e300, ...]``) would turn into inf or make every triangle
    "degenerate" once rounded to float32.
    """

    max_model_bytes: int = GIB // 2
    max_placements: int = 1_000_000
    max_triangles: int = 50_000_000
    max_coordinate: float = 1e18

    def __post_init__(self) -> None:
        for name in ("max_model_bytes", "max_placements", "max_triangles"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, not {getattr(self, name)}")
        if not self.max_coordinate > 0:
            raise ValueError(f"max_coordinate must be > 0, not {self.max_coordinate}")


DEFAULT_INPUT_BUDGETS = InputBudgets()


def describe_bytes(n: float) -> str:
    """``3.2 GiB`` style size for messages."""
    for unit, size in (("GiB", GIB), ("MiB", 1024 ** 2), ("KiB", 1024)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"
