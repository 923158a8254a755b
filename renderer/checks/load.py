"""``load``: the built files read back consistently (see :mod:`renderer.loader`)."""

from __future__ import annotations

from ..results import CheckResult
from .base import Check, Context


class LoadCheck(Check):
    name = "load"
    measures = ("the seed and sidecar JSON parse; .idx/.vtx sizes match the meshes' byte ranges and the "
                "vertex stride; every index is below its mesh's vertex count; every materialId exists; "
                "every position is finite")
    tolerance = "none: any inconsistency fails"
    reason = ("these are exact facts of the format (docs/FORMAT.md): an engine reading a file that breaks "
              "one of them reads out of bounds or draws garbage, so there is no acceptable amount")

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        if ctx.load_error is not None:
            r.messages.append(ctx.load_error)
            r.worst("errors", 1, 0)
            return r.finish()
        m = ctx.model
        assert m is not None
        r.figures = {"meshes": len(m.meshes), "materials": len(m.materials), "vertices": int(len(m.positions)),
                     "triangles": m.triangles(0), "lods": m.lod_count}
        return r.finish()


CHECK = LoadCheck()
