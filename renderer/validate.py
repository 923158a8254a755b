"""Validate built models by rendering them headless (lavapipe) and checking the pictures.

The checks live one per module in :mod:`renderer.checks` (each states what it measures, its
tolerance and why); :func:`run_checks` is the runner: it loads the model, uploads it once,
renders the views every render check shares, and iterates over the registry. Files-only
checks (``textures``, ``roles``'s source reading) run even when rendering is impossible.

:func:`renderer.batch.validate_model` and :func:`renderer.batch.validate_batch` run this in a
renderer subprocess (see :mod:`renderer.worker`) unless ``isolate=False``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from assetpipe.core.errors import AssetpipeError

from . import compare
from .camera import fit_camera
from .checks import NAMES, REGISTRY, Context
from .checks.ktx2_levels import Ktx2Levels, ktx2_cache_key
from .checks.source import find_source, start_source
from .checks.textures import SRGB_ROLES
from .loader import load_built_model, read_sidecar
from .results import DEFAULT_VIEWS, CheckResult, ValidateOptions, ValidationResult

CHECKS = NAMES

__all__ = ["CHECKS", "DEFAULT_VIEWS", "SRGB_ROLES", "CheckResult", "ValidateOptions", "ValidationResult",
           "find_source", "run_checks"]


#: the checks that read the source model (:func:`renderer.checks.source.load_source`)
SOURCE_READERS = frozenset({"source", "uvs"})


def _selected(options: ValidateOptions) -> set[str]:
    return set(options.checks) if options.checks else set(NAMES)


def _run_one(check: Any, ctx: Context, drawable: bool, load_seconds: float) -> CheckResult:
    """One check's result (a skip when what it needs is missing), with its seconds."""
    c0 = time.perf_counter()
    if check.name != "load" and check.name != "textures" and ctx.model is None:
        res = CheckResult(check.name, "skip", messages=["the built files did not load"])
    elif check.needs_render and not drawable:
        res = CheckResult(check.name, "skip", messages=["the model has no triangles to draw"])
    else:
        res = check.run(ctx)
    res.seconds = time.perf_counter() - c0 + (load_seconds if check.name == "load" else 0.0)
    return res


def run_checks(model_json: Path, options: ValidateOptions, renderer: Any) -> ValidationResult:
    """Run the selected checks of one model on ``renderer`` (in this process)."""
    model_json = Path(model_json)
    result = ValidationResult(model=str(model_json), id=model_json.name[: -len(".json")])
    ctx = Context(model_json=model_json, options=options, renderer=renderer, timings=result.timings,
                  notes=result.notes)
    renderer.ctx.take_messages()
    selected = _selected(options)
    t0 = time.perf_counter()
    if selected & SOURCE_READERS:
        # the source model is read on its own thread from here, while the build's files are
        # read, uploaded and drawn (its sidecar names the source)
        side = read_sidecar(model_json)
        if side is not None:  # else the load check reports what is wrong with it
            start_source(ctx, side)
    try:
        parsed: dict[Path, Any] = {}
        with ctx.timer("load"):
            ctx.model = load_built_model(model_json, parsed=parsed)
        for path, image in parsed.items():  # the texture checks read these KTX2 files too
            ctx.cache[ktx2_cache_key(path)] = Ktx2Levels(name=str(path), image=image)
        result.id = ctx.model.id
        result.notes += ctx.model.notes
    except AssetpipeError as exc:
        ctx.load_error = str(exc)
    load_seconds = time.perf_counter() - t0
    drawable = ctx.model is not None and ctx.model.triangles(0) > 0
    wants_render = any(c.needs_render and c.name in selected for c in REGISTRY)
    results: dict[str, CheckResult] = {}
    try:
        if drawable and wants_render:
            ctx.cams = [fit_camera(ctx.model.center, ctx.model.radius, v, options.width, options.height)
                        for v in options.views]
            with ctx.timer("upload"):  # textures from the first level these views can sample
                ctx.gpu = renderer.upload(ctx.model, ctx.cams)
            result.notes += [n for n in ctx.model.notes if n not in result.notes]  # e.g. a format decoded on the CPU
            with ctx.timer("render"):
                for cam in ctx.cams:
                    if "source" in selected:  # one pass for both when every material is OPAQUE
                        shaded, facing = renderer.render_pair(ctx.gpu, cam)
                        ctx.shaded.append(shaded)
                    else:
                        facing = renderer.render(ctx.gpu, cam, mode="facing")
                    ctx.coverage.append(compare.coverage(facing))
                    ctx.front.append(compare.front(facing))
        # the checks that read the source model last: it is read on its own thread meanwhile;
        # those that read files only (Check.beside) run on threads beside the others (the report
        # lists the checks in REGISTRY order whatever order they ran in)
        beside: dict[str, Any] = {}
        pool = None
        try:
            for check in sorted(REGISTRY, key=lambda c: c.name in SOURCE_READERS):
                if check.name not in selected or check.name == "vulkan":
                    continue
                if check.beside and ctx.model is not None:
                    if pool is None:
                        from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

                        pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="assetpipe-check")
                    beside[check.name] = pool.submit(_run_one, check, ctx, drawable, load_seconds)
                else:
                    results[check.name] = _run_one(check, ctx, drawable, load_seconds)
            with ctx.timer("compare"):
                for name, fut in beside.items():
                    results[name] = fut.result()
        finally:
            if pool is not None:
                pool.shutdown(wait=True)
    finally:
        if ctx.gpu is not None:
            renderer.release(ctx.gpu)
    if "vulkan" in selected:  # last: it collects the layer's messages of everything above
        from .checks import BY_NAME  # noqa: PLC0415

        results["vulkan"] = BY_NAME["vulkan"].run(ctx)
    result.checks = [results[n] for n in NAMES if n in results]
    return result
