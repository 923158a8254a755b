"""``lods``: each LOD at its switch distance looks like LOD0 (culled silhouettes, so holes show)."""

from __future__ import annotations

import math

from .. import compare
from ..camera import fit_camera
from ..results import CheckResult
from .base import Check, Context


class LodsCheck(Check):
    name = "lods"
    measures = ("for each LOD k >= 1, rendered at its switchDistance at the LOD reference pixel scale "
                "(lod_reference_px, lod_reference_fov_deg) from the first view and its opposite, as the pixels whose nearest surface faces the eye "
                "(or is double-sided), so holes and flipped faces show: pixels where LOD k and LOD0 differ and that are more than 1 px from the other's silhouette")
    tolerance = "lod_max_unexplained_px + lod_max_unexplained_fraction x LOD0's area (4 px + 0.2%)"
    reason = ("switchDistance is where the level's Hausdorff error projects to at most 1 px, so a correct "
              "level moves silhouette edges by at most 1 px: anything beyond 1 px is a hole or a flipped "
              "face. The small budget absorbs pixel-centre ties on edges nearly parallel to a row")
    needs_render = True

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        model, options = ctx.model, ctx.options
        assert model is not None
        levels = model.lod_count
        r.figures = {"levels": levels, "perLevel": []}
        if levels <= 1:
            return r.finish()
        ppu = (options.lod_reference_px / 2) / math.tan(math.radians(options.lod_reference_fov_deg) / 2)
        views = (options.views[0], tuple(-c for c in options.views[0]))  # a hole on the far side shows too
        for k in range(1, levels):
            dists = [m.lods[min(k, len(m.lods) - 1)].switch_distance for m in model.meshes if m.lods]
            switch = max(dists) if dists else 0.0
            distance = max(switch, 1.2 * model.radius, 1e-6)  # never closer than the switch distance
            radius_px = model.radius * ppu / distance
            size = int(min(max(2 * radius_px * 1.1 + 4, 32), options.lod_max_render_px))
            fov = math.degrees(2 * math.atan((size / 2) / ppu))
            bad = area = differing = 0
            for view in views:
                cam = fit_camera(model.center, model.radius, view, size, size, fov_y_deg=fov, distance=distance)
                with ctx.timer("render"):
                    a = compare.front(ctx.renderer.render(ctx.gpu, cam, mode="facing", lod=0))
                    b = compare.front(ctx.renderer.render(ctx.gpu, cam, mode="facing", lod=k))
                with ctx.timer("compare"):
                    bad = max(bad, int(compare.unexplained(a, b, 1).sum()))
                    area = max(area, int(a.sum()))
                    differing = max(differing, int((a ^ b).sum()))
            with ctx.timer("compare"):
                budget = options.lod_max_unexplained_px + options.lod_max_unexplained_fraction * area
                r.figures["perLevel"].append({
                    "level": k, "switchDistance": switch, "renderDistance": round(distance, 6),
                    "renderPx": size, "triangles": model.triangles(k), "areaPx": area,
                    "differingPx": differing, "unexplainedPx": bad, "budgetPx": round(budget, 1)})
                if area == 0:
                    r.worst("emptyLod0", 1, 0)
                    r.messages.append(f"LOD{k}: LOD0 covers no pixel at {distance:.4g}")
                elif r.worst("unexplainedOverBudget", bad / max(budget, 1e-9), 1.0):
                    r.messages.append(f"LOD{k}: {bad} pixels differ from LOD0 by more than 1 px at its switch "
                                      f"distance {switch:.4g} (budget {budget:.0f})")
        return r.finish()


CHECK = LodsCheck()
