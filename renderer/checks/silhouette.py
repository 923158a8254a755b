"""``silhouette``: each view's render is not empty and its box matches the CPU projection."""

from __future__ import annotations

import dataclasses

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


def drawn_groups(model: RenderModel, lod: int = 0) -> list[np.ndarray]:
    """Per mesh, the positions its LOD ``lod`` draws (meshes drawing nothing left out)."""
    out = []
    for m in model.meshes:
        if not m.lods:
            continue
        level = m.lods[min(lod, len(m.lods) - 1)]
        idx = model.indices[level.first_index:level.first_index + level.index_count]
        if not idx.size:
            continue
        used = np.zeros(m.vertex_count, bool)
        used[idx] = True
        out.append(model.positions[m.vertex_base:m.vertex_base + m.vertex_count][used])
    return out


def group_corners(groups: list[np.ndarray]) -> np.ndarray:
    """(G, 8, 3): the corners of each non-empty group's axis-aligned box (computed once per model,
    shared by the views)."""
    groups = [g for g in groups if len(g)]
    if not groups:
        return np.zeros((0, 8, 3))
    return np.stack([box_corners(g.min(0), g.max(0)) for g in groups])


def projected_box(cam, groups: list[np.ndarray], corners: np.ndarray | None = None,
                  ) -> tuple[float, float, float, float] | None:
    """(x0, y0, x1, y1): the pixel box of the projection of every point of ``groups``, exactly as
    projecting them all, but visiting only the groups that can hold an extreme: a projected coordinate
    is a linear-fractional function of the position (positive denominator in front of the eye), so its
    extremes over a group's axis-aligned box are reached at the box's corners; a group whose corners
    cannot beat the extremes found so far cannot hold a point that does. MetalRoughSpheresNoTextures
    (99 spheres): a few of the 99 projected per view instead of all 521k points."""
    groups = [g for g in groups if len(g)]
    if not groups:
        return None
    if corners is None:
        corners = group_corners(groups)  # (G, 8, 3)
    cpx, _ = project_points(cam, corners.reshape(-1, 3))
    cpx = cpx.reshape(len(groups), 8, 2)
    hi, lo = cpx.max(axis=1), cpx.min(axis=1)  # per group: bounds of what its points can reach
    best_lo, best_hi = np.full(2, np.inf), np.full(2, -np.inf)
    done = np.zeros(len(groups), bool)
    # the groups most likely to hold the extremes first, then every group that could still beat them
    order = np.unique(np.r_[lo.argmin(axis=0), hi.argmax(axis=0)])
    while True:
        for i in order:
            px, _ = project_points(cam, groups[i])
            best_lo, best_hi = np.minimum(best_lo, px.min(0)), np.maximum(best_hi, px.max(0))
            done[i] = True
        order = np.flatnonzero(~done & ((lo < best_lo).any(axis=1) | (hi > best_hi).any(axis=1)))
        if not order.size:
            break
    return float(best_lo[0]), float(best_lo[1]), float(best_hi[0]), float(best_hi[1])


def supersampled_box(ctx: Context, cam, factor: int) -> tuple[float, ...] | None:
    """The covered box of LOD0 seen by ``cam`` rendered at ``factor`` times its pixels a side,
    in ``cam``'s pixel units (x0, y0, x1, y1; x1/y1 exclusive as :func:`compare.bbox`), or None
    when nothing is covered."""
    fine = dataclasses.replace(cam, width=cam.width * factor, height=cam.height * factor)
    with ctx.timer("render"):
        img = ctx.renderer.render(ctx.gpu, fine, mode="facing")
    box = compare.bbox(compare.coverage(img))
    return None if box is None else tuple(v / factor for v in box)


class SilhouetteCheck(Check):
    name = "silhouette"
    measures = ("per view: the render covers pixels; the covered pixels' bounding box against the CPU "
                "projection of the drawn vertices, and against the projected sidecar bounds")
    tolerance = "bbox_tolerance_px (2 px)"
    reason = ("rasterisation covers a pixel when its centre is inside a triangle, so a box edge can sit up "
              "to 1 px inside the projected extreme vertex; a thin extreme (a spike) can miss one more "
              "pixel centre: 2 px. Geometry thinner than a pixel can miss more (a wire 0.3 px wide covers "
              "a pixel centre every 3 px or so), so a view over the tolerance is rendered again at "
              "supersample (4) x the pixels a side and judged on that box, in the same pixel units. A "
              "transform, scale or vertex-stride bug moves the box by far more at any sampling")
    needs_render = True

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        model = ctx.model
        assert model is not None
        tol = ctx.options.bbox_tolerance_px
        with ctx.timer("compare"):
            groups = [g for g in drawn_groups(model) if len(g)]
            corners = group_corners(groups)
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
            with ctx.timer("compare"):
                cpu = projected_box(cam, groups, corners)
            if cpu is not None:
                fig["cpuBox"] = [round(float(v), 2) for v in cpu]
                err = max(abs(a - b) for a, b in zip(box, cpu))
                fig["maxBoxErrorPx"] = round(float(err), 3)
                f = ctx.options.supersample
                if err > tol and f > 1:
                    # a second look, sampled f x f finer: a thin extreme thinner than a pixel covers
                    # pixel centres only here and there; a transform or stride bug stays as far off
                    fine = supersampled_box(ctx, cam, f)
                    if fine is not None:
                        err = max(abs(a - b) for a, b in zip(fine, cpu))
                        fig["supersampledBox"] = [round(v, 2) for v in fine]
                        fig["supersampledBoxErrorPx"] = round(float(err), 3)
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
