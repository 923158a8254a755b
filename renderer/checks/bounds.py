"""``bounds``: the sidecar's bounds contain every vertex a draw uses (CPU, no rendering)."""

from __future__ import annotations

import numpy as np

from ..results import CheckResult
from .base import Check, Context


#: the sidecar prints bounds with 9 significant digits (docs/FORMAT.md): a printed value is within
#: half a unit of its ninth digit of the float32 it stands for, at most 5e-9 of itself
PRINT_ROUNDING = 5e-9


def printed_magnitude(side: dict) -> float:
    """The largest absolute coordinate the sidecar prints in its bounds (min, max, center) and
    its radius (0 when they are missing)."""
    b = side.get("bounds") if isinstance(side, dict) else None
    if not isinstance(b, dict):
        return 0.0
    vals = [v for k in ("min", "max", "center") for v in (b.get(k) or []) if isinstance(v, (int, float))]
    if isinstance(b.get("radius"), (int, float)):
        vals.append(b["radius"])
    return float(np.max(np.abs(vals))) if vals else 0.0


class BoundsCheck(Check):
    name = "bounds"
    measures = ("how far any drawn vertex (any LOD) lies outside the sidecar's bounds box, and outside the "
                "bounding sphere (center, radius), as a fraction of the box diagonal")
    tolerance = "1e-5 of the diagonal, plus 5e-9 of the largest printed bounds coordinate"
    reason = ("the bounds are computed from the same float32 positions, so only the rounding of the "
              "JSON-printed min/max/radius to 9 significant digits (at most 5e-9 of the printed value) can "
              "separate them; 1e-5 leaves room for that on a model near its origin, and a model far from it "
              "(coordinates 1e6 diagonals away) gets the printing's own bound on top, while a culling engine "
              "loses geometry at any larger miss")

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
        limit = self.LIMIT + PRINT_ROUNDING * printed_magnitude(m.sidecar) / diag
        r.figures = {"outsideBox": box_out, "outsideSphere": max(sphere_out, 0.0), "limit": limit}
        if r.worst("outsideBox", box_out, limit):
            r.messages.append(f"a vertex lies {box_out:.3g} of the diagonal outside the sidecar bounds box "
                              f"(> {limit:.3g})")
        if r.worst("outsideSphere", max(sphere_out, 0.0), limit):
            r.messages.append(f"a vertex lies {sphere_out:.3g} of the diagonal outside the bounding sphere "
                              f"(> {limit:.3g})")
        return r.finish()


CHECK = BoundsCheck()
