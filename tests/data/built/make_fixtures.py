"""Write the hand-made built fixtures of the renderer tests, in the format of docs/FORMAT.md.

``cube``: one model with two meshes and two materials:

* ``mesh-0-0``: a unit cube (-0.5..0.5), each face a 3x3 vertex grid (8 triangles a face),
  textured with an 8x8 four-colour texture (KTX2, 4 levels, R8G8B8A8_SRGB) on every face.
  LOD1 is the same cube with 2 triangles a face, using the prefix of the vertex range that
  holds the face corners (so ``vertexCount`` 24 of 54).
* ``mesh-1-0``: a double-sided quad in front of the cube with a half-transparent
  (BLEND) orange material, no texture.

The source the model was "built" from is written too: ``src/cube.obj`` (same geometry,
for the source comparison check). Run ``python tests/data/built/make_fixtures.py`` to
regenerate; the outputs are committed.
"""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent
KTX2_ID = b"\xabKTX 20\xbb\r\n\x1a\n"


def texture_levels() -> list[np.ndarray]:
    """An 8x8 texture (four coloured quadrants, a white dot) and its gamma-correct box-filtered mips."""
    lv0 = np.zeros((8, 8, 4), np.uint8)
    lv0[..., 3] = 255
    lv0[:4, :4, :3] = (220, 40, 40)
    lv0[:4, 4:, :3] = (40, 200, 60)
    lv0[4:, :4, :3] = (50, 80, 230)
    lv0[4:, 4:, :3] = (240, 220, 40)
    lv0[1, 1, :3] = 255
    levels = [lv0]
    lin = _to_linear(lv0[..., :3].astype(np.float64) / 255.0)
    alpha = lv0[..., 3].astype(np.float64) / 255.0
    while levels[-1].shape[0] > 1:  # gamma-correct box filter (average in linear light)
        h, w = lin.shape[0] // 2, lin.shape[1] // 2
        lin = lin.reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
        alpha = alpha.reshape(h, 2, w, 2).mean(axis=(1, 3))
        rgb = np.round(_to_srgb(lin) * 255.0)
        levels.append(np.concatenate([rgb, np.round(alpha * 255.0)[..., None]], axis=-1).astype(np.uint8))
    return levels


def _to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _to_srgb(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def ktx2_bytes(levels: list[np.ndarray], vk_format: int = 43) -> bytes:
    """A KTX2 file: 2D, one layer, one face, no supercompression, RGBA8 with a basic DFD."""
    srgb = vk_format == 43
    samples = b"".join(
        struct.pack("<HBBBBBBII", 8 * i, 7, ch | (0x10 if (ch == 15 and srgb) else 0), 0, 0, 0, 0, 0, 255)
        for i, ch in enumerate((0, 1, 2, 15)))
    block = struct.pack("<IHHBBBB4B8B", 0, 2, 24 + len(samples), 1, 1, 2 if srgb else 1, 0,
                        0, 0, 0, 0, 4, 0, 0, 0, 0, 0, 0, 0) + samples
    dfd = struct.pack("<I", 4 + len(block)) + block
    n = len(levels)
    header_size = 12 + 9 * 4 + 4 * 4 + 2 * 8 + n * 24
    dfd_offset = header_size
    data_start = (dfd_offset + len(dfd) + 3) // 4 * 4
    # levels are stored smallest first; the index lists level 0 first
    offsets = [0] * n
    pos = data_start
    for i in reversed(range(n)):
        offsets[i] = pos
        pos += (levels[i].nbytes + 3) // 4 * 4
    h, w = levels[0].shape[:2]
    out = bytearray(KTX2_ID)
    out += struct.pack("<9I", vk_format, 1, w, h, 0, 0, 1, n, 0)
    out += struct.pack("<4I2Q", dfd_offset, len(dfd), 0, 0, 0, 0)
    for i in range(n):
        out += struct.pack("<3Q", offsets[i], levels[i].nbytes, levels[i].nbytes)
    out += dfd
    out += b"\0" * (data_start - len(out))
    for i in reversed(range(n)):
        assert len(out) == offsets[i]
        out += levels[i].tobytes()
        out += b"\0" * ((-len(out)) % 4)
    return bytes(out)


def cube_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (54, 5: x y z u v) with face corners first, LOD0 (48, 3) and LOD1 (12, 3) triangles."""
    # each face: origin corner, two edge vectors (u, v) so that u x v points outwards
    faces = [
        ((0.5, -0.5, 0.5), (0, 0, -1), (0, 1, 0)),    # +X
        ((-0.5, -0.5, -0.5), (0, 0, 1), (0, 1, 0)),   # -X
        ((-0.5, 0.5, 0.5), (1, 0, 0), (0, 0, -1)),    # +Y
        ((-0.5, -0.5, -0.5), (1, 0, 0), (0, 0, 1)),   # -Y
        ((-0.5, -0.5, 0.5), (1, 0, 0), (0, 1, 0)),    # +Z
        ((0.5, -0.5, -0.5), (-1, 0, 0), (0, 1, 0)),   # -Z
    ]
    corners, extras, lod0, lod1 = [], [], [], []
    grid_ids = np.zeros((6, 3, 3), int)
    for f, (o, du, dv) in enumerate(faces):
        o, du, dv = np.array(o, float), np.array(du, float), np.array(dv, float)
        for j in range(3):
            for i in range(3):
                p = o + du * i / 2 + dv * j / 2
                uv = (i / 2, 1 - j / 2)  # top-left origin: v grows downwards
                row = [*p, *uv]
                if i in (0, 2) and j in (0, 2):
                    grid_ids[f, j, i] = len(corners)
                    corners.append(row)
                else:
                    grid_ids[f, j, i] = -1 - len(extras)
                    extras.append(row)
    n_corners = len(corners)
    ids = np.where(grid_ids >= 0, grid_ids, n_corners + (-1 - grid_ids))
    for f in range(6):
        g = ids[f]
        for j in range(2):
            for i in range(2):
                a, b, c, d = g[j, i], g[j, i + 1], g[j + 1, i + 1], g[j + 1, i]
                lod0 += [(a, b, c), (a, c, d)]
        a, b, c, d = g[0, 0], g[0, 2], g[2, 2], g[2, 0]
        lod1 += [(a, b, c), (a, c, d)]
    verts = np.array(corners + extras, np.float32)
    return verts, np.array(lod0, np.uint32), np.array(lod1, np.uint32), ids


def quad_mesh() -> tuple[np.ndarray, np.ndarray]:
    """A 0.6 x 0.6 quad at z = 0.8 facing +Z."""
    v = np.array([[-0.3, -0.3, 0.8, 0, 1], [0.3, -0.3, 0.8, 1, 1], [0.3, 0.3, 0.8, 1, 0],
                  [-0.3, 0.3, 0.8, 0, 0]], np.float32)
    return v, np.array([(0, 1, 2), (0, 2, 3)], np.uint32)


def bounds(p: np.ndarray) -> dict:
    lo, hi = p.min(0).astype(float), p.max(0).astype(float)
    c = (lo + hi) / 2
    return {"min": lo.tolist(), "max": hi.tolist(), "center": c.tolist(),
            "radius": float(np.linalg.norm(hi - lo) / 2)}


def write_cube(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "textures").mkdir(exist_ok=True)
    mid = "cube"
    cube_v, lod0, lod1, _ = cube_mesh()
    quad_v, quad_i = quad_mesh()
    vtx = np.concatenate([cube_v, quad_v]).astype("<f4")
    idx = np.concatenate([lod0.ravel(), quad_i.ravel(), lod1.ravel()]).astype("<u4")
    (out / f"{mid}.vtx").write_bytes(vtx.tobytes())
    (out / f"{mid}.idx").write_bytes(idx.tobytes())

    levels = texture_levels()
    png = out / "textures" / "tmp.png"
    Image.fromarray(levels[0], "RGBA").save(png, optimize=False, compress_level=9)
    digest = "sha256-" + hashlib.sha256(png.read_bytes()).hexdigest()[:32]
    png_rel = f"textures/{digest}.png"
    png.replace(out / png_rel)
    ktx_rel = f"textures/{digest}-baseColor.ktx2"
    (out / ktx_rel).write_bytes(ktx2_bytes(levels))

    n0, nq, n1 = lod0.size * 4, quad_i.size * 4, lod1.size * 4
    seed = {"id": mid, "meshes": [
        {"id": "mesh-0-0", "materialId": f"{mid}-mat-0", "idxOffset": 0, "idxSize": n0,
         "vtxOffset": 0, "vtxSize": cube_v.size * 4},
        {"id": "mesh-1-0", "materialId": f"{mid}-mat-1", "idxOffset": n0, "idxSize": nq,
         "vtxOffset": cube_v.size * 4, "vtxSize": quad_v.size * 4}],
        "idxFilename": f"{mid}.idx", "vtxFilename": f"{mid}.vtx"}
    mats = [{"id": f"{mid}-mat-0", "texturePath": png_rel, "color": [1.0, 1.0, 1.0, 1.0]},
            {"id": f"{mid}-mat-1", "texturePath": "", "color": [1.0, 0.5, 0.1, 0.5]}]
    zero_err = {"simplifier": 0.0, "hausdorff": 0.0, "rms": 0.0, "hausdorffRel": 0.0, "rmsRel": 0.0}
    side = {
        "formatVersion": 1, "id": mid, "generator": "tests/data/built/make_fixtures.py",
        "vertexLayout": {"stride": 20, "attributes": [
            {"name": "position", "format": "float32x3", "offset": 0},
            {"name": "uv0", "format": "float32x2", "offset": 12}]},
        "bounds": bounds(vtx[:, :3]),
        "meshes": [
            {"id": "mesh-0-0", "name": "cube", "materialId": f"{mid}-mat-0", "vertexCount": len(cube_v),
             "triangleCount": len(lod0), "bounds": bounds(cube_v[:, :3]), "lods": [
                 {"level": 0, "idxOffset": 0, "idxSize": n0, "triangles": len(lod0), "vertexCount": len(cube_v),
                  "error": zero_err, "switchDistance": 0.0},
                 {"level": 1, "idxOffset": n0 + nq, "idxSize": n1, "triangles": len(lod1), "vertexCount": 24,
                  "error": zero_err, "switchDistance": 4.0}]},
            {"id": "mesh-1-0", "name": "glass", "materialId": f"{mid}-mat-1", "vertexCount": len(quad_v),
             "triangleCount": len(quad_i), "bounds": bounds(quad_v[:, :3]), "lods": [
                 {"level": 0, "idxOffset": n0, "idxSize": nq, "triangles": len(quad_i),
                  "vertexCount": len(quad_v), "error": zero_err, "switchDistance": 0.0}]}],
        "materials": [
            {"id": f"{mid}-mat-0", "name": "checker", "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
             "alphaMode": "OPAQUE", "alphaCutoff": 0.5, "doubleSided": False, "transparent": False,
             "textures": {"baseColor": {
                 "path": png_rel, "ktx2": ktx_rel, "width": 8, "height": 8, "levels": len(levels),
                 "colorSpace": "srgb", "vkFormat": 43, "texCoord": 0,
                 "sampler": {"magFilter": 9728, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}}}},
            {"id": f"{mid}-mat-1", "name": "glass", "baseColorFactor": [1.0, 0.5, 0.1, 0.5],
             "alphaMode": "BLEND", "alphaCutoff": 0.5, "doubleSided": True, "transparent": True,
             "textures": {}}],
        "stats": {"degenerateTriangles": 0, "weldedVertices": 0},
        "warnings": [],
        "sources": [{"path": "../src/cube.obj", "digest": "none"}],
    }
    (out / f"{mid}.json").write_text(json.dumps(seed, indent=2) + "\n")
    (out / f"{mid}-mat.json").write_text(json.dumps(mats, indent=2) + "\n")
    (out / f"{mid}.asset.json").write_text(json.dumps(side, indent=2) + "\n")

    # the "source": the same triangles as an OBJ (LOD0 cube + quad)
    src = HERE / "src"
    src.mkdir(exist_ok=True)
    Image.fromarray(levels[0], "RGBA").save(src / "checker.png", optimize=False, compress_level=9)
    (src / "cube.mtl").write_text("newmtl checker\nKd 1 1 1\nmap_Kd checker.png\n\n"
                                  "newmtl glass\nKd 1 0.5 0.1\nd 0.5\n")
    lines = ["# fixture source of tests/data/built/cube (written by make_fixtures.py)", "mtllib cube.mtl",
             "o cube", "usemtl checker"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in cube_v[:, :3]]
    lines += [f"vt {u:.6f} {1 - v:.6f}" for u, v in cube_v[:, 3:]]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in lod0]
    lines += ["o glass", "usemtl glass"]
    base = len(cube_v)
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in quad_v[:, :3]]
    lines += [f"vt {u:.6f} {1 - v:.6f}" for u, v in quad_v[:, 3:]]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in quad_i + base]
    (src / "cube.obj").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write_cube(HERE / "cube")
    print("wrote", HERE / "cube", "and", HERE / "src" / "cube.obj")
