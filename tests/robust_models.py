"""Small generated models and helpers for the robustness tests (kill, determinism, precision,
confinement): UV spheres as OBJ or glTF, a glTF whose material has three textures (the key
order of a material's ``textures`` once followed step completion), and a CLI runner in a
subprocess with this checkout's code."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from gltf_builder import GltfBuilder

REPO = Path(__file__).resolve().parents[1]


def uv_sphere(n_lon: int = 24, n_lat: int = 12, r: float = 1.0, center=(0.0, 0.0, 0.0)):
    """(positions (N, 3) float64, triangles (M, 3) uint32, uv (N, 2) float32); closed, outward
    winding, a UV seam column duplicated."""
    pos, uv = [], []
    for j in range(1, n_lat):
        th = np.pi * j / n_lat
        for i in range(n_lon + 1):
            ph = 2 * np.pi * (i % n_lon) / n_lon
            pos.append([r * np.sin(th) * np.cos(ph), r * np.sin(th) * np.sin(ph), r * np.cos(th)])
            uv.append([i / n_lon, j / n_lat])
    top, bottom = len(pos), len(pos) + 1
    pos += [[0, 0, r], [0, 0, -r]]
    uv += [[0.5, 0.0], [0.5, 1.0]]
    w = n_lon + 1
    tris = []
    for j in range(n_lat - 2):
        for i in range(n_lon):
            a, b, c, d = j * w + i, j * w + i + 1, (j + 1) * w + i, (j + 1) * w + i + 1
            tris += [[a, c, b], [b, c, d]]
    last = (n_lat - 2) * w
    for i in range(n_lon):
        tris.append([top, i, i + 1])
        tris.append([bottom, last + i + 1, last + i])
    p = np.array(pos, np.float64) + np.asarray(center, np.float64)
    return p, np.array(tris, np.uint32), np.array(uv, np.float32)


def tube(centre: np.ndarray, radius: float, sides: int = 24, caps: bool = True, across=(1.0, 0.0, 0.0)):
    """A tube of ``sides`` around the polyline ``centre`` (P, 3): (positions (N, 3) float64,
    faces (M, 3) int64), outward-facing; ``caps``: closed with a fan at each end; ``across``:
    a direction never along the curve (the rings' first axis is across it)."""
    centre = np.asarray(centre, np.float64)
    d = np.gradient(centre, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = np.cross(d, np.asarray(across, np.float64))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(d, a)
    th = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.cos(th)[None, :, None] * a[:, None] + np.sin(th)[None, :, None] * b[:, None]
    pos = (centre[:, None] + radius * ring).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(len(centre) - 1), np.arange(sides), indexing="ij")
    v0, v1 = i * sides + j, i * sides + (j + 1) % sides
    faces = [np.stack([v0, v1, v1 + sides], -1).reshape(-1, 3),
             np.stack([v0, v1 + sides, v0 + sides], -1).reshape(-1, 3)]
    if caps:
        n, s, last = len(pos), np.arange(sides), (len(centre) - 1) * sides
        faces += [np.stack([np.full(sides, n), (s + 1) % sides, s], 1),
                  np.stack([np.full(sides, n + 1), last + s, last + (s + 1) % sides], 1)]
        pos = np.vstack([pos, centre[0], centre[-1]])
    return pos, np.concatenate(faces).astype(np.int64)


def bent_curve(points: int = 40) -> np.ndarray:
    """(points, 3) a bent curve about 1.7 long (a leg, a wire)."""
    t = np.linspace(0, 1, points)
    return np.stack([np.sin(3 * t) * 0.6, np.cos(2 * t) * 0.4, t * 1.5], 1)


def write_obj(path: Path, pos, tris, uv=None) -> Path:
    """An OBJ with positions written exactly (repr: float64 round trip)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(pos, np.float64).tolist()]
    if uv is not None:
        lines += [f"vt {u!r} {v!r}" for u, v in np.asarray(uv, np.float64).tolist()]
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in (np.asarray(tris, np.int64) + 1).tolist()]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in (np.asarray(tris, np.int64) + 1).tolist()]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def png_bytes(w: int, h: int, seed: int) -> bytes:
    from PIL import Image

    rng = np.random.default_rng(seed)
    img = Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), "RGB")
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


def write_textured_gltf(path: Path, n_lon: int = 24, n_lat: int = 12, seed: int = 0) -> Path:
    """A sphere whose material has baseColor, normal and metallicRoughness textures (PNG files
    beside it): the import lists them in that order, sorted keys put metallicRoughness second."""
    pos, tris, uv = uv_sphere(n_lon, n_lat)
    b = GltfBuilder()
    path = Path(path)
    texs = {}
    for k, role in enumerate(("base", "normal", "mr")):
        name = f"{path.stem}-{role}.png"
        (path.parent / name).write_bytes(png_bytes(16, 16, seed * 10 + k))
        texs[role] = b.add_texture(uri=name)
    mat = b.add_material(pbrMetallicRoughness={"baseColorTexture": {"index": texs["base"]},
                                               "metallicRoughnessTexture": {"index": texs["mr"]}},
                         normalTexture={"index": texs["normal"]})
    normals = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    b.add_node(mesh=b.add_triangles(pos, tris, material=mat, NORMAL=normals, TEXCOORD_0=uv))
    return b.write_gltf(path)


def write_sphere_glb(path: Path, pos, tris) -> Path:
    b = GltfBuilder()
    b.add_node(mesh=b.add_triangles(np.asarray(pos, np.float32), np.asarray(tris)))
    return b.write_glb(path)


def make_inputs(folder: Path, n_obj: int = 4, n_gltf: int = 2) -> Path:
    """A folder of small models: OBJ spheres of varied density and textured glTF spheres."""
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(n_obj):
        pos, tris, uv = uv_sphere(16 + 8 * k, 8 + 4 * k, r=1.0 + k)
        write_obj(folder / f"ball{k}.obj", pos, tris, uv)
    for k in range(n_gltf):
        write_textured_gltf(folder / f"tex{k}.gltf", 20 + 4 * k, 10 + 2 * k, seed=k)
    return folder


def cli_env(**extra) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update({k: str(v) for k, v in extra.items()})
    return env


def cli_cmd(*args) -> list[str]:
    return [sys.executable, "-m", "assetpipe.cli", *[str(a) for a in args]]


def run_cli(*args, env=None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(cli_cmd(*args), env=env or cli_env(), capture_output=True, text=True, timeout=timeout)


def output_bytes(out_dir: Path) -> dict[str, bytes]:
    """Every file a build wrote into ``out_dir``, except its own state folder."""
    out = {}
    for p in sorted(Path(out_dir).rglob("*")):
        rel = p.relative_to(out_dir)
        if p.is_file() and rel.parts[0] != ".assetpipe":
            out[rel.as_posix()] = p.read_bytes()
    return out


def assert_same_outputs(got: dict[str, bytes], want: dict[str, bytes], what: str) -> None:
    assert sorted(got) == sorted(want), f"{what}: file lists differ: {sorted(set(got) ^ set(want))}"
    differ = [k for k in want if got[k] != want[k]]
    assert not differ, f"{what}: files differ from a clean build: {differ}"


def verify_cache(cache: Path) -> tuple[int, int]:
    """(blobs, records) checked: every blob's content matches its name, every record parses,
    matches its checksum and names only intact blobs."""
    from assetpipe.cache.store import Store
    from assetpipe.core.hashing import digest_bytes

    store = Store(cache)
    blobs = records = 0
    for p in sorted((cache / "objects").glob("*/*")):
        assert digest_bytes(p.read_bytes()) == f"xxh3:{p.parent.name}{p.name}", f"corrupt blob {p}"
        blobs += 1
    for p in sorted((cache / "actions").glob("*/*")):
        assert store.get_record(f"xxh3:{p.parent.name}{p.name}") is not None, f"corrupt record {p}"
        records += 1
    assert not store.dropped, store.dropped
    return blobs, records
