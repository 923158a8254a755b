"""Generated CAD-style models for the LOD benchmark: models the corpus does not hold.

``write_cad_models(folder)`` writes two .glb files (fixed seeds, so every run measures the same
geometry):

* ``assembly.glb``: 62 parts in 7 materials: six subdivided boxes (flat faces: free to simplify),
  40 bolts (a 24-sided shank and a hexagonal head each), eight gears (annuli) and eight shafts
  (long 48-sided cylinders): many small closed parts with hard edges, the kind of model where
  one ratio for every part wastes triangles and the simplifier stalls on part counts;
* ``pipes.glb``: 15 bent tubes (24 sides, 200 rings, smooth spline paths) in 3 materials: a
  piping plant, smooth and thin.

Used by ``benchmarks/lod.py --cad`` (TABLE 1 on these besides the corpus).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _material(rng: np.random.Generator, i: int):
    import trimesh

    colour = (np.r_[rng.random(3), 1.0] * 255).astype(np.uint8)
    return trimesh.visual.material.PBRMaterial(name=f"m{i}", baseColorFactor=colour)


def _placed(mesh, rng: np.random.Generator, spread: float):
    import trimesh

    t = trimesh.transformations.random_rotation_matrix(rng.random(3))
    t[:3, 3] = rng.normal(size=3) * spread
    return mesh.apply_transform(t)


def assembly(path: Path, seed: int = 7) -> Path:
    import trimesh

    rng = np.random.default_rng(seed)
    mats = [_material(rng, i) for i in range(7)]
    parts = []
    for k in range(6):
        box = trimesh.creation.box(extents=rng.uniform(0.2, 1.0, 3)).subdivide().subdivide()
        parts.append((box.apply_translation(rng.normal(size=3) * 0.6), k % 4))
    for _ in range(40):
        shank = trimesh.creation.cylinder(0.02, 0.15, sections=24)
        head = trimesh.creation.cylinder(0.04, 0.03, sections=6).apply_translation([0, 0, 0.08])
        parts.append((_placed(trimesh.util.concatenate([shank, head]), rng, 0.7), 4))
    for _ in range(8):
        t = trimesh.transformations.random_rotation_matrix(rng.random(3))
        t[:3, 3] = rng.normal(size=3) * 0.5
        parts.append((trimesh.creation.annulus(0.1, 0.25, 0.05, sections=64).apply_transform(t), 5))
        parts.append((trimesh.creation.cylinder(0.05, 1.2, sections=48).apply_transform(t), 6))
    scene = trimesh.Scene()
    for i, (mesh, mi) in enumerate(parts):
        mesh.visual = trimesh.visual.TextureVisuals(material=mats[mi])
        scene.add_geometry(mesh, node_name=f"p{i}", geom_name=f"g{i}")
    scene.export(str(path))
    return path


def _tube(points: np.ndarray, radius: float, sides: int = 24):
    """A tube of ``sides`` around a polyline ``points`` (P, 3), open ends: a trimesh.Trimesh."""
    import sys

    import trimesh

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from robust_models import tube  # noqa: PLC0415 - the tests' generated-model helpers

    pos, faces = tube(points, radius, sides, caps=False, across=(0.3, 0.5, 0.8))
    return trimesh.Trimesh(pos, faces, process=False)


def pipes(path: Path, seed: int = 7) -> Path:
    import trimesh
    from scipy.interpolate import splev, splprep

    rng = np.random.default_rng(seed)
    mats = [_material(rng, i) for i in range(3)]
    scene = trimesh.Scene()
    for k in range(15):
        control = np.cumsum(rng.normal(size=(12, 3)) * 0.3, axis=0)
        tck, _ = splprep(control.T, s=0.5)
        tube = _tube(np.array(splev(np.linspace(0, 1, 200), tck)).T, 0.05 + 0.05 * rng.random())
        tube.visual = trimesh.visual.TextureVisuals(material=mats[k % 3])
        scene.add_geometry(tube, node_name=f"t{k}", geom_name=f"t{k}")
    scene.export(str(path))
    return path


def write_cad_models(folder: Path) -> list[tuple[str, Path]]:
    """(name, path) of each generated model, written into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    return [("assembly (generated)", assembly(folder / "assembly.glb")),
            ("pipes (generated)", pipes(folder / "pipes.glb"))]
