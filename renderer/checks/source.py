"""``source``: LOD0 against an independent render of the source (trimesh import, same renderer)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.errors import AssetpipeError

from .. import compare
from ..results import CheckResult, ValidateOptions
from .base import Check, Context


def find_source(model_json: Path, side: dict[str, Any], options: ValidateOptions) -> Path | None:
    """The source file of a built model: as the build recorded it (OUT/.assetpipe/state.json),
    beside the build, or under ``source_root`` (searched)."""
    sources = side.get("sources") or []
    if not sources or not sources[0].get("path"):
        return None
    rel = Path(sources[0]["path"])
    digest = sources[0].get("digest")
    cands = [rel] if rel.is_absolute() else [Path(model_json).parent / rel]
    from assetpipe.core.state_file import source_of  # noqa: PLC0415 - the build's own record of its sources

    recorded = source_of(Path(model_json).parent, side.get("id", Path(model_json).stem))
    if recorded is not None:
        cands.insert(0, recorded)
    if options.source_root and not rel.is_absolute():
        root = Path(options.source_root)
        cands.append(root / rel)
        if root.is_dir():
            cands += sorted(root.rglob(rel.name))
    found = [c for c in cands if c.is_file()]
    if len(found) > 1 and digest:
        try:
            from assetpipe.core.hashing import digest_file  # noqa: PLC0415

            same = [c for c in found if digest_file(c) == digest]
            found = same or found
        except Exception:  # noqa: BLE001 - the digest is a tie-breaker only
            pass
    return found[0].resolve() if found else None


def start_source(ctx: Context, sidecar: dict[str, Any] | None = None) -> None:
    """Start reading the context's source model on a thread of its own, so that its parsing,
    image decoding and mip chains (OpenCV releases the GIL) overlap the build's upload and
    renders (AlphaBlendModeTest, four 2048^2 images, in-process, alternating: 1.64, 1.72, 1.52 s
    -> 1.48, 1.33, 1.58 s). :func:`load_source` waits for it; what it returns or raises is the
    same as reading it there. ``sidecar``: the built model's sidecar, read before the model
    (whose KTX2 files take a while at 4096^2) so that the thread starts first; default: the
    loaded model's."""
    if "source" in ctx.cache or "source_future" in ctx.cache:
        return
    if sidecar is None:
        if ctx.model is None:
            return
        sidecar = ctx.model.sidecar
    src = find_source(ctx.model_json, sidecar, ctx.options)
    if src is None:
        return  # load_source says why
    from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

    from ..loader import frame_origin  # noqa: PLC0415
    from ..source_model import load_source_model  # noqa: PLC0415

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="assetpipe-source")
    ctx.cache["source_future"] = (src, pool.submit(load_source_model, src, decoded=ctx.cache,
                                                   origin=frame_origin(sidecar)))
    pool.shutdown(wait=False)


def load_source(ctx: Context) -> tuple[Path | None, Any, str | None]:
    """(source path, trimesh RenderModel or None, why not) for the context's model, memoised."""
    if "source" not in ctx.cache:
        from ..source_model import load_source_model  # noqa: PLC0415

        assert ctx.model is not None
        started = ctx.cache.pop("source_future", None)
        src = started[0] if started else find_source(ctx.model_json, ctx.model.sidecar, ctx.options)
        if src is None:
            names = [s.get("path") for s in ctx.model.sidecar.get("sources", [])][:1]
            ctx.cache["source"] = (None, None, f"source {names} not found (set source_root)")
        else:
            try:
                with ctx.timer("load"):
                    model = started[1].result() if started else load_source_model(
                        src, decoded=ctx.cache, origin=ctx.model.position_offset)
                ctx.cache["source"] = (src, model, None)
            except AssetpipeError as exc:
                ctx.cache["source"] = (src, None, f"source not importable by trimesh: {exc}")
    return ctx.cache["source"]


class SourceCheck(Check):
    name = "source"
    measures = ("per view, LOD0 against the source imported by trimesh and drawn by the same renderer: "
                "silhouette XOR over union and pixels more than 1 px from the other silhouette (coverage, "
                "no culling), the same for the pixels whose nearest surface faces the eye or is double-sided "
                "(winding), and the mean "
                "absolute difference of 8x8-block mean colours where both cover")
    tolerance = ("source_max_xor 3% of the union; source_max_unexplained 0.2% of the union; "
                 "source_color_tolerance 2/255 (0..1 sRGB), 4/255 more when a drawn texture is block-compressed "
                 "(texture_compressed_png_tolerance - texture_png_tolerance, as roles)")
    reason = ("the build only welds, reorders and re-encodes vertices: silhouettes agree up to float "
              "rounding (the worst XOR and unexplained fractions measured on the 38 corpus models and 9 "
              "generated kinds were 0 at 256 px), so 3% and 0.2% only absorb edge pixels. Colours: both sides "
              "draw every texture role the same way, each with a mip chain (the reference's made by "
              "renderer/ref_mips.py) and the source's glTF sampler; what is left is mip rounding and blending: "
              "the worst mean block difference of the good models was 0.0022 (AlphaBlendModeTest) with RGBA8 "
              "textures, 2/255 leaves 3.5x; block-compressed builds add the encoder's error (worst 0.0092, "
              "Duck with ETC2; 0.0034 with BC), 6/255 leaves 2.5x. A wrong texture in any drawn role, a flipped "
              "V or a wrong format moved the mean by 0.009 to 0.77 in the mutation runs (a nearly flat map turned "
              "around, by less: the roles check compares every role's texels directly)")
    needs_render = True

    def run(self, ctx: Context) -> CheckResult:
        from ..source_model import source_caveats  # noqa: PLC0415

        r = self.result()
        model, options, renderer = ctx.model, ctx.options, ctx.renderer
        assert model is not None
        src, source, why = load_source(ctx)
        if source is None:
            r.status = "skip"
            r.messages.append(str(why))
            return r.finish()
        ctx.notes += [f"source: {n}" for n in source.notes]
        geometry_ok, colour_ok, caveats = source_caveats(src, model, source)
        ctx.notes += [f"source check: {c}" for c in caveats]
        r.figures = {"source": str(src), "views": []}
        if not geometry_ok:
            r.status = "skip"
            r.messages += caveats
            return r.finish()
        culled = True
        if src.suffix.lower() not in (".gltf", ".glb"):
            # OBJ has no double-sidedness: the source is drawn as the build's materials say when they
            # all agree; with mixed materials the winding is not compared
            sides = {m.double_sided for m in model.materials}
            if len(sides) == 1:
                for m in source.materials:
                    m.double_sided = next(iter(sides))
            else:
                culled = False
                caveats = caveats + ["the OBJ build mixes single- and double-sided materials: winding not compared"]
        if src.suffix.lower() not in (".gltf", ".glb"):
            _build_samplers(model, source)
        names = {str(a.get("name", "")).lower() for a in (model.sidecar.get("vertexLayout") or {}).get("attributes", [])}
        if not names & {"color0", "color", "color_0", "colour0"} and (source.colors != 1.0).any():
            source.colors[:] = 1.0  # the build's layout carries no colour (--layout): draw the source without
            caveats = caveats + ["the built vertex layout has no colour attribute: the source's vertex colours "
                                 "are not drawn"]
        attrs = {"normal": "normal_texture", "metallicRoughness": "metallic_roughness_texture",
                 "occlusion": "occlusion_texture", "emissive": "emissive_texture"}
        if model.uvs1 is None:  # the build carries no second UV set: its roles there are not drawn on
            gone = set()         # either side (the loader's notes say so, per material)
            for m in source.materials:
                for role, slot in zip(attrs, m.role_uv):
                    if slot == 1 and getattr(m, attrs[role]) is not None:
                        setattr(m, attrs[role], None)
                        gone.add(role)
            if gone:
                caveats = caveats + [f"{sorted(gone)} on TEXCOORD_1 drawn on neither side: the build's vertex layout "
                                     "has no uv1 (build with --layout ...,uv1 to carry it)"]
        undrawn = [r for r in source.sidecar.get("undrawnRoles", []) if r in attrs and any(
            getattr(m, attrs[r]) is not None for m in model.materials)]
        if undrawn and colour_ok:  # the build draws a role the reference cannot (another UV set elsewhere)
            colour_ok = False
            caveats = caveats + [f"the build draws {undrawn} textures the source reference cannot draw (trimesh "
                                 "reads TEXCOORD_0 only): colours not compared"]
        color_tol = options.source_color_tolerance
        drawn = [t for m in model.materials for t in (m.texture, m.normal_texture, m.metallic_roughness_texture,
                                                      m.occlusion_texture, m.emissive_texture) if t is not None]
        if any(t.size is not None for t in drawn):  # a block format: the encoders' error, as roles allows
            color_tol += options.texture_compressed_png_tolerance - options.texture_png_tolerance
        r.figures["colorTolerance"] = round(color_tol, 5)
        gpu = None
        try:
            with ctx.timer("upload"):
                gpu = renderer.upload(source, ctx.cams)  # drawn shaded by these views only
            for k, (cam, sil, a, img) in enumerate(zip(ctx.cams, ctx.coverage, ctx.front, ctx.shaded)):
                with ctx.timer("render"):  # drawn as the build was (one pass when both are all OPAQUE)
                    if renderer.one_pass(gpu) == renderer.one_pass(ctx.gpu):
                        simg, facing = renderer.render_pair(gpu, cam)
                    else:
                        simg, facing = renderer.render(gpu, cam), renderer.render(gpu, cam, mode="facing")
                    ssil, b = compare.coverage(facing), compare.front(facing)
                with ctx.timer("compare"):
                    union = max(int((sil | ssil).sum()), 1)
                    xor = compare.xor_fraction(sil, ssil)
                    unexp = float(compare.unexplained(sil, ssil, 1).sum()) / union
                    color, blocks = compare.block_color_difference(img, simg)
                    view = {"xor": round(xor, 5), "unexplained": round(unexp, 5), "colorDiff": round(color, 4),
                            "colorBlocks": blocks}
                    per_block = compare.block_color_differences(img, simg)
                    if per_block.size:  # the spread, for reports (not compared)
                        view["blockDiffP99"] = round(float(np.quantile(per_block, 0.99)), 4)
                        view["blockDiffMax"] = round(float(per_block.max()), 4)
                    if r.worst("xor", xor, options.source_max_xor):
                        r.messages.append(f"view {k}: {xor:.2%} of the silhouette differs from the source "
                                          f"(> {options.source_max_xor:.2%})")
                    if r.worst("unexplained", unexp, options.source_max_unexplained):
                        r.messages.append(f"view {k}: {unexp:.2%} of the silhouette is more than 1 px from the "
                                          f"source's (> {options.source_max_unexplained:.2%})")
                    if culled:
                        cu = float(compare.unexplained(a, b, 1).sum()) / union
                        view["frontUnexplained"] = round(cu, 5)
                        if r.worst("frontUnexplained", cu, options.source_max_unexplained):
                            r.messages.append(f"view {k}: front faces cover {cu:.2%} of the silhouette more than 1 px "
                                              f"away from the source's (> {options.source_max_unexplained:.2%}; "
                                              "flipped winding?)")
                    if colour_ok and r.worst("colorDiff", color, color_tol):
                        r.messages.append(f"view {k}: shaded colours differ from the source by {color:.4f} "
                                          f"(> {color_tol:.4f}; wrong texture or material?)")
                    r.figures["views"].append(view)
        finally:
            if gpu is not None:
                renderer.release(gpu)
        if not colour_ok:
            r.figures["colourCompared"] = False
        if caveats:
            r.figures["caveats"] = list(caveats)
        return r.finish()


ROLE_ATTRS = ("texture", "normal_texture", "metallic_roughness_texture", "occlusion_texture", "emissive_texture")


def _build_samplers(model: Any, source: Any) -> None:
    """A source format without samplers (OBJ): the reference samples each role as the build does
    when the build uses one sampler for that role throughout (the filters are then the importer's
    choice, which the source does not state, not something to validate)."""
    import dataclasses  # noqa: PLC0415

    for attr in ROLE_ATTRS:
        used = {repr(sorted(t.sampler.items())): t.sampler for m in model.materials
                if (t := getattr(m, attr)) is not None}
        if len(used) != 1:
            continue
        sampler = next(iter(used.values()))
        for m in source.materials:
            t = getattr(m, attr)
            if t is not None:
                setattr(m, attr, dataclasses.replace(t, sampler=dict(sampler)))


CHECK = SourceCheck()
