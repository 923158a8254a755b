"""``bounds``: the sidecar's bounds contain every vertex a draw uses (CPU, no rendering)."""

from __future__ import annotations

import numpy as np

from ..results import CheckResult
from .base import Check, Context


class BoundsCheck(Check):
    name = "bounds"
    measures = ("how far any drawn vertex (any LOD) lies outside the sidecar's bounds box, and outside the "
                "bounding sphere (center, radius), as a fraction of the box diagonal")
    tolerance = "1e-5 of the diagonal"
    reason = ("the bounds are computed from the same float32 positions, so only float rounding of the "
              "JSON-printed min/max/radius (about 1e-7 relative) can separate them; 1e-5 leaves 100x for that "
              "while a culling engine loses geometry at any larger miss")

    LIMIT = 1e-5

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        m = ctx.model
        if m is None or not len(m.positions):
            r.status = "skip"
            r.messages.append("no vertices to check")
            return r.finish()
        used = np.zeros(len(m.positions), bool)
        for mesh in m.meshes:
            for lod in mesh.lods:
                idx = m.indices[lod.first_index:lod.first_index + lod.index_count]
                used[mesh.vertex_base:mesh.vertex_base + mesh.vertex_count][idx] = True
        if not used.any():
            return r.finish()
        p = m.positions[used].astype(np.float64)
        diag = max(float(np.linalg.norm(m.bounds_max - m.bounds_min)), 1e-12)
        box_out = float(np.max(np.maximum(m.bounds_min - p, 0) + np.maximum(p - m.bounds_max, 0))) / diag
        sphere_out = float(np.max(np.linalg.norm(p - m.center, axis=1)) - m.radius) / diag
        r.figures = {"outsideBox": box_out, "outsideSphere": max(sphere_out, 0.0)}
        if r.worst("outsideBox", box_out, self.LIMIT):
            r.messages.append(f"a vertex lies {box_out:.3g} of the diagonal outside the sidecar bounds box "
                              f"(> {self.LIMIT:g})")
        if r.worst("outsideSphere", max(sphere_out, 0.0), self.LIMIT):
            r.messages.append(f"a vertex lies {sphere_out:.3g} of the diagonal outside the bounding sphere "
                              f"(> {self.LIMIT:g})")
        return r.finish()


CHECK = BoundsCheck()
