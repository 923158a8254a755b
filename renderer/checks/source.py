"""``source``: LOD0 against an independent render of the source (trimesh import, same renderer)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

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


def load_source(ctx: Context) -> tuple[Path | None, Any, str | None]:
    """(source path, trimesh RenderModel or None, why not) for the context's model, memoised."""
    if "source" not in ctx.cache:
        from ..source_model import load_source_model  # noqa: PLC0415

        assert ctx.model is not None
        src = find_source(ctx.model_json, ctx.model.sidecar, ctx.options)
        if src is None:
            names = [s.get("path") for s in ctx.model.sidecar.get("sources", [])][:1]
            ctx.cache["source"] = (None, None, f"source {names} not found (set source_root)")
        else:
            try:
                with ctx.timer("load"):
                    ctx.cache["source"] = (src, load_source_model(src, decoded=ctx.cache), None)
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
                 "source_color_tolerance 0.08 (0..1 sRGB)")
    reason = ("the build only welds, reorders and re-encodes vertices: silhouettes agree up to float "
              "rounding (the worst XOR and unexplained fractions measured on the 38 corpus models and 8 "
              "generated kinds were 0 at 256 px), so 3% and 0.2% only absorb edge pixels. Colours: the build "
              "samples a mip chain where the source draws level 0; 8x8 block means hide that aliasing: the "
              "worst block-mean difference measured was 0.017 (AlphaBlendModeTest), while a swapped texture, "
              "a flipped V or a wrong format moved block means by 0.12 to 0.55 in the mutation runs")
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
        names = {str(a.get("name", "")).lower() for a in (model.sidecar.get("vertexLayout") or {}).get("attributes", [])}
        if not names & {"color0", "color", "color_0", "colour0"} and (source.colors != 1.0).any():
            source.colors[:] = 1.0  # the build's layout carries no colour (--layout): draw the source without
            caveats = caveats + ["the built vertex layout has no colour attribute: the source's vertex colours "
                                 "are not drawn"]
        gpu = None
        try:
            with ctx.timer("upload"):
                gpu = renderer.upload(source)
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
                    if colour_ok and r.worst("colorDiff", color, options.source_color_tolerance):
                        r.messages.append(f"view {k}: shaded colours differ from the source by {color:.3f} "
                                          f"(> {options.source_color_tolerance}; wrong texture or material?)")
                    r.figures["views"].append(view)
        finally:
            if gpu is not None:
                renderer.release(gpu)
        if not colour_ok:
            r.figures["colourCompared"] = False
        if caveats:
            r.figures["caveats"] = list(caveats)
        return r.finish()


CHECK = SourceCheck()
