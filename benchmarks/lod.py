"""LOD benchmark: simplifiers x ratios on the corpus and a generated 1M-triangle mesh.

Run:  .venv/bin/python benchmarks/lod.py            (everything; long: 1M samples a side)
      .venv/bin/python benchmarks/lod.py --quick    (4 small meshes, no 1M mesh)
      .venv/bin/python benchmarks/lod.py --only Duck,stanford-bunny --no-big
      .venv/bin/python benchmarks/lod.py --only spider,beast --no-big --no-simplifiers
          --variants ours --no-recorded --samples 100000   (TABLE 1 for a few cells, quickly)
      .venv/bin/python benchmarks/lod.py --cad --no-corpus --no-big --no-simplifiers --no-recorded
          (TABLE 1 on generated CAD-style models the corpus does not hold: benchmarks/cad_models.py)
      .venv/bin/python benchmarks/lod.py --unseen --no-corpus --no-big --no-simplifiers --variants ours
          (TABLE 1 and TABLE 2 on five generated models of kinds the corpus does not hold, nothing
          tuned on them: benchmarks/unseen_models.py)

Simplifier table: for every file (loaded with trimesh and merged into one mesh, node
transforms applied) and every simplifier (meshopt, meshopt-attr, meshopt+lock_border, sloppy,
fast-simplification) and ratio (1/2, 1/4, 1/8, 1/16), the mesh is simplified *directly from
level 0* in the same local frame and with the same welding as :func:`build_lod_chain`; the
simplifier call alone is timed, and the result's two-sided Hausdorff and RMS distance to level 0
is measured with :mod:`pipelines.surface_error`.

Comparison with gltfpack (found on PATH, else in .venv/node/node_modules/.bin of this checkout
or of /work/main): the same ratios go through ``gltfpack -si R -se 1 -sv -noq`` (its time
includes process start-up and file I/O), and its whole output is measured against the whole
model. Ours is made *the way the build makes it* (assetpipe/steps.py task_lod): the file is
imported and processed per mesh (default mesh options), then
:func:`pipelines.lod_model.build_model_lods` (merging, duplicates, affine copies, chains) and
level k of the model is the union of the output meshes' level k, measured against the same
whole-model reference. For equal triangle counts every output mesh uses gltfpack's overall
ratios (its output count / input count), ``min_triangles=1`` and no error budget. Variants:
``ours`` (default options), ``ours-chained`` and ``ours-direct`` (levels only from the level
above / only from level 0), ``ours-per-mesh`` (no merging, chained, duplicates kept: how the
build made levels before), ``ours-one-ratio`` (every mesh at every ratio: ``balance_meshes``
off). Their time is the whole chain's (all levels): with the build's
measurement for ``ours``, without it for the others (``--measure-variants``: with it; their
levels only differ where a stalled step picks among pruning and sloppy).

Printed at the end, from this one run:
* TABLE 1: per (mesh, ratio) cell, gltfpack's Hausdorff and each variant's as a multiple of
  it; per variant the share of cells within 1.1x gltfpack's (goal >= 90%). A cell is one draw of
  each simplifier, and meshoptimizer's largest error moves by up to 2.5x between triangle orders
  of one mesh: ``benchmarks/lod_draws.py`` compares medians over several orders;
* TABLE 2: the recorded Hausdorff of every level of the build's own chains (default options)
  against a dense ``--samples`` measurement with another seed (recorded/dense >= 1 when the
  recorded value is a bound);
* whole-chain throughput in input triangles per second, with and without error measurement.

Writes benchmarks/results/lod.csv, lod-chains.csv, lod-vs-gltfpack.csv, lod-recorded.csv and
lod-pareto.png (matplotlib, else drawn with Pillow).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from assetpipe.pipelines import simplify as simp  # noqa: E402
from assetpipe.pipelines.lod import (  # noqa: E402
    DEFAULT_LOD_OPTIONS, LodOptions, build_lod_chain, weld_for_simplification)
from assetpipe.pipelines.lod_model import build_model_lods  # noqa: E402
from assetpipe.pipelines.surface_error import (  # noqa: E402
    ZERO_ERROR as ZERO, local_frame, measure_against, measure_levels, points_to_mesh_distance,
    prepare_reference, sample_surface)

GLTFPACK_LOCAL = REPO / ".venv" / "node" / "node_modules" / ".bin" / "gltfpack"
GLTFPACK_MAIN = Path("/work/main/.venv/node/node_modules/.bin/gltfpack")
_SHARED = REPO.parent / "shared" / "corpus"
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", _SHARED if _SHARED.is_dir() else "/work/shared/corpus")) / "models"
RESULTS = REPO / "benchmarks" / "results"
#: TABLE 2: a level whose dense distance is under this fraction of the diagonal loses nothing
#: (float32 positions resolve about 6e-8 of a coordinate): its recorded/dense ratio is noise
LOSSLESS = 1e-6
RATIOS = (1 / 2, 1 / 4, 1 / 8, 1 / 16)
SIMPLIFIERS = ("meshopt", "meshopt-attr", "meshopt+lock_border", "sloppy", "fast-simplification")
#: our variants in the comparison with gltfpack: the default; levels only from the level above;
#: only from level 0; the way the build made them before merging (one chain per mesh); and every
#: mesh at every ratio (LodOptions.balance_meshes off; on by default since LOD step 17)
VARIANTS = {"ours": {}, "ours-chained": {"chain": "chained"}, "ours-direct": {"chain": "direct"},
            "ours-per-mesh": {"merge_meshes": False, "chain": "chained", "dedupe_triangles": False},
            "ours-one-ratio": {"balance_meshes": False},
            "ours-in-place": {"move_vertices": False}}
MIN_TRIANGLES = 300  # corpus files below this are too small to say anything


# ----------------------------------------------------------------------------- inputs


def load_merged(path: Path):
    """One corpus file as one mesh: positions f64, faces u32, uv f32|None, normals f32|None."""
    import trimesh

    s = trimesh.load(str(path), process=False)
    if isinstance(s, trimesh.Trimesh):
        s = trimesh.Scene(s)
    P, F, U, N, off, has_uv, has_n = [], [], [], [], 0, True, True
    for node in s.graph.nodes_geometry:
        T, name = s.graph[node]
        g = s.geometry[name]
        if not isinstance(g, trimesh.Trimesh) or len(g.faces) == 0:
            continue
        v = np.asarray(g.vertices, np.float64) @ T[:3, :3].T + T[:3, 3]
        f = np.asarray(g.faces, np.int64)
        if np.linalg.det(T[:3, :3]) < 0:
            f = f[:, ::-1]
        uv = getattr(g.visual, "uv", None)
        if uv is None or len(uv) != len(v):
            has_uv, uv = False, np.zeros((len(v), 2))
        n = g._cache.cache.get("vertex_normals")
        if n is None or len(n) != len(v):
            has_n, n = False, np.zeros((len(v), 3))
        else:
            n = n @ np.linalg.inv(T[:3, :3])
            n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        P.append(v), F.append(f + off), U.append(uv), N.append(n)
        off += len(v)
    if not P:
        return None
    return (np.concatenate(P), np.concatenate(F).astype(np.uint32),
            np.concatenate(U).astype(np.float32) if has_uv else None,
            np.concatenate(N).astype(np.float32) if has_n else None)


def displaced_torus(nu: int = 1000, nv: int = 500, seed: int = 0):
    """A closed torus grid, 2*nu*nv triangles (1M by default), displaced by seeded waves."""
    rng = np.random.default_rng(seed)
    u = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    v = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    U, V = np.meshgrid(u, v, indexing="ij")
    disp = np.zeros_like(U)
    for _ in range(24):
        a, b = rng.integers(1, 40, 2)
        ph = rng.random(2) * 2 * np.pi
        disp += rng.random() * 0.08 / np.sqrt(a * b) * np.sin(a * U + ph[0]) * np.sin(b * V + ph[1])
    rr = 0.35 + disp
    pos = np.stack([(1 + rr * np.cos(V)) * np.cos(U), (1 + rr * np.cos(V)) * np.sin(U),
                    rr * np.sin(V)], -1).reshape(-1, 3)
    uv = np.stack([U / (2 * np.pi), V / (2 * np.pi)], -1).reshape(-1, 2).astype(np.float32)
    i, j = np.arange(nu)[:, None], np.arange(nv)[None, :]
    a, b = i * nv + j, ((i + 1) % nu) * nv + j
    c, d = ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return pos, f.astype(np.uint32), uv, None


def corpus_files(only: set[str] | None):
    files = sorted([*CORPUS.glob("*/*.obj"), *CORPUS.glob("*/*.glb"), *CORPUS.glob("*/glTF/*.gltf")])
    for p in files:
        name = p.relative_to(CORPUS).parts[0]
        if only is None or name in only:
            yield name, p


# ----------------------------------------------------------------------------- runs


class Sampled:
    """A sampled two-sided Hausdorff distance against one reference mesh: ``n`` area samples
    a side plus every used vertex, exact point-to-triangle distances
    (surface_error.points_to_mesh_distance). A *lower* value of the true distance: what
    "the 1M-sample Hausdorff" means in the tables (as a fraction of the reference's diagonal)."""

    def __init__(self, pos: np.ndarray, idx: np.ndarray, n: int, seed: int = 7):
        self.pos = np.asarray(pos, np.float64)
        self.idx = np.asarray(idx, np.int64).reshape(-1, 3)
        _, self.diag = local_frame(self.pos, self.idx)
        self.n, self.seed = n, seed
        self.pts = np.concatenate([sample_surface(self.pos, self.idx, n, seed),
                                   self.pos[np.unique(self.idx)]])

    def rel(self, pos: np.ndarray, idx: np.ndarray) -> float:
        pos = np.asarray(pos, np.float64)
        idx = np.asarray(idx, np.int64).reshape(-1, 3)
        if idx.shape[0] == 0:
            return math.inf
        fwd = points_to_mesh_distance(self.pts, pos, idx).max()
        back_pts = np.concatenate([sample_surface(pos, idx, self.n, self.seed + 1), pos[np.unique(idx)]])
        back = points_to_mesh_distance(back_pts, self.pos, self.idx).max()
        return float(max(fwd, back)) / self.diag


def run_simplifier(kind: str, pos32, welded, target, uv, normals):
    o = DEFAULT_LOD_OPTIONS
    if kind == "meshopt":
        return simp.simplify(pos32, welded, target)[0]
    if kind == "meshopt+lock_border":
        return simp.simplify(pos32, welded, target, lock_border=True)[0]
    if kind == "meshopt-attr":
        cols, w = [], []
        if uv is not None:
            cols.append(uv), w.extend([o.uv_weight] * 2)
        if normals is not None:
            cols.append(normals), w.extend([o.normal_weight] * 3)
        if not cols:
            return simp.simplify(pos32, welded, target)[0]
        return simp.simplify(pos32, welded, target, attributes=np.concatenate(cols, 1),
                             attribute_weights=w)[0]
    if kind == "sloppy":
        return simp.simplify_sloppy(pos32, welded, target)[0]
    if kind == "fast-simplification":
        return simp.simplify_fast(pos32, welded, target)[0]
    raise ValueError(kind)


def find_gltfpack() -> str | None:
    """gltfpack on PATH, else the one npm installed beside the venv."""
    found = shutil.which("gltfpack")
    for local in (GLTFPACK_LOCAL, GLTFPACK_MAIN):
        if found is None and local.exists():
            found = str(local)
    return found


class Hd:
    """A measured Hausdorff distance shaped like SurfaceError for the tables (RMS not sampled)."""

    def __init__(self, rel: float):
        self.hausdorff_rel, self.rms_rel = rel, math.nan


def load_build_meshes(path: Path):
    """The file as the build's LOD step sees it: one :class:`LodPart` per mesh, after import
    and mesh processing with the default options (assetpipe.steps task_lod)."""
    from assetpipe.model_import import import_model
    from assetpipe.pipelines.lod_model import LodPart
    from assetpipe.steps import material_description, material_groups
    from assetpipe.pipelines.mesh_options import ATTRIBUTE_COMPONENTS, DEFAULT_MESH_OPTIONS
    from assetpipe.pipelines.mesh_process import process_mesh

    layout = DEFAULT_MESH_OPTIONS.layout
    cols, c = {}, 0
    for a in layout:
        cols[a] = slice(c, c + ATTRIBUTE_COMPONENTS[a])
        c += ATTRIBUTE_COMPONENTS[a]
    model = import_model(path)
    # meshes whose materials are equal in content share a group, as in the build (assetpipe.steps)
    groups = material_groups([material_description(m, lambda ref: ref.image.digest) for m in model.materials],
                             [mesh.material for mesh in model.meshes])
    out = []
    for mesh, group in zip(model.meshes, groups):
        pm = process_mesh(mesh, DEFAULT_MESH_OPTIONS)
        if pm.indices.shape[0] == 0:
            continue
        v = pm.vertices
        uv = v[:, cols["uv0"]] if "uv0" in cols and mesh.uv0 is not None else None
        normals = v[:, cols["normal"]] if "normal" in cols else None
        others = tuple(v[:, cols[a]] for a in layout if a not in ("position", "normal")
                       and not (a == "uv0" and uv is not None))
        exact = tuple(v[:, cols[a]] for a in layout if a not in ("position", "normal", "tangent"))
        mat = model.materials[mesh.material] if 0 <= mesh.material < len(model.materials) else None
        out.append(LodPart(vertices=v, positions=v[:, :3].astype(np.float64), indices=pm.indices,
                           uv=uv, normals=normals, others=others, exact=exact,
                           group_key=(group, uv is not None),
                           double_sided=bool(mat.double_sided) if mat is not None else False))
    return out


def whole_model(parts) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3) float64, triangles (M, 3) int64) of :func:`load_build_meshes`' parts as
    one mesh: the whole model every level is measured against."""
    pos = np.concatenate([b.positions for b in parts])
    offs = np.cumsum([0] + [len(b.positions) for b in parts])
    return pos, np.concatenate([b.indices.astype(np.int64) + o for b, o in zip(parts, offs)])


def union_levels(meshes, depth: int | None = None):
    """(all positions f64, level k of every output mesh concatenated, for each k).

    meshes: :class:`LodMesh` list. A mesh whose chain stopped early contributes its coarsest
    level to the deeper levels."""
    pos, offsets, off = [], [], 0
    for m in meshes:
        pos.append(np.asarray(m.vertices[:, :3], np.float64)), offsets.append(off)
        off += len(m.vertices)
    depth = depth or max(len(m.levels) for m in meshes)
    levels = [np.concatenate([m.levels[min(k, len(m.levels) - 1)].indices.astype(np.int64) + o
                              for m, o in zip(meshes, offsets)]) for k in range(depth)]
    return np.concatenate(pos), levels


def gltfpack_run(exe: str, src: Path, ratio: float, tmp: Path):
    import trimesh

    out = tmp / f"gp-{ratio:.4f}.glb"
    t = time.perf_counter()
    r = subprocess.run([exe, "-i", str(src), "-o", str(out), "-si", f"{ratio}", "-se", "1",
                        "-sv", "-noq"], capture_output=True, text=True)
    dt = time.perf_counter() - t
    if r.returncode != 0 or not out.exists():
        return None
    m = trimesh.load(str(out), force="mesh", process=False)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.uint32), dt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="4 small corpus meshes, no 1M mesh")
    ap.add_argument("--only", help="comma-separated corpus folder names")
    ap.add_argument("--no-big", action="store_true", help="skip the generated 1M-triangle mesh")
    ap.add_argument("--cad", action="store_true",
                    help="also the generated CAD-style models of benchmarks/cad_models.py (an assembly "
                         "of 62 small parts, a piping plant): models the corpus does not hold")
    ap.add_argument("--unseen", action="store_true",
                    help="also the generated models of benchmarks/unseen_models.py (a far-off noisy "
                         "scan, a small merged CAD part, a terrain with tiled UVs, a two-sheet shell, "
                         "a cracked seam): kinds the corpus does not hold, nothing tuned on them")
    ap.add_argument("--no-corpus", action="store_true",
                    help="no corpus files (with --cad / --unseen: those alone)")
    ap.add_argument("--no-gltfpack", action="store_true")
    ap.add_argument("--measure-variants", action="store_true",
                    help="build the ours-chained/-direct/-per-mesh variants with error measurement too")
    ap.add_argument("--no-simplifiers", action="store_true",
                    help="skip the per-simplifier table (meshopt, sloppy, fast-simplification, ...)")
    ap.add_argument("--samples", type=int, default=1_000_000,
                    help="area samples per side of the comparison measurements (1M by default)")
    ap.add_argument("--variants", help="comma-separated subset of our variants for TABLE 1 "
                    f"(default: all of {','.join(VARIANTS)})")
    ap.add_argument("--no-recorded", action="store_true",
                    help="skip TABLE 2 (the build's recorded bounds against a dense measurement)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()

    only = set(args.only.split(",")) if args.only else None
    variants = VARIANTS
    if args.variants:
        unknown = set(args.variants.split(",")) - set(VARIANTS)
        if unknown:
            ap.error(f"unknown variants {sorted(unknown)} (of {list(VARIANTS)})")
        variants = {v: VARIANTS[v] for v in args.variants.split(",")}
    if args.quick and only is None:
        only = {"Duck", "fuze", "spider", "stanford-bunny"}
    gltfpack = None if args.no_gltfpack else find_gltfpack()
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="lodbench-"))

    meshes = []
    for name, path in ([] if args.no_corpus else corpus_files(only)):
        m = load_merged(path)
        if m is None or len(m[1]) < MIN_TRIANGLES:
            continue
        meshes.append((name, path, m))
    if args.cad:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from cad_models import write_cad_models  # noqa: PLC0415 - beside this file

        for name, path in write_cad_models(tmp / "cad"):
            meshes.append((name, path, load_merged(path)))
    if args.unseen:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from unseen_models import write_unseen_models  # noqa: PLC0415 - beside this file

        for name, path in write_unseen_models(tmp / "unseen"):
            meshes.append((name, path, load_merged(path)))
    if not (args.quick or args.no_big):
        import trimesh

        big = displaced_torus()
        big_path = tmp / "torus-1M.glb"
        trimesh.Trimesh(big[0], big[1], process=False).export(str(big_path))
        meshes.append(("torus-1M (generated)", big_path, big))

    rows, chains, compare, recorded = [], [], [], []
    print(f"{'mesh':24} {'simplifier':20} {'ratio':>6} {'tris':>8} {'ms':>9} {'Mtri/s':>7} "
          f"{'haus%':>8} {'rms%':>8}")
    for name, path, (pos, tri, uv, normals) in meshes:
        m0 = len(tri)
        used = np.zeros(len(pos), bool)
        used[tri.reshape(-1)] = True
        lo, hi = pos[used].min(0), pos[used].max(0)
        diag = float(np.linalg.norm(hi - lo))
        pos32 = ((pos - (lo + hi) / 2) / diag).astype(np.float32)
        welded = weld_for_simplification(tri, pos, uv, normals)
        ref = None if args.no_simplifiers else prepare_reference(pos, tri, samples=args.samples)

        def emit(kind, ratio, out_tri, seconds, err):
            row = dict(mesh=name, simplifier=kind, ratio=ratio, input_triangles=m0,
                       triangles=int(out_tri), seconds=seconds,
                       mtris_per_s=m0 / seconds / 1e6 if seconds > 0 else math.nan,
                       hausdorff_pct=100 * err.hausdorff_rel, rms_pct=100 * err.rms_rel)
            rows.append(row)
            print(f"{name[:24]:24} {kind:20} {ratio:6.4f} {row['triangles']:8d} {1e3 * seconds:9.1f} "
                  f"{row['mtris_per_s']:7.2f} {row['hausdorff_pct']:8.4f} {row['rms_pct']:8.5f}",
                  flush=True)

        for kind in () if args.no_simplifiers else SIMPLIFIERS:
            outs, times = [], []
            for r in RATIOS:
                target = max(1, int(round(r * m0)))
                t = time.perf_counter()
                out = run_simplifier(kind, pos32, welded, target, uv, normals)
                times.append(time.perf_counter() - t)
                outs.append(out)
            for r, out, dt, err in zip(RATIOS, outs, times, measure_levels(ref, outs)):
                emit(kind, r, len(out), dt, err)
        # --- as the build does it: the model's meshes (build_model_lods), against the whole model
        build = load_build_meshes(path)
        bpos, bidx = whole_model(build)
        bref = prepare_reference(bpos, bidx, samples=DEFAULT_LOD_OPTIONS.error_samples)
        dense = Sampled(bpos, bidx, args.samples)
        m_build = len(bidx)
        if gltfpack:
            gp = []
            for r in RATIOS:
                res = gltfpack_run(gltfpack, path, r, tmp)
                if res is None:
                    print(f"{name[:24]:24} gltfpack failed at {r}")
                    continue
                gpos, gtri, dt = res
                gerr = Hd(dense.rel(gpos, gtri))
                emit("gltfpack", r, len(gtri), dt, gerr)
                gp.append((r, len(gtri), gerr))
            if gp:
                # ours at gltfpack's triangle counts: each output mesh at gltfpack's ratios,
                # no error budget (a cell compares equal counts)
                ratios = (1.0, *[max(g / m_build, 1e-9) for _, g, _ in gp])
                for variant, extra in variants.items():
                    # the build's measurement (a bound) only matters to "ours" and
                    # "ours-one-ratio" (they pick among chained and direct candidates by
                    # measurement); the other variants make the same levels without it, and
                    # are timed without it
                    opts = LodOptions(ratios=ratios, min_triangles=1, max_error=None,
                                      error_samples=min(args.samples, DEFAULT_LOD_OPTIONS.error_samples),
                                      measure=variant in ("ours", "ours-one-ratio", "ours-in-place") or args.measure_variants, **extra)
                    t = time.perf_counter()
                    lm = build_model_lods(build, opts)
                    dt = time.perf_counter() - t
                    upos, levels = union_levels(lm, len(ratios))
                    errs = [Hd(dense.rel(upos, lv)) for lv in levels[1:]]
                    for k, ((r, g, gerr), lv, oerr) in enumerate(zip(gp, levels[1:], errs), start=1):
                        emit(variant, r, len(lv), dt, oerr)
                        compare.append(dict(mesh=name, variant=variant, ratio=r, meshes=len(build),
                                            output_meshes=len(lm), gltfpack_triangles=g,
                                            our_triangles=len(lv), gltfpack_hausdorff_pct=100 * gerr.hausdorff_rel,
                                            our_hausdorff_pct=100 * oerr.hausdorff_rel,
                                            gltfpack_rms_pct=100 * gerr.rms_rel, our_rms_pct=100 * oerr.rms_rel,
                                            chain_seconds=dt))
        if args.no_recorded:
            continue
        # the build's own chains (default options): recorded error against a dense measurement
        t = time.perf_counter()
        built = build_model_lods(build, LodOptions())
        t_chain = time.perf_counter() - t
        t = time.perf_counter()
        build_model_lods(build, LodOptions(measure=False))
        t_simplify = time.perf_counter() - t
        for j, m in enumerate(built):
            if len(m.levels) < 2:
                continue
            mpos = m.vertices[:, :3].astype(np.float64)
            mdense = Sampled(mpos, m.levels[0].indices, args.samples, seed=12345)
            for lv in m.levels[1:]:
                d = mdense.rel(mpos, lv.indices)
                recorded.append(dict(mesh=name, output_mesh=j, level=lv.level, triangles=lv.triangles,
                                     copy=m.copy_of is not None,
                                     recorded_pct=100 * lv.hausdorff_rel, dense_pct=100 * d,
                                     ratio=lv.hausdorff_rel / d if d > 0 else math.nan))
        upos, levels = union_levels(built)
        errs = measure_against(bref, [(upos, lv) for lv in levels[1:]])
        chains.append(dict(mesh=name, meshes=len(build), output_meshes=len(built),
                           distinct=sum(m.copy_of is None for m in built), input_triangles=m_build,
                           seconds=t_chain, seconds_without_measuring=t_simplify,
                           levels=" ".join(str(len(lv)) for lv in levels),
                           hausdorff_pct=" ".join(f"{100 * e.hausdorff_rel:.4f}" for e in [ZERO, *errs])))
        print(f"{name[:24]:24} chain ({len(build)} meshes -> {len(built)}, "
              f"{chains[-1]['distinct']} distinct) {chains[-1]['levels']}  Hausdorff% "
              f"{chains[-1]['hausdorff_pct']}  {t_chain:.2f} s ({m_build / t_chain / 1e6:.2f} M input tri/s; "
              f"{m_build / t_simplify / 1e6:.2f} M/s without measuring)", flush=True)

    _write_csv(args.out / "lod.csv", rows)
    _write_csv(args.out / "lod-chains.csv", chains)
    if compare:
        _write_csv(args.out / "lod-vs-gltfpack.csv", compare)
    _plot(rows, args.out / "lod-pareto.png")
    shutil.rmtree(tmp, ignore_errors=True)

    print()
    print("median over meshes and ratios (time per input triangle, Hausdorff and RMS % of diagonal):")
    for kind in (*SIMPLIFIERS, "gltfpack", *variants):
        sel = [r for r in rows if r["simplifier"] == kind]
        if sel:
            print(f"  {kind:20} {np.median([1e9 * r['seconds'] / r['input_triangles'] for r in sel]):8.1f} ns/tri"
                  f"  haus {np.median([r['hausdorff_pct'] for r in sel]):7.4f}%"
                  f"  rms {np.median([r['rms_pct'] for r in sel]):8.5f}%")
    if compare:
        print()
        print("TABLE 1: Hausdorff at equal triangle count, ours / gltfpack (-si R -se 1 -sv -noq), "
              f"{args.samples} samples per side")
        variants = list(variants)
        cells = sorted({(c["mesh"], c["ratio"]) for c in compare})
        by = {(c["mesh"], c["ratio"], c["variant"]): c for c in compare}
        print(f"  {'mesh':28} {'ratio':>6} {'gp tris':>8} {'gp haus%':>9} " +
              " ".join(f"{v:>14}" for v in variants))
        for mesh, r in cells:
            c0 = by[(mesh, r, variants[0])]
            print(f"  {mesh[:28]:28} 1/{round(1 / r):<4} {c0['gltfpack_triangles']:8d} "
                  f"{c0['gltfpack_hausdorff_pct']:9.4f} " + " ".join(
                      f"{by[(mesh, r, v)]['our_hausdorff_pct'] / max(c0['gltfpack_hausdorff_pct'], 1e-12):8.2f}x"
                      f"{'*' if by[(mesh, r, v)]['our_triangles'] > 1.05 * c0['gltfpack_triangles'] else ' '}     "
                      for v in variants))
        print("  (* our count > 1.05x gltfpack's)")
        for v in variants:
            sel = [c for c in compare if c["variant"] == v]
            ok = sum(c["our_hausdorff_pct"] <= 1.1 * c["gltfpack_hausdorff_pct"] + 1e-9 for c in sel)
            print(f"  {v:14} within 1.1x gltfpack: {ok}/{len(sel)} cells = {100 * ok / len(sel):.0f}% "
                  f"(goal >= 90%); median ratio "
                  f"{np.median([c['our_hausdorff_pct'] / max(c['gltfpack_hausdorff_pct'], 1e-12) for c in sel]):.2f}")
    if recorded:
        print()
        print(f"TABLE 2: recorded Hausdorff of every level (the build's chains) against a dense "
              f"{args.samples}-sample measurement (other seed)")
        print(f"  {'mesh':28} {'out':>4} {'lvl':>3} {'tris':>8} {'recorded%':>10} {'dense%':>10} {'rec/dense':>9}")
        for r in recorded:
            print(f"  {r['mesh'][:28]:28} {r['output_mesh']:4d} {r['level']:3d} {r['triangles']:8d} "
                  f"{r['recorded_pct']:10.4f} {r['dense_pct']:10.4f} {r['ratio']:9.3f}"
                  f"{'  copy' if r['copy'] else ''}")
        # a ratio says nothing where the level loses nothing: there the dense value is rounding
        # (1e-16..1e-14 of the diagonal) and the bound stops at its absolute tolerance or at
        # float32's resolution; those levels are reported by their bound instead
        lossy = [r for r in recorded if math.isfinite(r["ratio"]) and r["dense_pct"] >= 100 * LOSSLESS]
        lossless = [r for r in recorded if r["dense_pct"] < 100 * LOSSLESS]
        ratios_ = np.array([r["ratio"] for r in lossy])
        if ratios_.size:
            print(f"  recorded/dense: min {ratios_.min():.3f}, median {np.median(ratios_):.3f}, "
                  f"max {ratios_.max():.3f}; below the dense value: {int((ratios_ < 1).sum())}/{ratios_.size}")
        if lossless:
            print(f"  {len(lossless)} lossless levels (dense value under {LOSSLESS:g} of the diagonal): recorded "
                  f"bound at most {max(r['recorded_pct'] for r in lossless) / 100:.3g} of the diagonal; below the "
                  f"dense value: {sum(r['recorded_pct'] < r['dense_pct'] for r in lossless)}")
        _write_csv(args.out / "lod-recorded.csv", recorded)
    if not compare:
        print("gltfpack not run (not on PATH or --no-gltfpack): no comparison")
    if not chains:
        return 0
    total_in = sum(c["input_triangles"] for c in chains)
    total_t = sum(c["seconds"] for c in chains)
    total_s = sum(c["seconds_without_measuring"] for c in chains)
    print(f"whole-chain throughput over {len(chains)} models ({sum(c['meshes'] for c in chains)} meshes): {total_in / total_t / 1e6:.2f} M input "
          f"triangles/s with error measurement, {total_in / total_s / 1e6:.2f} M/s simplification "
          f"only (goal >= 1 M/s)")
    for c in chains:
        if c["input_triangles"] >= 500_000:
            print(f"  {c['mesh']}: {c['input_triangles'] / c['seconds'] / 1e6:.2f} M/s with measurement, "
                  f"{c['input_triangles'] / c['seconds_without_measuring'] / 1e6:.2f} M/s without")
    print(f"results: {args.out}/lod.csv, lod-chains.csv, lod-pareto.png")
    return 0


def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _plot(rows: list[dict], path: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        _plot_pillow(rows, path)
        return
    fig, ax = plt.subplots(figsize=(8, 5.5))
    kinds = sorted({r["simplifier"] for r in rows})
    for kind in kinds:
        sel = [r for r in rows if r["simplifier"] == kind]
        x = np.array([1e9 * r["seconds"] / r["input_triangles"] for r in sel])
        y = np.array([max(r["hausdorff_pct"], 1e-5) for r in sel])
        pts = ax.scatter(x, y, s=10, alpha=0.35)
        ax.scatter([np.median(x)], [np.median(y)], s=120, marker="*", color=pts.get_facecolor()[0],
                   edgecolor="black", label=f"{kind} (median)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per input triangle (ns)  [gltfpack: whole process]")
    ax.set_ylabel("measured Hausdorff distance (% of bbox diagonal)")
    ax.set_title("LOD simplifiers: time vs error (all meshes, ratios 1/2..1/16)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_pillow(rows: list[dict], path: Path) -> None:
    """The same Pareto plot (log time per input triangle vs log Hausdorff) drawn with Pillow,
    for machines without matplotlib: a dot per cell, a ringed dot per simplifier's median."""
    from PIL import Image, ImageDraw

    pts = [(r["simplifier"], 1e9 * r["seconds"] / r["input_triangles"], max(r["hausdorff_pct"], 1e-5))
           for r in rows if r["seconds"] > 0 and math.isfinite(r["hausdorff_pct"])]
    if not pts:
        return
    W, H, L, B = 900, 620, 70, 50
    lx = np.log10([p[1] for p in pts])
    ly = np.log10([p[2] for p in pts])
    x0, x1 = math.floor(lx.min()), math.ceil(lx.max()) + (lx.max() == lx.min())
    y0, y1 = math.floor(ly.min()), math.ceil(ly.max()) + (ly.max() == ly.min())
    img = Image.new("RGB", (W, H), "white")
    d = ImageDraw.Draw(img)
    sx = lambda v: L + (v - x0) / (x1 - x0) * (W - L - 220)  # noqa: E731
    sy = lambda v: H - B - (v - y0) / (y1 - y0) * (H - B - 30)  # noqa: E731
    for e in range(x0, x1 + 1):
        d.line([(sx(e), 30), (sx(e), H - B)], fill=(225, 225, 225))
        d.text((sx(e) - 12, H - B + 6), f"1e{e}", fill="black")
    for e in range(y0, y1 + 1):
        d.line([(L, sy(e)), (W - 220, sy(e))], fill=(225, 225, 225))
        d.text((8, sy(e) - 6), f"1e{e}%", fill="black")
    d.text((L, H - 22), "time per input triangle (ns, log)  [gltfpack: whole process; ours: whole chain]", fill="black")
    d.text((L, 8), "LOD simplifiers: time vs measured Hausdorff (% of diagonal, log)", fill="black")
    palette = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
               (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]
    kinds = sorted({p[0] for p in pts})
    for n, kind in enumerate(kinds):
        col = palette[n % len(palette)]
        sel = [(math.log10(p[1]), math.log10(p[2])) for p in pts if p[0] == kind]
        for x, y in sel:
            d.ellipse([sx(x) - 2, sy(y) - 2, sx(x) + 2, sy(y) + 2], fill=col)
        mx, my = np.median([p[0] for p in sel]), np.median([p[1] for p in sel])
        d.ellipse([sx(mx) - 7, sy(my) - 7, sx(mx) + 7, sy(my) + 7], fill=col, outline="black", width=2)
        d.rectangle([W - 205, 40 + 18 * n, W - 195, 50 + 18 * n], fill=col)
        d.text((W - 188, 38 + 18 * n), f"{kind} (median: ringed)", fill="black")
    img.save(path)


if __name__ == "__main__":
    raise SystemExit(main())
