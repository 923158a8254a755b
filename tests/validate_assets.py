"""Generated glTF assets of every material kind, for the validator's false-alarm and mutation tests.

``write_assets(folder)`` writes one .glb per kind (:data:`KINDS`): a UV sphere (normals, UVs,
a second UV set, vertex colours where the kind needs them) with small textures made here:

* ``pbr``: base colour (red top half, blue bottom half, stripes: a flipped V or a wrong texture
  moves the picture), a bumpy normal map (short-period bumps, so mips that skip renormalisation
  shorten vectors), metallic-roughness, occlusion on UV set 1, and a *mostly black emissive*
  (256 x 256, one 2 x 2 white spot: its linear mean rounds to black at the small mips);
* ``specgloss``: KHR_materials_pbrSpecularGlossiness with a diffuse texture and the default
  specularFactor (1, 1, 1), the issue's false alarm;
* ``mask`` / ``blend``: alpha-tested and blended base colour; ``masksoft``: alpha-tested at 0.9
  over a fine pattern of opaque texels, whose small levels' alpha the coverage-keeping chain
  scales up;
* ``transform``: KHR_texture_transform on the base colour;
* ``vertexcolor``: COLOR_0, no texture;
* ``multiuv``: base colour on TEXCOORD_1;
* ``normalmap``: a renormalised-normal-map fixture: a normal map whose source texels are not
  unit length (so the build's renormalised level 0 differs from the PNG's bytes);
* ``orm``: occlusion, roughness and metallic packed in one texture (R, G, B) that both roles name,
  on TEXCOORD_0 with the base colour and the normal map, so the shaded picture draws every role.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from gltf_builder import GltfBuilder

KINDS = ("pbr", "specgloss", "mask", "masksoft", "blend", "transform", "vertexcolor", "multiuv", "normalmap", "orm")


def sphere(seg_u: int = 32, seg_v: int = 16):
    """(positions, normals, uv0, uv1, indices) of a UV sphere of radius 1; counter-clockwise outside."""
    u = np.linspace(0, 1, seg_u + 1)
    v = np.linspace(0, 1, seg_v + 1)
    uu, vv = np.meshgrid(u, v)
    theta, phi = uu * 2 * np.pi, vv * np.pi
    pos = np.stack([np.sin(phi) * np.cos(theta), np.cos(phi), -np.sin(phi) * np.sin(theta)], -1).reshape(-1, 3)
    uv0 = np.stack([uu, vv], -1).reshape(-1, 2)
    uv1 = uv0 * 0.5 + 0.25
    i = np.arange(seg_v)[:, None] * (seg_u + 1) + np.arange(seg_u)[None, :]
    a, b, c, d = i, i + 1, i + seg_u + 1, i + seg_u + 2
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    p = pos[tris]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    tris = tris[area > 1e-9]  # the poles' degenerate triangles
    return (pos.astype(np.float32), pos.astype(np.float32), uv0.astype(np.float32), uv1.astype(np.float32),
            tris.astype(np.uint16))


def png(rgba: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba, np.uint8)).save(buf, "PNG")
    return buf.getvalue()


def base_texture(n: int = 64, alpha: np.ndarray | None = None) -> np.ndarray:
    img = np.zeros((n, n, 4), np.uint8)
    img[: n // 2] = (220, 60, 40, 255)
    img[n // 2:] = (40, 80, 220, 255)
    img[:, (np.arange(n) // 8) % 2 == 1, :3] //= 2
    if alpha is not None:
        img[..., 3] = alpha
    return img


def normal_texture(n: int = 64, unit: bool = True) -> np.ndarray:
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    v = np.stack([0.5 * np.sin(x * np.pi / 2), 0.5 * np.cos(y * np.pi / 2 + 0.3), np.ones_like(x)], -1)
    if unit:
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
    else:
        v *= 0.8  # not unit length: the build renormalises level 0
    out = np.empty((n, n, 4), np.uint8)
    out[..., :3] = np.rint((np.clip(v, -1, 1) + 1) * 127.5)
    out[..., 3] = 255
    return out


def data_texture(n: int = 64, seed: int = 0) -> np.ndarray:
    y, x = np.mgrid[0:n, 0:n]
    img = np.empty((n, n, 4), np.uint8)
    img[..., 0] = 255 - (x * 2) % 256 if seed else 200
    img[..., 1] = (y * 4 + 30) % 256
    img[..., 2] = ((x // 16 + y // 16) % 2) * 200 + 20
    img[..., 3] = 255
    return img


def orm_texture(n: int = 64) -> np.ndarray:
    """Occlusion (R: a dark band), roughness (G: a ramp along U) and metallic (B: stripes on one
    side), none symmetric under a half turn, so a texture turned around changes every channel's picture."""
    y, x = np.mgrid[0:n, 0:n]
    img = np.empty((n, n, 4), np.uint8)
    img[..., 0] = np.where((y >= n // 4) & (y < n // 2), 70, 255)
    img[..., 1] = 40 + (x * 200) // (n - 1)
    img[..., 2] = np.where((x < n // 3) & (y % 16 < 8), 255, 0)  # metal stripes on the left third only
    img[..., 3] = 255
    return img


def emissive_texture(n: int = 256) -> np.ndarray:
    img = np.zeros((n, n, 4), np.uint8)
    img[..., 3] = 255
    img[100:102, 60:62, :3] = 255
    return img


def make_asset(kind: str) -> GltfBuilder:
    b = GltfBuilder()
    pos, nrm, uv0, uv1, idx = sphere()
    attrs = {"NORMAL": nrm, "TEXCOORD_0": uv0, "TEXCOORD_1": uv1}
    mat: dict = {"name": kind, "pbrMetallicRoughness": {"metallicFactor": 0.0}}
    pbr = mat["pbrMetallicRoughness"]

    def tex(img: np.ndarray) -> int:
        return b.add_texture(data=png(img), sampler={"magFilter": 9729, "minFilter": 9987})

    if kind == "pbr":
        pbr["baseColorTexture"] = {"index": tex(base_texture())}
        pbr["metallicRoughnessTexture"] = {"index": tex(data_texture(seed=1))}
        mat["normalTexture"] = {"index": tex(normal_texture())}
        # on TEXCOORD_1 (drawn from the layout's uv1 when the build carries it); a dark band that a
        # half turn moves (the R channel of data_texture(seed=0) is uniform: turned, it looked the same)
        mat["occlusionTexture"] = {"index": tex(orm_texture()), "texCoord": 1}
        mat["emissiveTexture"] = {"index": tex(emissive_texture())}
        mat["emissiveFactor"] = [1.0, 1.0, 1.0]
    elif kind == "specgloss":
        mat = {"name": kind, "extensions": {"KHR_materials_pbrSpecularGlossiness": {
            "diffuseTexture": {"index": tex(base_texture())}, "glossinessFactor": 0.5}}}
        b.doc["extensionsUsed"] = ["KHR_materials_pbrSpecularGlossiness"]
    elif kind == "mask":
        alpha = np.where((np.indices((64, 64)).sum(0) // 8) % 2 == 0, 255, 0).astype(np.uint8)
        pbr["baseColorTexture"] = {"index": tex(base_texture(alpha=alpha))}
        mat.update(alphaMode="MASK", alphaCutoff=0.5, doubleSided=True)
    elif kind == "masksoft":
        # a fine pattern of opaque texels (20%) over transparent ones, tested at 0.9, as
        # AlphaBlendModeTest's labels: the small levels' alpha averages to about 0.2 everywhere,
        # and keeping 20% of texels above the cutoff scales it up about 4.5x, so their
        # premultiplied means move far from level 0's, which the old rule took for a broken chain
        dots = np.where(np.random.default_rng(5).random((64, 64)) < 0.2, 255, 0).astype(np.uint8)
        pbr["baseColorTexture"] = {"index": tex(base_texture(alpha=dots))}
        mat.update(alphaMode="MASK", alphaCutoff=0.9, doubleSided=True)
    elif kind == "blend":
        pbr["baseColorTexture"] = {"index": tex(base_texture(alpha=np.full((64, 64), 160, np.uint8)))}
        mat.update(alphaMode="BLEND")
    elif kind == "transform":
        pbr["baseColorTexture"] = {"index": tex(base_texture()), "extensions": {
            "KHR_texture_transform": {"offset": [0.25, 0.0], "scale": [2.0, 1.0]}}}
        b.doc["extensionsUsed"] = ["KHR_texture_transform"]
    elif kind == "vertexcolor":
        col = np.c_[(pos + 1) / 2, np.ones(len(pos))].astype(np.float32)
        attrs["COLOR_0"] = col
    elif kind == "multiuv":
        pbr["baseColorTexture"] = {"index": tex(base_texture()), "texCoord": 1}
    elif kind == "orm":
        orm = tex(orm_texture())
        pbr["baseColorTexture"] = {"index": tex(base_texture())}
        pbr["metallicRoughnessTexture"] = {"index": orm}
        mat["occlusionTexture"] = {"index": orm}
        mat["normalTexture"] = {"index": tex(normal_texture())}
    elif kind == "normalmap":
        pbr["baseColorTexture"] = {"index": tex(base_texture())}
        mat["normalTexture"] = {"index": tex(normal_texture(unit=False))}
    else:
        raise ValueError(kind)
    m = b.add_material(**mat)
    b.add_node(mesh=b.add_triangles(pos, idx, material=m, **attrs), name=kind)
    return b


def write_assets(folder: Path, kinds: tuple[str, ...] = KINDS) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    return [make_asset(k).write_glb(folder / f"{k}.glb") for k in kinds]


def write_wires_obj(path: Path, wires: int = 20, radius: float = 0.004, seed: int = 1) -> Path:
    """An OBJ of ``wires`` thin bent tubes (24 sides, 40 rings, ``radius``) around a bumpy
    sphere of radius 0.5: at 256 px the wires are under a pixel wide, so a picture at one sample
    a pixel shows them dotted (what the silhouette and lods checks' second look is for)."""
    rng = np.random.default_rng(seed)
    verts, faces, off = [], [], 0

    def add(v: np.ndarray, f: np.ndarray) -> None:
        nonlocal off
        verts.append(v)
        faces.append(f + off)
        off += len(v)

    from robust_models import bent_curve, tube

    tube_pos, tf = tube(bent_curve(40), radius, 24)
    for _ in range(wires):
        rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        if np.linalg.det(rot) < 0:
            rot[:, 0] *= -1
        add(tube_pos @ rot.T + rng.normal(size=3) * 0.3, tf)
    sp, _, _, _, si = sphere(48, 24)
    add(sp * 0.5 + [1.5, 0, 0], si.reshape(-1, 3))
    with open(path, "w") as fh:
        fh.writelines("v %.6f %.6f %.6f\n" % tuple(p) for p in np.concatenate(verts))
        fh.writelines("f %d %d %d\n" % tuple(f) for f in np.concatenate(faces) + 1)
    return path
