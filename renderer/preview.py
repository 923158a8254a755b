"""Contact sheets of built models: several views, the LODs side by side, every texture's mips.

``make_preview(model_json, out_png)`` renders with the process's shared renderer (lavapipe)
and writes one PNG:

* a title line: model id, meshes, triangles, materials, loader notes;
* "Views": the model from four angles, shaded (factor x texture x vertex colour, MASK
  discarded, BLEND blended) over a neutral background;
* "LODs": each level from the same camera, labelled with its triangle count, the largest
  relative Hausdorff error of its meshes and its switch distance;
* "Textures": per material and role, the mip levels left to right at their relative sizes
  (tiny levels enlarged with nearest filtering), labelled with size and level count.

``python -m renderer.preview OUT/ID.json preview.png`` does the same from the shell.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .camera import fit_camera
from .loader import load_built_model, read_ktx2

VIEWS = {"front-right": (-0.6, -0.45, -1.0), "back-left": (0.8, -0.3, 0.7), "top": (0.2, -1.0, 0.3),
         "side": (-1.0, -0.1, 0.0)}
BG = (46, 48, 56)
PANEL_BG = (70, 74, 84)
TEXT = (235, 235, 235)
DIM = (170, 175, 185)
PAD = 12


def _font(size: int) -> ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)  # scalable (Pillow >= 10.1 with FreeType)
    except TypeError:  # pragma: no cover - older Pillow
        return ImageFont.load_default()


def _composite(render: np.ndarray, bg: tuple[int, int, int] = PANEL_BG) -> Image.Image:
    """The render (premultiplied by its alpha where blended) over a flat background."""
    rgb = render[..., :3].astype(np.float32)
    a = render[..., 3:4].astype(np.float32) / 255.0
    out = rgb + np.asarray(bg, np.float32) * (1.0 - a)
    return Image.fromarray(np.clip(out + 0.5, 0, 255).astype(np.uint8), "RGB")


def _checker(w: int, h: int, cell: int = 4) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    return np.where(((x // cell + y // cell) % 2)[..., None] == 0, 200, 150).astype(np.float32)


def _mip_tile(level: np.ndarray, size: tuple[int, int]) -> Image.Image:
    """A mip level shown at ``size`` (nearest), alpha over a checkerboard."""
    img = Image.fromarray(np.ascontiguousarray(level[..., :4]), "RGBA").resize(size, Image.NEAREST)
    arr = np.asarray(img, np.float32)
    a = arr[..., 3:4] / 255.0
    out = arr[..., :3] * a + _checker(size[0], size[1]) * (1.0 - a)
    return Image.fromarray(np.clip(out + 0.5, 0, 255).astype(np.uint8), "RGB")


def make_preview(model_json: Path | str, out_png: Path | str, view_px: int = 256,
                 texture_px: int = 128) -> Path:
    """Write the contact sheet of ``model_json`` to ``out_png``; returns the PNG path."""
    from .session import shared_renderer  # noqa: PLC0415

    model_json, out_png = Path(model_json), Path(out_png)
    model = load_built_model(model_json)
    renderer = shared_renderer(view_px, view_px)
    renderer.ctx.take_messages()
    font, small, big = _font(14), _font(12), _font(20)

    gpu = renderer.upload(model)
    try:
        views = [(name, _composite(renderer.render(gpu, fit_camera(model.center, model.radius, d, view_px,
                                                                    view_px))))
                 for name, d in VIEWS.items()]
        lod_cam = fit_camera(model.center, model.radius, VIEWS["front-right"], view_px, view_px)
        lods = []
        for k in range(max(model.lod_count, 1)):
            img = _composite(renderer.render(gpu, lod_cam, lod=k))
            errs = [m.lods[min(k, len(m.lods) - 1)].error.get("hausdorffRel", 0.0) for m in model.meshes if m.lods]
            dists = [m.lods[min(k, len(m.lods) - 1)].switch_distance for m in model.meshes if m.lods]
            label = [f"LOD{k}: {model.triangles(k):,} triangles",
                     f"error {max(errs, default=0.0):.3%} of diagonal", f"switch at {max(dists, default=0.0):.4g}"]
            lods.append((label, img))
    finally:
        renderer.release(gpu)

    # textures: every role of every material, all levels as stored
    strips: list[tuple[str, list[np.ndarray]]] = []
    for mat in model.sidecar.get("materials", []):
        for role, tex in (mat.get("textures") or {}).items():
            title = f"{mat.get('id')} / {role}"
            try:
                if tex.get("ktx2"):
                    img = read_ktx2((model.root / tex["ktx2"]).read_bytes())
                    levels = [np.asarray(lv) for lv in img.levels]
                    if img.block_format is not None:  # BC/ETC2 blocks: decoded for the strip
                        from assetpipe.core.ktx2 import decode_level  # noqa: PLC0415

                        levels = [decode_level(lv, img.vk_format, max(1, img.width >> k), max(1, img.height >> k))
                                  for k, lv in enumerate(levels)]
                    title += f"  {img.width}x{img.height}, {len(levels)} levels, vkFormat {img.vk_format}"
                else:
                    with Image.open(model.root / tex["path"]) as im:
                        levels = [np.asarray(im.convert("RGBA"))]
                    title += "  (no KTX2: level 0 image only)"
            except Exception as exc:  # noqa: BLE001 - show the problem on the sheet
                title += f"  UNREADABLE: {exc}"
                levels = []
            strips.append((title, levels))

    # layout
    cols = len(VIEWS)
    label_h = 20
    width = PAD + max(cols, len(lods)) * (view_px + PAD)
    tex_rows_h = sum(label_h + texture_px + PAD + 16 for _ in strips)
    lod_label_h = 3 * 16 + 4
    height = (PAD + 30 + 16 * min(len(model.notes), 4) + label_h + view_px + 20 + PAD + label_h + view_px
              + lod_label_h + PAD + (label_h + tex_rows_h if strips else 0) + PAD)
    sheet = Image.new("RGB", (width, height), BG)
    draw = ImageDraw.Draw(sheet)
    y = PAD
    n_mats = len(model.materials)
    draw.text((PAD, y), f"{model.id}   {len(model.meshes)} meshes, {model.triangles(0):,} triangles, "
                        f"{n_mats} materials, {max(model.lod_count, 1)} LODs", fill=TEXT, font=big)
    y += 30
    for note in model.notes[:4]:
        draw.text((PAD, y), f"note: {note}", fill=DIM, font=small)
        y += 16
    draw.text((PAD, y), "Views", fill=TEXT, font=font)
    y += label_h
    for i, (name, img) in enumerate(views):
        x = PAD + i * (view_px + PAD)
        sheet.paste(img, (x, y))
        draw.text((x + 4, y + view_px + 3), name, fill=DIM, font=small)
    y += view_px + 20 + PAD
    draw.text((PAD, y), "LODs (same camera)", fill=TEXT, font=font)
    y += label_h
    for i, (label, img) in enumerate(lods):
        x = PAD + i * (view_px + PAD)
        sheet.paste(img, (x, y))
        for j, line in enumerate(label):
            draw.text((x + 4, y + view_px + 3 + 16 * j), line, fill=TEXT if j == 0 else DIM, font=small)
    y += view_px + lod_label_h + PAD
    if strips:
        draw.text((PAD, y), "Textures (mip levels as stored)", fill=TEXT, font=font)
        y += label_h
        for title, levels in strips:
            draw.text((PAD, y), title, fill=DIM, font=small)
            y += 16
            x = PAD
            if levels:
                h0, w0 = levels[0].shape[:2]
                scale = texture_px / max(h0, w0)
                for k, lv in enumerate(levels):
                    h, w = lv.shape[:2]
                    size = (max(int(round(w * scale)), 6), max(int(round(h * scale)), 6))
                    if x + size[0] > width - PAD:
                        break
                    sheet.paste(_mip_tile(lv, size), (x, y))
                    draw.text((x, y + size[1] + 1), str(k), fill=DIM, font=small)
                    x += size[0] + 6
            y += texture_px + PAD + label_h - 16
    out_png.parent.mkdir(parents=True, exist_ok=True)
    sheet.crop((0, 0, width, min(height, y + PAD))).save(out_png)
    return out_png


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python -m renderer.preview OUT/ID.json preview.png")
    print(make_preview(sys.argv[1], sys.argv[2]))
