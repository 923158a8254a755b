"""``lods``: each LOD at its switch distance looks like LOD0 (culled silhouettes, so holes show)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .. import compare
from ..camera import fit_camera
from ..results import CheckResult
from .base import Check, Context


def boundary_length(model, lod: int) -> float:
    """Total length of the open edges (used by exactly one triangle) at LOD ``lod``."""
    return float(boundary_lengths(model, lod).sum())


def mesh_diagonals(model) -> np.ndarray:
    """(meshes,) the diagonal of each mesh's box (its LOD0 vertices; 0 for an empty mesh)."""
    out = np.zeros(len(model.meshes))
    live = [i for i, mesh in enumerate(model.meshes) if mesh.vertex_count]
    if live:  # per-mesh boxes from one reduceat over the meshes' (disjoint, contiguous) vertex ranges
        order = sorted(live, key=lambda i: model.meshes[i].vertex_base)
        starts = np.array([model.meshes[i].vertex_base for i in order])
        ends = starts + np.array([model.meshes[i].vertex_count for i in order])
        if (starts[1:] >= ends[:-1]).all():
            cut = np.c_[starts, ends].reshape(-1)
            cut = cut[:-1] if cut[-1] == len(model.positions) else cut  # the last range then runs to the end
            hi = np.maximum.reduceat(model.positions, cut, axis=0)[::2].astype(np.float64)
            lo = np.minimum.reduceat(model.positions, cut, axis=0)[::2].astype(np.float64)
            out[order] = np.linalg.norm(hi - lo, axis=1)
            return out
    for i in live:
        mesh = model.meshes[i]
        pos = model.positions[mesh.vertex_base:mesh.vertex_base + mesh.vertex_count]
        out[i] = float(np.linalg.norm(pos.max(0).astype(np.float64) - pos.min(0)))
    return out


def boundary_lengths(model, lod: int, welds: list[np.ndarray] | None = None) -> np.ndarray:
    """(meshes,) length of each mesh's open edges (used by exactly one triangle) at LOD ``lod``.

    Vertices at one position (to float32 rounding, :func:`position_ids`) are one: a UV or
    normal seam is closed, and a crack between its two sides (the copies apart) is open. (Unwelded, a seam
    counted as open in every level alike, which held while simplification only shortened seams;
    a level whose vertices moved (docs/FORMAT.md) can lengthen one without opening it: spider's
    legs at LOD3 1.07x their LOD0 seam length, closed.) Edges are 1-D integer keys (uint32 when
    the mesh has under 65,536 vertices, else int64), so a million triangles take a sort of 3M
    integers. Meshes with the same indices and welding (placed copies of one mesh:
    MetalRoughSpheresNoTextures' 99 spheres) have the same open edges as index pairs: found once,
    measured on each mesh's own positions. ``welds``: :func:`mesh_welds` of the model, made once
    for all its levels (None: made here).
    """
    import hashlib  # noqa: PLC0415

    if welds is None:
        welds = mesh_welds(model)

    total = np.zeros(len(model.meshes))
    found: dict[tuple[int, int, bytes], tuple[np.ndarray, np.ndarray]] = {}  # indices -> open edges (u, v)
    for i, mesh in enumerate(model.meshes):
        if not mesh.lods:
            continue
        level = mesh.lods[min(lod, len(mesh.lods) - 1)]
        t = model.indices[level.first_index:level.first_index + level.index_count].reshape(-1, 3)
        if not len(t):
            continue
        pos = model.positions[mesh.vertex_base:mesh.vertex_base + mesh.vertex_count]
        t = welds[i][t]
        key = (mesh.vertex_count, t.size, hashlib.blake2b(t.tobytes(), digest_size=20).digest())
        if key in found:
            u, v = found[key]
            total[i] = float(np.linalg.norm(pos[u] - pos[v], axis=1).sum()) if u.size else 0.0
            continue
        t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])]  # collapsed triangles draw nothing
        n = mesh.vertex_count + 1
        dtype = np.uint32 if n <= 65535 else np.int64
        a = t.astype(dtype).reshape(-1)                 # corners 0, 1, 2 of each triangle ...
        b = t[:, [1, 2, 0]].astype(dtype).reshape(-1)   # ... and the next corner: the three edges
        keys = np.minimum(a, b) * dtype(n) + np.maximum(a, b)
        keys.sort()
        if keys.size:
            change = keys[1:] != keys[:-1]
            single = keys[np.r_[True, change] & np.r_[change, True]]
        else:
            single = keys
        u, v = single // dtype(n), single % dtype(n)
        found[key] = (u, v)
        if single.size:
            total[i] = float(np.linalg.norm(pos[u] - pos[v], axis=1).sum())
    return total


LOD_MAX_OPEN_EDGE_GROWTH = 0.05  # diagonals; see LodsCheck.reason


#: vertices closer than this many float32 steps of the mesh's largest coordinate are one
#: position for the open-edge count: seam copies computed by different formulas differ in
#: rounding (a UV sphere's seam at sin(2 pi) = -2.4e-16 against 0: the validate fixtures' mask
#: sphere had 5.27 diagonals of such "open" edges at LOD0, which its levels close)
WELD_STEPS = 2


def position_ids(pos: np.ndarray) -> np.ndarray:
    """(N,) for positions (N, 3): each vertex's first vertex at the same position, positions
    rounded to a grid of :data:`WELD_STEPS` float32 steps of the largest coordinate (the same
    dtype as an index: uint32, or int64 from 2^32 vertices)."""
    n = pos.shape[0]
    p = np.asarray(pos, np.float64)
    top = float(np.abs(p).max()) if n else 0.0
    step = top * WELD_STEPS * 2.0 ** -23 if np.isfinite(top) and top > 0 else 1.0
    q = np.round(np.where(np.isfinite(p), p, 0.0) / step).astype(np.int64)
    order = np.lexsort((q[:, 2], q[:, 1], q[:, 0]))  # stable: equal rows keep index order
    s = q[order]
    new = np.r_[True, np.any(s[1:] != s[:-1], axis=1)] if n else np.zeros(0, bool)
    ids = np.empty(n, np.int64)
    ids[order] = order[new][np.cumsum(new) - 1]
    return ids.astype(np.uint32) if n < 2**32 else ids


def mesh_welds(model) -> list[np.ndarray]:
    """Per mesh, :func:`position_ids` of its vertex range (its levels' indices map through it)."""
    return [position_ids(model.positions[m.vertex_base:m.vertex_base + m.vertex_count]) for m in model.meshes]


def nearest_drawn(model, point: np.ndarray) -> np.ndarray | None:
    """The LOD0 vertex a draw uses nearest ``point`` (float64 (3,)), or None when none is drawn."""
    from .silhouette import drawn_positions  # noqa: PLC0415

    p = drawn_positions(model, 0).astype(np.float64)
    if not len(p):
        return None
    return p[int(np.argmin(np.einsum("ij,ij->i", p - point, p - point)))]


def budget_for(options, area: float) -> float:
    """Unexplained pixels allowed where LOD0 covers ``area`` pixels."""
    return options.lod_max_unexplained_px + options.lod_max_unexplained_fraction * area


@dataclass(frozen=True)
class _Lod0Picture:
    """LOD0 as the lods check pictures it: the camera (every level is drawn with it), the
    front-facing pixels, whether any pixel is covered, and whether the camera was aimed at the
    nearest drawn vertex or turned to the opposite side (see ``LodsCheck._lod0_picture``)."""
    cam: object
    front: np.ndarray
    covered: bool
    reaimed: bool
    flipped: bool


class LodsCheck(Check):
    name = "lods"
    measures = ("the length of LOD k's open edges against LOD0's, for the model and for each mesh; and for each LOD k >= 1, rendered at its switchDistance at the LOD reference pixel scale "
                "(lod_reference_px, lod_reference_fov_deg) from the first view, as the pixels whose nearest surface faces the eye "
                "(or is double-sided), so holes and flipped faces show: pixels where LOD k and LOD0 differ and that are more than 1 px from the other's silhouette")
    tolerance = ("lod_max_unexplained_px + lod_max_unexplained_fraction x LOD0's area (4 px + 0.2%); open "
                 "edges at most 0.05 diagonals longer than LOD0's (the model's diagonal; each mesh's against its own)")
    reason = ("switchDistance is where the level's Hausdorff error projects to at most 1 px, so a correct "
              "level moves silhouette edges by at most 1 px: anything beyond 1 px is a hole or a flipped "
              "face. The small budget absorbs pixel-centre ties on edges nearly parallel to a row. Geometry "
              "thinner than a pixel is dotted at one sample a pixel, and the dots of two levels fall apart: "
              "a level over the budget is rendered again at supersample (4) x the pixels a side and judged "
              "on that picture in the same pixel units (sub-pixels more than 4 from the other's silhouette, "
              "each 1/16 px), where a hole still shows. "
              "Holes a double-sided closed mesh hides in every picture show as open edges (vertices at identical "
              "positions welded, so seams are closed and a crack between a seam's sides is open): simplifying "
              "straightens borders, so LOD k's open edges were never longer than LOD0's (growth never above 0 "
              "over 74 LOD levels of 19 corpus and generated models, seams then counted unwelded); 0.05 "
              "diagonals leaves room for a border vertex moved by its Hausdorff error. Per mesh as well: a hole in "
              "a small part of a large model is small against the model's diagonal (2CylinderEngine: under 0.05) "
              "but not against the part's (3.36 of its diagonal); per-mesh growth was never above 0 either "
              "(60 levels of 20 models)")
    needs_render = True

    @staticmethod
    def _lod0_picture(ctx: Context, model, view, size: int, fov: float, distance: float) -> "_Lod0Picture":
        """LOD0's lods picture at ``distance``: from ``view`` at the model's centre; where that
        picture (capped at lod_max_render_px: the middle of the model) covers nothing, as for a
        ring or a frame, aimed at the drawn LOD0 vertex nearest the centre; where it shows only
        back faces, as for a one-sided sheet (a ceiling, a wall) facing away, from the opposite
        side. A closed model turned inside out shows back faces from both and stays so."""
        def picture(aim, direction, reaimed: bool, flipped: bool) -> _Lod0Picture:
            cam = fit_camera(aim, model.radius, direction, size, size, fov_y_deg=fov, distance=distance)
            img = ctx.renderer.render(ctx.gpu, cam, mode="facing", lod=0)
            return _Lod0Picture(cam, compare.front(img), bool(compare.coverage(img).any()), reaimed, flipped)

        got = picture(model.center, view, False, False)
        if not got.covered:
            near = nearest_drawn(model, model.center)
            if near is not None:
                got = picture(near, view, True, False)
        if got.covered and not got.front.any():
            other = picture(got.cam.target, tuple(-float(x) for x in view), got.reaimed, True)
            if other.front.any():
                got = other
        return got

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        model, options = ctx.model, ctx.options
        assert model is not None
        levels = model.lod_count
        r.figures = {"levels": levels, "perLevel": []}
        if levels <= 1:
            return r.finish()
        ppu = (options.lod_reference_px / 2) / math.tan(math.radians(options.lod_reference_fov_deg) / 2)
        with ctx.timer("compare"):
            diag = max(float(np.linalg.norm(model.bounds_max - model.bounds_min)), 1e-12)
            welds = mesh_welds(model)  # one welding per mesh, for every level
            open0 = boundary_lengths(model, 0, welds)
            mesh_diag = np.maximum(mesh_diagonals(model), 1e-12)
        # one view: a hole on the far side shows as open edges (above), and each view costs two renders
        # of the full LOD0 per level (4 s of lavapipe time for a 1M-triangle model under load)
        views = (options.views[0],)
        lod0: dict[tuple, np.ndarray] = {}  # LOD0's picture per camera: levels clamped to one distance share it
        for k in range(1, levels):
            dists = [m.lods[min(k, len(m.lods) - 1)].switch_distance for m in model.meshes if m.lods]
            switch = max(dists) if dists else 0.0
            distance = max(switch, 1.2 * model.radius, 1e-6)  # never closer than the switch distance
            radius_px = model.radius * ppu / distance
            size = int(min(max(2 * radius_px * 1.1 + 4, 32), options.lod_max_render_px))
            fov = math.degrees(2 * math.atan((size / 2) / ppu))
            bad = area = differing = 0
            fine_bad: float | None = None
            reaimed = back_only = flipped_view = False
            for view in views:
                with ctx.timer("render"):
                    key = (view, distance, size, fov)
                    if key not in lod0:
                        lod0[key] = self._lod0_picture(ctx, model, view, size, fov, distance)
                    pic = lod0[key]
                    cam, a = pic.cam, pic.front
                    back_only = back_only or (pic.covered and not a.any())
                    reaimed, flipped_view = reaimed or pic.reaimed, flipped_view or pic.flipped
                    b = compare.front(ctx.renderer.render(ctx.gpu, cam, mode="facing", lod=k))
                with ctx.timer("compare"):
                    view_bad = int(compare.unexplained(a, b, 1).sum())
                    view_area = int(a.sum())
                    area = max(area, view_area)
                    differing = max(differing, int((a ^ b).sum()))
                f = options.supersample
                if view_bad > budget_for(options, view_area) and f > 1:
                    # a second look, sampled f x f finer (the same picture, judged in the same pixel
                    # units: sub-pixels more than f from the other's silhouette, counted as 1/f^2
                    # of a pixel): geometry thinner than a pixel is dotted at one sample a pixel,
                    # and the dots of LOD0 and LOD k fall in different places; a hole stays
                    fine = dataclasses.replace(cam, width=size * f, height=size * f)
                    with ctx.timer("render"):
                        a_f = compare.front(ctx.renderer.render(ctx.gpu, fine, mode="facing", lod=0))
                        b_f = compare.front(ctx.renderer.render(ctx.gpu, fine, mode="facing", lod=k))
                    with ctx.timer("compare"):
                        view_bad = int(compare.unexplained(a_f, b_f, f).sum()) / (f * f)
                        fine_bad = max(fine_bad or 0.0, view_bad)
                bad = max(bad, view_bad)
            with ctx.timer("compare"):
                grown = boundary_lengths(model, k, welds) - open0
                growth = float(grown.sum()) / diag
                if r.worst("openEdgeGrowth", growth, LOD_MAX_OPEN_EDGE_GROWTH):
                    r.messages.append(f"LOD{k}: its open edges are {growth:.3g} diagonals longer than LOD0's "
                                      f"(> {LOD_MAX_OPEN_EDGE_GROWTH}; a hole?)")
                per_mesh = grown / mesh_diag  # a hole in a small part is small against the model's diagonal
                worst_mesh = int(np.argmax(per_mesh)) if per_mesh.size else 0
                mesh_growth = float(per_mesh[worst_mesh]) if per_mesh.size else 0.0
                if r.worst("meshOpenEdgeGrowth", mesh_growth, LOD_MAX_OPEN_EDGE_GROWTH) and growth <= \
                        LOD_MAX_OPEN_EDGE_GROWTH:
                    r.messages.append(f"LOD{k}: mesh {model.meshes[worst_mesh].id}'s open edges are {mesh_growth:.3g} "
                                      f"of its diagonal longer than at LOD0 (> {LOD_MAX_OPEN_EDGE_GROWTH}; a hole?)")
                budget = budget_for(options, area)
                r.figures["perLevel"].append({
                    "level": k, "openEdgeGrowth": round(growth, 5), "meshOpenEdgeGrowth": round(mesh_growth, 5), "switchDistance": switch, "renderDistance": round(distance, 6),
                    "renderPx": size, "triangles": model.triangles(k), "areaPx": area,
                    "differingPx": differing, "unexplainedPx": round(bad, 2), "budgetPx": round(budget, 1)})
                if reaimed:  # LOD0 covered nothing in the middle of the model
                    r.figures["perLevel"][-1]["aimedAtNearestVertex"] = True
                if flipped_view:  # LOD0 showed only back faces from the first view
                    r.figures["perLevel"][-1]["seenFromOppositeSide"] = True
                if fine_bad is not None:  # the second look decided
                    r.figures["perLevel"][-1]["supersampledUnexplainedPx"] = round(fine_bad, 2)
                if area == 0 and back_only:
                    r.worst("emptyLod0", 1, 0)
                    r.messages.append(f"LOD{k}: LOD0 shows only back faces at {distance:.4g}: its triangles face "
                                      "away from the eye (inside out? check the source's winding)")
                elif area == 0:
                    r.worst("emptyLod0", 1, 0)
                    r.messages.append(f"LOD{k}: LOD0 covers no pixel at {distance:.4g}")
                elif r.worst("unexplainedOverBudget", bad / max(budget, 1e-9), 1.0):
                    r.messages.append(f"LOD{k}: {bad} pixels differ from LOD0 by more than 1 px at its switch "
                                      f"distance {switch:.4g} (budget {budget:.0f})")
        return r.finish()


CHECK = LodsCheck()
