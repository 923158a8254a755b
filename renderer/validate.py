"""Validate built models by rendering them headless (lavapipe) and checking the pictures.

Checks (each a :class:`CheckResult` with figures):

``load``
    The built files read back: sizes, offsets, index ranges, material ids (see
    :mod:`renderer.loader`). A failure here skips the render checks.
``vulkan``
    No message from the Khronos validation layer (with synchronization validation) while
    this model was uploaded and drawn. Any message fails.
``silhouette``
    From each view: the render (coverage of every triangle, no culling) is not empty, and its
    silhouette's bounding box equals the CPU
    projection of the drawn vertices within ``bbox_tolerance_px`` and lies inside the
    projection of the sidecar ``bounds`` (same tolerance).
``source``
    LOD0 against an independent render of the *source* (trimesh import, flattened, same
    renderer), both drawn as coverage (no culling: OBJ has no double-sidedness): the fraction of differing silhouette pixels (XOR over union) must be at most
    ``source_max_xor``; pixels not explained by a 1-px edge shift must be at most
    ``source_max_unexplained`` of the union. Shaded colours are compared as 8x8-block means
    where both cover (mean absolute difference at most ``source_color_tolerance``): this catches
    a swapped texture or material. Skipped (with a note) when the source file is not found.
``lods``
    Each LOD k >= 1 at its ``switchDistance`` against LOD0 at the same distance, rendered at
    the pixel scale of the LOD reference view (``lod_reference_px`` vertical pixels,
    ``lod_reference_fov_deg``), drawn with the materials' culling so holes show: pixels that differ and are not within 1 px of the other
    silhouette must number at most ``lod_max_unexplained_px + lod_max_unexplained_fraction x
    area`` (the 1-pixel budget: differences only along edges).
``textures``
    Every material texture (all roles): the KTX2 exists and reads, its vkFormat is the
    sidecar's and fits the role (SRGB for colour roles), it holds the full mip chain with the
    expected dimensions, no level is all black (unless level 0 is), float data has no NaN,
    each level's mean colour stays within ``texture_mean_tolerance`` of level 0's, and level 0
    equals the ``path`` PNG/JPEG (mean difference at most 2/255), whose name must match the
    seed's ``texturePath``. Block-compressed KTX2s (BC, ETC2/EAC) are decoded on the CPU
    (texture2ddecoder) and checked the same way; their level 0 is compared with the PNG/JPEG
    over the channels the format stores, within ``texture_compressed_png_tolerance``.

:func:`validate_model` and :func:`validate_batch` run the checks in a renderer subprocess
(see :mod:`renderer.worker`) unless ``isolate=False``.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.errors import AssetpipeError

from . import compare
from .camera import DEFAULT_VIEW, Camera, box_corners, fit_camera, project_points
from .loader import (RenderModel, load_built_model, material_list_path, read_ktx2, sidecar_path)

CHECKS = ("load", "vulkan", "silhouette", "source", "lods", "textures")
DEFAULT_VIEWS: tuple[tuple[float, float, float], ...] = (DEFAULT_VIEW, (0.8, -0.3, 0.7), (0.2, -1.0, 0.3))
SRGB_ROLES = {"baseColor", "emissive"}


@dataclass
class ValidateOptions:
    """Options of the checks; every figure the checks compare against is here."""

    width: int = 256
    height: int = 256
    views: tuple[tuple[float, float, float], ...] = DEFAULT_VIEWS
    checks: tuple[str, ...] = CHECKS
    validation_layer: bool = True
    bbox_tolerance_px: float = 2.0
    source_root: str | None = None  # where to look for the sources (searched recursively)
    source_max_xor: float = 0.03
    source_max_unexplained: float = 0.002
    source_color_tolerance: float = 0.08
    lod_reference_px: int = 1080
    lod_reference_fov_deg: float = 60.0
    lod_max_render_px: int = 512
    lod_max_unexplained_px: int = 4
    lod_max_unexplained_fraction: float = 0.002
    texture_mean_tolerance: float = 0.12
    texture_png_tolerance: float = 2.0 / 255.0
    # compressed level 0 vs the PNG: 2/255 as above plus 4/255, the RMS error of the 36 dB PSNR
    # goal of the block encoders (a mean absolute error is at most the RMS error)
    texture_compressed_png_tolerance: float = 6.0 / 255.0
    timeout_s: float = 120.0
    shader_cache: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ValidateOptions":
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in data.items() if k in names}
        if "views" in kw:
            kw["views"] = tuple(tuple(float(c) for c in v) for v in kw["views"])
        if "checks" in kw:
            kw["checks"] = tuple(kw["checks"])
        return cls(**kw)


@dataclass
class CheckResult:
    """One check: ``status`` is "pass", "fail" or "skip"; ``figures`` are its measurements."""

    name: str
    status: str
    figures: dict[str, Any] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def passed(self) -> bool:
        return self.status != "fail"


@dataclass
class ValidationResult:
    """All checks of one model, the notes, and the time split (setup/load/upload/render/compare)."""

    model: str
    id: str
    checks: list[CheckResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    error: str | None = None  # set when the asset could not be validated at all (crash, timeout)

    @property
    def passed(self) -> bool:
        return self.error is None and all(c.passed for c in self.checks)

    def check(self, name: str) -> CheckResult | None:
        return next((c for c in self.checks if c.name == name), None)

    def failures(self) -> list[str]:
        """One line per failed check (or the error)."""
        out = [f"{self.model}: {self.error}"] if self.error else []
        out += [f"{self.model}: {c.name}: {'; '.join(c.messages) or 'failed'}" for c in self.checks if not c.passed]
        return out

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["passed"] = self.passed
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ValidationResult":
        checks = [CheckResult(**{k: v for k, v in c.items() if k != "passed"}) for c in d.get("checks", [])]
        return cls(model=d["model"], id=d.get("id", ""), checks=checks, notes=list(d.get("notes", [])),
                   timings=dict(d.get("timings", {})), error=d.get("error"))


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


# ------------------------------------------------------------------------------ textures
def check_textures(model_json: Path, options: ValidateOptions) -> CheckResult:
    """Check (e): every material texture at every mip level (CPU only, no rendering)."""
    t0 = time.perf_counter()
    root = Path(model_json).parent
    msgs: list[str] = []
    figures: dict[str, Any] = {}
    try:
        side = json.loads(sidecar_path(model_json).read_text())
        seed_mats = {m.get("id"): m for m in json.loads(material_list_path(model_json).read_text())}
    except (OSError, ValueError) as exc:
        return CheckResult("textures", "fail", messages=[f"cannot read the material files: {exc}"])
    count = 0
    seen: dict[str, tuple[dict[str, Any], list[str]]] = {}
    for mat in side.get("materials", []):
        mid = mat.get("id")
        for role, tex in (mat.get("textures") or {}).items():
            count += 1
            key = f"{mid}/{role}"
            fig: dict[str, Any] = {}
            figures[key] = fig
            seed_path = (seed_mats.get(mid) or {}).get("texturePath", "")
            if role == "baseColor" and seed_path != tex.get("path"):
                msgs.append(f"{key}: seed texturePath {seed_path!r} differs from the sidecar's {tex.get('path')!r}")
            ktx_rel = tex.get("ktx2")
            if not ktx_rel:
                msgs.append(f"{key}: no KTX2 (mip chain missing)")
                continue
            if ktx_rel in seen:  # a texture shared by several materials is checked once
                fig.update(seen[ktx_rel][0])
                msgs += [f"{key}: {m.split(': ', 1)[1]}" for m in seen[ktx_rel][1]]
                continue
            tex_msgs = _check_one_texture(root, key, role, tex, fig, options)
            seen[ktx_rel] = (dict(fig), tex_msgs)
            msgs += tex_msgs
    figures["textures"] = count
    return CheckResult("textures", "fail" if msgs else "pass", _jsonable(figures), msgs,
                       time.perf_counter() - t0)


_SRGB_TO_LINEAR = np.where(np.arange(256) / 255.0 <= 0.04045, np.arange(256) / 255.0 / 12.92,
                           ((np.arange(256) / 255.0 + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _check_one_texture(root: Path, key: str, role: str, tex: dict[str, Any], fig: dict[str, Any],
                       options: ValidateOptions) -> list[str]:
    """The checks of one KTX2 (see :func:`check_textures`); fills ``fig``, returns the problems."""
    from PIL import Image  # noqa: PLC0415

    msgs: list[str] = []
    ktx_rel = tex["ktx2"]
    try:
        img = read_ktx2((root / ktx_rel).read_bytes())
    except OSError as exc:
        return [f"{key}: KTX2 {ktx_rel} missing ({exc.strerror})"]
    except Exception as exc:  # noqa: BLE001
        return [f"{key}: KTX2 {ktx_rel} unreadable: {exc}"]
    w, h, levels = int(img.width), int(img.height), list(img.levels)
    fmt = int(img.vk_format)
    block = getattr(img, "block_format", None)
    if block is not None:
        from assetpipe.core.ktx2 import decode_level, stored_channels  # noqa: PLC0415

        levels = [decode_level(lv, fmt, max(w >> i, 1), max(h >> i, 1)) for i, lv in enumerate(levels)]
        fig["blockFormat"] = block.name
    full = int(math.floor(math.log2(max(w, h, 1)))) + 1
    fig.update(width=w, height=h, levels=len(levels), fullChain=full, vkFormat=fmt)
    if fmt != int(tex.get("vkFormat", fmt)):
        msgs.append(f"{key}: vkFormat {fmt} but the sidecar says {tex.get('vkFormat')}")
    expect_fmt = 43 if role in SRGB_ROLES else 37
    if block is not None and block.srgb != (role in SRGB_ROLES):
        msgs.append(f"{key}: vkFormat {fmt} ({block.name}) for a {'colour' if role in SRGB_ROLES else 'data'} role "
                    f"(expected {'an sRGB' if role in SRGB_ROLES else 'a UNORM'} format)")
    if fmt in (37, 43) and fmt != expect_fmt:
        msgs.append(f"{key}: vkFormat {fmt} for a {'colour' if role in SRGB_ROLES else 'data'} role "
                    f"(expected {expect_fmt})")
    if (w, h) != (int(tex.get("width", w)), int(tex.get("height", h))):
        msgs.append(f"{key}: {w}x{h} but the sidecar says {tex.get('width')}x{tex.get('height')}")
    if len(levels) != int(tex.get("levels", len(levels))):
        msgs.append(f"{key}: {len(levels)} levels but the sidecar says {tex.get('levels')}")
    if len(levels) < full:
        msgs.append(f"{key}: {len(levels)} of {full} mip levels (missing levels)")
    means = []
    lv0_rgb_any = bool(np.asarray(levels[0])[..., :3].any()) if levels else False
    for i, lv in enumerate(levels):
        arr = np.asarray(lv)
        expect = (max(h >> i, 1), max(w >> i, 1))
        if arr.shape[:2] != expect:
            msgs.append(f"{key}: level {i} is {arr.shape[1]}x{arr.shape[0]}, expected {expect[1]}x{expect[0]}")
            continue
        if arr.dtype.kind == "f":
            if not np.isfinite(arr).all():
                msgs.append(f"{key}: level {i} holds NaN/Inf")
                continue
            rgb, alpha = arr[..., :3].astype(np.float32), arr[..., 3].astype(np.float32)
        else:
            rgb = _SRGB_TO_LINEAR[arr[..., :3]] if img.srgb else arr[..., :3].astype(np.float32) / 255.0
            alpha = arr[..., 3].astype(np.float32) / 255.0
        if i > 0 and lv0_rgb_any and not arr[..., :3].any():
            msgs.append(f"{key}: level {i} is all black")
        # premultiplied linear means: what a gamma-correct, alpha-aware box filter preserves
        means.append((rgb * alpha[..., None]).reshape(-1, 3).mean(axis=0))
    if means:
        drift = [float(np.abs(m - means[0]).max()) for m in means]
        fig["maxMeanDrift"] = round(max(drift), 4)
        bad = [i for i, d in enumerate(drift) if d > options.texture_mean_tolerance]
        if bad:
            msgs.append(f"{key}: levels {bad} drift from level 0's mean colour by up to {max(drift):.3f} "
                        f"(> {options.texture_mean_tolerance})")
    png_rel = tex.get("path")
    if png_rel and levels:
        try:
            with Image.open(root / png_rel) as im:
                ref = np.asarray(im.convert("RGBA"))
        except Exception as exc:  # noqa: BLE001
            return msgs + [f"{key}: level-0 image {png_rel} unreadable: {exc}"]
        lv0 = np.asarray(levels[0])
        if ref.shape != lv0.shape:
            msgs.append(f"{key}: {png_rel} is {ref.shape[1]}x{ref.shape[0]}, the KTX2 level 0 "
                        f"{lv0.shape[1]}x{lv0.shape[0]} (swapped texture?)")
        elif lv0.dtype == np.uint8:
            n, tol = 4, options.texture_png_tolerance
            if block is not None:
                n, tol = len(stored_channels(fmt)), options.texture_compressed_png_tolerance
            d = float(np.abs(ref[..., :n].astype(np.int16) - lv0[..., :n].astype(np.int16)).mean()) / 255.0
            fig["level0VsImage"] = round(d, 5)
            if d > tol:
                msgs.append(f"{key}: KTX2 level 0 differs from {png_rel} (mean {d:.4f}; swapped texture?)")
    return msgs


# ------------------------------------------------------------------------------- sources
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


# ------------------------------------------------------------------------- the validator
class _Timer:
    def __init__(self, timings: dict[str, float], key: str) -> None:
        self.timings, self.key = timings, key

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        self.timings[self.key] = self.timings.get(self.key, 0.0) + time.perf_counter() - self.t0


def _drawn_positions(model: RenderModel, lod: int = 0) -> np.ndarray:
    """Positions referenced by the model's LOD ``lod`` draws."""
    parts = []
    for m in model.meshes:
        if not m.lods:
            continue
        level = m.lods[min(lod, len(m.lods) - 1)]
        idx = model.indices[level.first_index:level.first_index + level.index_count]
        parts.append(np.unique(idx).astype(np.int64) + m.vertex_base)
    if not parts:
        return np.zeros((0, 3), np.float32)
    return model.positions[np.unique(np.concatenate(parts))]


def _cameras(model: RenderModel, options: ValidateOptions) -> list[Camera]:
    return [fit_camera(model.center, model.radius, v, options.width, options.height) for v in options.views]


def run_checks(model_json: Path, options: ValidateOptions, renderer: Any) -> ValidationResult:
    """Run the selected checks of one model on ``renderer`` (in this process)."""
    model_json = Path(model_json)
    result = ValidationResult(model=str(model_json), id=model_json.name[: -len(".json")])
    timings = result.timings
    ctx = renderer.ctx
    ctx.take_messages()
    selected = set(options.checks)

    if "textures" in selected:
        with _Timer(timings, "compare"):
            result.checks.append(check_textures(model_json, options))

    t0 = time.perf_counter()
    try:
        with _Timer(timings, "load"):
            model = load_built_model(model_json)
    except AssetpipeError as exc:
        result.checks.insert(0, CheckResult("load", "fail", messages=[str(exc)], seconds=time.perf_counter() - t0))
        return result
    result.id = model.id
    result.notes += model.notes
    result.checks.insert(0, CheckResult("load", "pass", {
        "meshes": len(model.meshes), "materials": len(model.materials), "vertices": int(len(model.positions)),
        "triangles": model.triangles(0), "lods": model.lod_count}, seconds=time.perf_counter() - t0))

    if model.triangles(0) == 0:
        for name in ("silhouette", "source", "lods"):
            if name in selected:
                result.checks.append(CheckResult(name, "skip", messages=["the model has no triangles to draw"]))
        selected -= {"silhouette", "source", "lods"}
    gpu = None
    try:
        with _Timer(timings, "upload"):
            gpu = renderer.upload(model)
        result.notes += [n for n in model.notes if n not in result.notes]  # e.g. a format decoded on the CPU
        cams = _cameras(model, options)
        sils: list[np.ndarray] = []
        shaded: list[np.ndarray] = []
        with _Timer(timings, "render"):
            for cam in cams:
                sils.append(compare.coverage(renderer.render(gpu, cam, mode="coverage")))
                if "source" in selected:
                    shaded.append(renderer.render(gpu, cam))
        if "silhouette" in selected:
            with _Timer(timings, "compare"):
                result.checks.append(_check_silhouette(model, cams, sils, options))
        if "source" in selected:
            result.checks.append(_check_source(model_json, model, cams, sils, shaded, options, renderer, timings,
                                               result.notes))
        if "lods" in selected:
            result.checks.append(_check_lods(model, gpu, options, renderer, timings))
    finally:
        if gpu is not None:
            renderer.release(gpu)
    if "vulkan" in selected:
        msgs = ctx.take_messages()
        if not ctx.validation:
            result.checks.append(CheckResult("vulkan", "skip", messages=["validation layer disabled"]))
        else:
            result.checks.append(CheckResult("vulkan", "fail" if msgs else "pass", {"messages": len(msgs)},
                                             [f"{sev}: {text}" for sev, text in msgs[:20]]))
    order = {n: i for i, n in enumerate(CHECKS)}
    result.checks.sort(key=lambda c: order.get(c.name, 99))
    for c in result.checks:
        c.figures = _jsonable(c.figures)
    return result


def _check_silhouette(model: RenderModel, cams: list[Camera], sils: list[np.ndarray],
                      options: ValidateOptions) -> CheckResult:
    """Check (b): non-empty render whose box matches the CPU projection."""
    msgs: list[str] = []
    figs: dict[str, Any] = {"views": []}
    pts = _drawn_positions(model)
    tol = options.bbox_tolerance_px
    for k, (cam, sil) in enumerate(zip(cams, sils)):
        box = compare.bbox(sil)
        fig: dict[str, Any] = {"coverage": round(float(sil.mean()), 5)}
        figs["views"].append(fig)
        if box is None:
            msgs.append(f"view {k}: the render is empty")
            continue
        fig["renderBox"] = list(box)
        if len(pts):
            px, front = project_points(cam, pts)
            cpu = (px[:, 0].min(), px[:, 1].min(), px[:, 0].max(), px[:, 1].max())
            fig["cpuBox"] = [round(float(v), 2) for v in cpu]
            err = max(abs(a - b) for a, b in zip(box, cpu))
            fig["maxBoxErrorPx"] = round(float(err), 3)
            if err > tol:
                msgs.append(f"view {k}: silhouette box {box} differs from the CPU projection "
                            f"{tuple(round(float(v), 1) for v in cpu)} by {err:.1f} px (> {tol})")
        bpx, _ = project_points(cam, box_corners(model.bounds_min, model.bounds_max))
        bb = (bpx[:, 0].min() - tol, bpx[:, 1].min() - tol, bpx[:, 0].max() + tol, bpx[:, 1].max() + tol)
        if box[0] < bb[0] or box[1] < bb[1] or box[2] > bb[2] or box[3] > bb[3]:
            msgs.append(f"view {k}: silhouette box {box} exceeds the projected sidecar bounds "
                        f"{tuple(round(float(v), 1) for v in bb)}")
    return CheckResult("silhouette", "fail" if msgs else "pass", figs, msgs)


def _check_source(model_json: Path, model: RenderModel, cams: list[Camera], sils: list[np.ndarray],
                  shaded: list[np.ndarray], options: ValidateOptions, renderer: Any,
                  timings: dict[str, float], notes: list[str]) -> CheckResult:
    """Check (c): LOD0 against an independent trimesh import of the source."""
    from .source_model import load_source_model  # noqa: PLC0415

    t0 = time.perf_counter()
    src = find_source(model_json, model.sidecar, options)
    if src is None:
        names = [s.get("path") for s in model.sidecar.get("sources", [])][:1]
        return CheckResult("source", "skip", messages=[f"source {names} not found (set source_root)"])
    try:
        with _Timer(timings, "load"):
            source = load_source_model(src)
    except AssetpipeError as exc:
        return CheckResult("source", "skip", {"source": str(src)}, [f"source not importable by trimesh: {exc}"])
    notes += [f"source: {n}" for n in source.notes]
    from .source_model import source_caveats  # noqa: PLC0415

    geometry_ok, colour_ok, caveats = source_caveats(src, model, source)
    notes += [f"source check: {c}" for c in caveats]
    if not geometry_ok:
        return CheckResult("source", "skip", {"source": str(src)}, caveats)
    gpu = None
    msgs: list[str] = []
    figs: dict[str, Any] = {"source": str(src), "views": []}
    try:
        with _Timer(timings, "upload"):
            gpu = renderer.upload(source)
        for k, (cam, sil, img) in enumerate(zip(cams, sils, shaded)):
            with _Timer(timings, "render"):
                ssil = compare.coverage(renderer.render(gpu, cam, mode="coverage"))
                simg = renderer.render(gpu, cam)
            with _Timer(timings, "compare"):
                union = max(int((sil | ssil).sum()), 1)
                xor = compare.xor_fraction(sil, ssil)
                unexp = float(compare.unexplained(sil, ssil, 1).sum()) / union
                color, blocks = compare.block_color_difference(img, simg)
                figs["views"].append({"xor": round(xor, 5), "unexplained": round(unexp, 5),
                                      "colorDiff": round(color, 4), "colorBlocks": blocks})
                if xor > options.source_max_xor:
                    msgs.append(f"view {k}: {xor:.2%} of the silhouette differs from the source "
                                f"(> {options.source_max_xor:.2%})")
                if unexp > options.source_max_unexplained:
                    msgs.append(f"view {k}: {unexp:.2%} of the silhouette is more than 1 px from the source's "
                                f"(> {options.source_max_unexplained:.2%})")
                if colour_ok and color > options.source_color_tolerance:
                    msgs.append(f"view {k}: shaded colours differ from the source by {color:.3f} "
                                f"(> {options.source_color_tolerance}; wrong texture or material?)")
    finally:
        if gpu is not None:
            renderer.release(gpu)
    if not colour_ok:
        figs["colourCompared"] = False
    return CheckResult("source", "fail" if msgs else "pass", figs, msgs + ([] if msgs else caveats),
                       time.perf_counter() - t0)


def _check_lods(model: RenderModel, gpu: Any, options: ValidateOptions, renderer: Any,
                timings: dict[str, float]) -> CheckResult:
    """Check (d): each LOD at its switch distance against LOD0, at the reference pixel scale."""
    t0 = time.perf_counter()
    levels = model.lod_count
    if levels <= 1:
        return CheckResult("lods", "pass", {"levels": levels}, ["single LOD: nothing to compare"])
    ppu = (options.lod_reference_px / 2) / math.tan(math.radians(options.lod_reference_fov_deg) / 2)
    msgs: list[str] = []
    figs: dict[str, Any] = {"levels": levels, "perLevel": []}
    view = options.views[0]
    for k in range(1, levels):
        dists = [m.lods[min(k, len(m.lods) - 1)].switch_distance for m in model.meshes if m.lods]
        switch = max(dists) if dists else 0.0
        distance = max(switch, 1.2 * model.radius, 1e-6)  # never closer than the switch distance
        radius_px = model.radius * ppu / distance
        size = int(min(max(2 * radius_px * 1.1 + 4, 32), options.lod_max_render_px))
        fov = math.degrees(2 * math.atan((size / 2) / ppu))
        cam = fit_camera(model.center, model.radius, view, size, size, fov_y_deg=fov, distance=distance)
        with _Timer(timings, "render"):
            a = compare.coverage(renderer.render(gpu, cam, mode="silhouette", lod=0))
            b = compare.coverage(renderer.render(gpu, cam, mode="silhouette", lod=k))
        with _Timer(timings, "compare"):
            bad = int(compare.unexplained(a, b, 1).sum())
            area = int(a.sum())
            budget = options.lod_max_unexplained_px + options.lod_max_unexplained_fraction * area
            figs["perLevel"].append({"level": k, "switchDistance": switch, "renderDistance": round(distance, 6),
                                     "renderPx": size, "triangles": model.triangles(k), "areaPx": area,
                                     "differingPx": int((a ^ b).sum()), "unexplainedPx": bad,
                                     "budgetPx": round(budget, 1)})
            if area == 0:
                msgs.append(f"LOD{k}: LOD0 covers no pixel at {distance:.4g}")
            elif bad > budget:
                msgs.append(f"LOD{k}: {bad} pixels differ from LOD0 by more than 1 px at its switch distance "
                            f"{switch:.4g} (budget {budget:.0f})")
    return CheckResult("lods", "fail" if msgs else "pass", figs, msgs, time.perf_counter() - t0)
