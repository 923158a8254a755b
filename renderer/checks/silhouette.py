"""``silhouette``: each view's render is not empty and its box matches the CPU projection."""

from __future__ import annotations

import numpy as np

from .. import compare
from ..camera import box_corners, project_points
from ..loader import RenderModel
from ..results import CheckResult
from .base import Check, Context


def drawn_positions(model: RenderModel, lod: int = 0) -> np.ndarray:
    """Positions referenced by the model's LOD ``lod`` draws."""
    used = np.zeros(len(model.positions), bool)
    for m in model.meshes:
        if not m.lods:
            continue
        level = m.lods[min(lod, len(m.lods) - 1)]
        idx = model.indices[level.first_index:level.first_index + level.index_count]
        used[m.vertex_base:m.vertex_base + m.vertex_count][idx] = True
    return model.positions[used]


class SilhouetteCheck(Check):
    name = "silhouette"
    measures = ("per view: the render covers pixels; the covered pixels' bounding box against the CPU "
                "projection of the drawn vertices, and against the projected sidecar bounds")
    tolerance = "bbox_tolerance_px (2 px)"
    reason = ("rasterisation covers a pixel when its centre is inside a triangle, so a box edge can sit up "
              "to 1 px inside the projected extreme vertex; a thin extreme (a spike) can miss one more "
              "pixel centre: 2 px. A transform, scale or vertex-stride bug moves the box by far more")
    needs_render = True

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        model = ctx.model
        assert model is not None
        tol = ctx.options.bbox_tolerance_px
        pts = drawn_positions(model)
        views = []
        for k, (cam, sil) in enumerate(zip(ctx.cams, ctx.coverage)):
            box = compare.bbox(sil)
            fig: dict = {"coverage": round(float(sil.mean()), 5)}
            views.append(fig)
            if box is None:
                r.worst("emptyViews", 1, 0)
                r.messages.append(f"view {k}: the render is empty")
                continue
            fig["renderBox"] = list(box)
            if len(pts):
                px, _ = project_points(cam, pts)
                cpu = (px[:, 0].min(), px[:, 1].min(), px[:, 0].max(), px[:, 1].max())
                fig["cpuBox"] = [round(float(v), 2) for v in cpu]
                err = max(abs(a - b) for a, b in zip(box, cpu))
                fig["maxBoxErrorPx"] = round(float(err), 3)
                if r.worst("boxErrorPx", err, tol):
                    r.messages.append(f"view {k}: silhouette box {box} differs from the CPU projection "
                                      f"{tuple(round(float(v), 1) for v in cpu)} by {err:.1f} px (> {tol})")
            bpx, _ = project_points(cam, box_corners(model.bounds_min, model.bounds_max))
            over = max(bpx[:, 0].min() - box[0], bpx[:, 1].min() - box[1], box[2] - bpx[:, 0].max(),
                       box[3] - bpx[:, 1].max(), 0.0)
            if r.worst("outsideBoundsPx", over, tol):
                r.messages.append(f"view {k}: silhouette box {box} exceeds the projected sidecar bounds by "
                                  f"{over:.1f} px (> {tol})")
        r.figures = {"views": views}
        return r.finish()


CHECK = SilhouetteCheck()
