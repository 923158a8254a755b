"""``uvs``: each built vertex's uv0 is a UV the source has at that position (CPU, no rendering)."""

from __future__ import annotations

import numpy as np

from ..results import CheckResult
from .base import Check, Context
from .source import load_source

# float32 UVs are copied, not recomputed: they agree to float32 rounding of the node transform's
# effect on nothing (UVs are not transformed), i.e. exactly, up to the layout's storage precision.
UV_STORAGE_TOLERANCE = {"float32": 1e-5, "float16": 1e-3, "unorm16": 1.0 / 65535 + 1e-6,
                        "unorm8": 1.0 / 255 + 1e-6}


class UvsCheck(Check):
    name = "uvs"
    measures = ("for every LOD0 vertex of the build: the distance from its uv0 to the nearest UV of a source "
                "vertex at the same position, in the UV set the base colour samples with its texture transform "
                "(trimesh import; positions matched within 1e-4 of the diagonal); "
                "the largest over all vertices, and the fraction of vertices further than the tolerance")
    tolerance = "the uv0 storage precision: 1e-5 for float32 (1e-3 float16, 1/65535 unorm16)"
    reason = ("the build copies UVs (the base colour's UV set, a KHR_texture_transform baked in: the reference "
              "reads that set and applies the transform itself, renderer/source_model.py): a "
              "welded vertex keeps a UV the source has at that position, so any difference beyond the storage "
              "rounding is a flipped or shifted UV, whatever the texture looks like")

    def run(self, ctx: Context) -> CheckResult:
        from scipy.spatial import cKDTree  # noqa: PLC0415

        from ..source_model import uv_caveat  # noqa: PLC0415

        r = self.result()
        model = ctx.model
        assert model is not None
        attrs = {str(a.get("name", "")).lower(): a for a in (model.sidecar.get("vertexLayout") or {}).get(
            "attributes", [])}
        if "uv0" not in attrs:
            r.status = "skip"
            r.messages.append("the built layout has no uv0")
            return r.finish()
        src, source, why = load_source(ctx)
        if source is None:
            r.status = "skip"
            r.messages.append(str(why))
            return r.finish()
        ref_uvs = source.sidecar.get("referenceUvs")  # the base colour's UV set, transformed (glTF sources)
        caveat = uv_caveat(src) if ref_uvs is None else None
        has_uv = np.asarray([m.texture is not None for m in source.materials])
        if ref_uvs is not None:
            has_uv[:] = True
        if caveat or not has_uv.any():
            r.status = "skip"
            r.messages.append(caveat or "trimesh found no UVs in the source")
            return r.finish()
        fmt = str(attrs["uv0"].get("format", "float32x2")).split("x")[0]
        tol = UV_STORAGE_TOLERANCE.get(fmt, 1e-3)
        with ctx.timer("compare"):
            # source vertices that carry UVs (their material has a texture: trimesh read a uv array)
            keep = np.zeros(len(source.positions), bool)
            for mesh in source.meshes:
                if has_uv[mesh.material]:
                    keep[mesh.vertex_base:mesh.vertex_base + mesh.vertex_count] = True
            if ref_uvs is not None:
                keep &= source.sidecar["referenceUvMask"]
            used = np.zeros(len(model.positions), bool)
            for mesh in model.meshes:
                if mesh.lods and model.materials[mesh.material].texture is not None:
                    lod = mesh.lods[0]
                    idx = model.indices[lod.first_index:lod.first_index + lod.index_count]
                    used[mesh.vertex_base:mesh.vertex_base + mesh.vertex_count][idx] = True
            if not used.any():
                r.status = "skip"
                r.messages.append("no textured vertices")
                return r.finish()
            diag = max(float(np.linalg.norm(model.bounds_max - model.bounds_min)), 1e-12)
            suv_all = source.uvs if ref_uvs is None else ref_uvs
            spos, suv = source.positions[keep].astype(np.float64), suv_all[keep].astype(np.float64)
            bpos, buv = model.positions[used].astype(np.float64), model.uvs[used].astype(np.float64)
            # candidates: the source vertices within 1e-4 of the diagonal (a seam holds 2-4 at one position,
            # a pole of a UV sphere one per segment); the error is the UV distance to the nearest candidate's UV
            tree = cKDTree(spos)
            radius = 1e-4 * diag
            err = np.full(len(bpos), np.nan)
            todo = np.arange(len(bpos))
            k = 8
            while todo.size:
                kk = min(k, len(spos))
                d, j = tree.query(bpos[todo], k=kk, distance_upper_bound=radius)
                d, j = d.reshape(len(todo), -1), j.reshape(len(todo), -1)
                valid = np.isfinite(d)
                jj = np.where(valid, j, 0)
                uvd = np.where(valid, np.linalg.norm(suv[jj] - buv[todo][:, None, :], axis=2), np.inf)
                best = uvd.min(axis=1)
                err[todo] = np.where(valid.any(axis=1), best, np.nan)
                full = valid.all(axis=1) & (best > tol) & (kk < len(spos))
                todo, k = todo[full], k * 8  # every candidate was within reach: look at more of them
            matched = np.isfinite(err)
        if not matched.any():
            r.status = "skip"
            r.messages.append("no built vertex sits at a source vertex position (transformed source?)")
            return r.finish()
        worst = float(np.nanmax(err))
        frac = float(np.mean(err[matched] > tol))
        r.figures = {"vertices": int(used.sum()), "matched": int(matched.sum()), "maxUvError": worst,
                     "fractionOver": frac}
        if r.worst("maxUvError", worst, tol):
            r.messages.append(f"{frac:.1%} of the textured vertices have a uv0 up to {worst:.4g} away from the "
                              f"source's at the same position (> {tol:g}; flipped or shifted UVs?)")
        return r.finish()


CHECK = UvsCheck()
