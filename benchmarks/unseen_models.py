"""Generated models of kinds the corpus does not hold, for the LOD benchmark's check that the
accuracy goals carry over to models nothing was tuned on.

``write_unseen_models(folder)`` writes five files (fixed seeds, so every run measures the same
geometry):

* ``blob.obj``: an icosphere subdivided 6 times (81,920 triangles) with a smooth bump and 1%
  noise, scaled by 37 and offset by (1e4, -3e3, 250): a scan far from the origin;
* ``bracket.glb``: six primitives in one material (a 4 x 1 x 0.2 slab of 12 triangles, three
  48-sided cylinders, an annulus, a capsule): a small CAD part whose pieces are merged;
* ``terrain.glb``: a 160 x 160 height field with UVs tiled 50 times;
* ``shell.glb``: a torus inside a slightly thinner torus facing inward (two sheets 1% apart);
* ``cracked.obj``: two half-cylinder grids of different resolutions meeting along a seam they
  do not share (T-junctions: an open crack, as CAD tessellations leave them).

Used by ``benchmarks/lod.py --unseen`` (TABLE 1 and TABLE 2 on these besides the corpus).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    """(2 (rows-1) (cols-1), 3) triangles of a rows x cols vertex grid (row-major)."""
    i = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return np.concatenate([np.stack([a, d, b], 1), np.stack([a, c, d], 1)])


def blob(path: Path, seed: int = 5) -> Path:
    import trimesh

    rng = np.random.default_rng(seed)
    s = trimesh.creation.icosphere(6)
    v = np.asarray(s.vertices)
    bump = (0.08 * np.sin(5 * v[:, 0]) * np.cos(7 * v[:, 1]))[:, None] + 0.01 * rng.normal(size=(len(v), 1))
    pos = v * (1 + bump) * 37.0 + [1e4, -3e3, 250]
    trimesh.Trimesh(pos, s.faces, process=False).export(str(path))
    return path


def bracket(path: Path) -> Path:
    import trimesh

    parts = [trimesh.creation.box([4, 1, 0.2])]
    for x in (-1.5, 0.0, 1.5):
        parts.append(trimesh.creation.cylinder(0.15, 1.2, sections=48).apply_translation([x, 0, 0.6]))
    parts.append(trimesh.creation.annulus(0.3, 0.5, 0.3, sections=64).apply_translation([0, 0.3, 0.25]))
    cap = trimesh.creation.capsule(1.0, 0.2, count=[24, 24])
    cap.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    parts.append(cap.apply_translation([0, -0.4, 0.5]))
    scene = trimesh.Scene()
    for i, p in enumerate(parts):
        scene.add_geometry(p, node_name=f"part{i}", geom_name=f"part{i}")
    scene.export(str(path))
    return path


def terrain(path: Path, n: int = 160) -> Path:
    import trimesh

    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    z = 0.05 * np.sin(9 * x) * np.cos(6 * y) + 0.02 * np.sin(31 * x * y)
    pos = np.stack([x.ravel(), y.ravel(), z.ravel()], 1) * 100
    uv = np.stack([x.ravel(), y.ravel()], 1) * 50
    mesh = trimesh.Trimesh(pos, _grid_faces(n, n)[:, [0, 2, 1]], process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv))
    mesh.export(str(path))
    return path


def shell(path: Path) -> Path:
    import trimesh

    outer = trimesh.creation.torus(1.0, 0.3, major_sections=96, minor_sections=48)
    inner = trimesh.creation.torus(1.0, 0.29, major_sections=64, minor_sections=32)
    inner.invert()
    trimesh.util.concatenate([outer, inner]).export(str(path))
    return path


def cracked(path: Path) -> Path:
    import trimesh

    def half(nu: int, nv: int, u0: float, u1: float):
        u, v = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(0, 1, nv))
        pos = np.stack([np.cos(u.ravel() * np.pi), v.ravel() * 2, np.sin(u.ravel() * np.pi)], 1)
        return pos, _grid_faces(nv, nu)

    p1, f1 = half(40, 30, 0.0, 0.5)
    p2, f2 = half(60, 45, 0.5, 1.0)
    trimesh.Trimesh(np.concatenate([p1, p2]), np.concatenate([f1, f2 + len(p1)]),
                    process=False).export(str(path))
    return path


def write_unseen_models(folder: Path) -> list[tuple[str, Path]]:
    """(name, path) of each generated model, written into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    return [("blob (generated)", blob(folder / "blob.obj")),
            ("bracket (generated)", bracket(folder / "bracket.glb")),
            ("terrain (generated)", terrain(folder / "terrain.glb")),
            ("shell (generated)", shell(folder / "shell.glb")),
            ("cracked (generated)", cracked(folder / "cracked.obj"))]
