"""Regenerate the bundled example models (our own, CC0): ``python examples/make_examples.py``.

* ``crate/crate.gltf``: a textured cube (glTF with an external .bin and PNG);
* ``pyramid/pyramid.obj``: a textured square pyramid with a quad base (OBJ + MTL + PNG).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent


def texture(size: int, tint: tuple[int, int, int]) -> Image.Image:
    y, x = np.mgrid[0:size, 0:size]
    checker = ((x // (size // 8) + y // (size // 8)) % 2).astype(np.float64)
    shade = 0.55 + 0.45 * checker
    grad = 0.75 + 0.25 * (x / (size - 1))
    rgb = np.stack([shade * grad * c for c in tint], axis=-1)
    return Image.fromarray(np.clip(rgb, 0, 255).astype(np.uint8), "RGB")


def crate() -> None:
    d = HERE / "crate"
    d.mkdir(exist_ok=True)
    faces = []  # (normal axis, sign) -> 4 corners CCW seen from outside
    pos, uv, idx = [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            u_axis, v_axis = [(1, 2), (2, 0), (0, 1)][axis]
            corners = []
            for (a, b) in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0.0, 0.0, 0.0]
                p[axis] = 0.5 * sign
                p[u_axis] = 0.5 * a * sign
                p[v_axis] = 0.5 * b
                corners.append(p)
            base = len(pos)
            pos += corners
            uv += [[0, 1], [1, 1], [1, 0], [0, 0]]
            idx += [base, base + 1, base + 2, base, base + 2, base + 3]
            faces.append((axis, sign))
    p = np.array(pos, np.float32)
    t = np.array(uv, np.float32)
    i = np.array(idx, np.uint16)
    bin_ = i.tobytes() + p.tobytes() + t.tobytes()
    (d / "crate.bin").write_bytes(bin_)
    texture(256, (205, 150, 90)).save(d / "crate.png", optimize=True)
    n_i, n_p = i.nbytes, p.nbytes
    doc = {
        "asset": {"version": "2.0", "generator": "assetpipe examples/make_examples.py"},
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "crate"}],
        "meshes": [{"name": "crate", "primitives": [{"attributes": {"POSITION": 1, "TEXCOORD_0": 2},
                                                     "indices": 0, "material": 0}]}],
        "materials": [{"name": "wood", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                                "metallicFactor": 0.0}}],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987}],
        "images": [{"uri": "crate.png"}],
        "buffers": [{"uri": "crate.bin", "byteLength": len(bin_)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": n_i, "target": 34963},
            {"buffer": 0, "byteOffset": n_i, "byteLength": n_p, "target": 34962},
            {"buffer": 0, "byteOffset": n_i + n_p, "byteLength": t.nbytes, "target": 34962},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5123, "count": int(i.size), "type": "SCALAR"},
            {"bufferView": 1, "componentType": 5126, "count": len(p), "type": "VEC3",
             "min": p.min(axis=0).tolist(), "max": p.max(axis=0).tolist()},
            {"bufferView": 2, "componentType": 5126, "count": len(t), "type": "VEC2"},
        ],
    }
    (d / "crate.gltf").write_text(json.dumps(doc, indent=2) + "\n")


def pyramid() -> None:
    d = HERE / "pyramid"
    d.mkdir(exist_ok=True)
    texture(128, (170, 170, 185)).save(d / "stone.png", optimize=True)
    (d / "pyramid.mtl").write_text("newmtl stone\nKd 1 1 1\nmap_Kd stone.png\n")
    (d / "pyramid.obj").write_text(
        "# square pyramid: 4 triangle sides and a quad base\n"
        "mtllib pyramid.mtl\n"
        "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv 0 1.5 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 1\n"
        "o pyramid\nusemtl stone\n"
        "f 1/1 2/2 3/3 4/4\n"
        "f 1/1 2/2 5/5\nf 2/1 3/2 5/5\nf 3/1 4/2 5/5\nf 4/1 1/2 5/5\n")


if __name__ == "__main__":
    crate()
    pyramid()
