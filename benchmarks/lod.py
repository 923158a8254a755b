"""LOD benchmark: simplifiers x ratios on the corpus and a generated 1M-triangle mesh.

Run:  .venv/bin/python benchmarks/lod.py            (everything, a few minutes)
      .venv/bin/python benchmarks/lod.py --quick    (4 small meshes, no 1M mesh)
      .venv/bin/python benchmarks/lod.py --only Duck,stanford-bunny --no-big

Simplifier table: for every file (loaded with trimesh and merged into one mesh, node
transforms applied) and every simplifier (meshopt, meshopt-attr, meshopt+lock_border, sloppy,
fast-simplification) and ratio (1/2, 1/4, 1/8, 1/16), the mesh is simplified *directly from
level 0* in the same local frame and with the same welding as :func:`build_lod_chain`; the
simplifier call alone is timed, and the result's two-sided Hausdorff and RMS distance to level 0
is measured with :mod:`pipelines.surface_error`.

Comparison with gltfpack (found on PATH, else in .venv/node/node_modules/.bin): the same ratios
go through ``gltfpack -si R -se 1 -noq`` (its time includes process start-up and file I/O), and
its whole output is measured against the whole model. Ours is made *the way the build makes
it* (assetpipe/steps.py task_lod): the file is imported and processed per mesh (one mesh per
glTF primitive / OBJ material group, default mesh options), each mesh gets its own
:func:`build_lod_chain` with default options, and level k of the model is the union of the
meshes' level k, measured against the same whole-model reference. For equal triangle counts,
each mesh's chain uses gltfpack's overall ratios (its output count / input count) and
``min_triangles=1`` (the build's default 32 floors each of spider's 19 small meshes, which no
longer compares equal counts); the counts of both are printed.

Printed at the end, from this one run:
* the share of (mesh, ratio) cells where our Hausdorff distance is <= gltfpack's at equal
  triangle count, and the cells where our count exceeds gltfpack's by more than 5%;
* whole-chain throughput (per build mesh, ``build_lod_chain`` with default options) in input
  triangles per second, with and without error measurement.

Writes benchmarks/results/lod.csv, lod-chains.csv, lod-vs-gltfpack.csv and lod-pareto.png
(needs matplotlib).
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
from assetpipe.pipelines.surface_error import (  # noqa: E402
    ZERO_ERROR as ZERO, measure_against, measure_levels, prepare_reference)

GLTFPACK_LOCAL = REPO / ".venv" / "node" / "node_modules" / ".bin" / "gltfpack"
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
RESULTS = REPO / "benchmarks" / "results"
RATIOS = (1 / 2, 1 / 4, 1 / 8, 1 / 16)
SIMPLIFIERS = ("meshopt", "meshopt-attr", "meshopt+lock_border", "sloppy", "fast-simplification")
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
    if found is None and GLTFPACK_LOCAL.exists():
        found = str(GLTFPACK_LOCAL)
    return found


def load_build_meshes(path: Path):
    """The file as the build's LOD step sees it: one (positions f64, indices u32, uv f32|None)
    per mesh, after import and mesh processing with the default options (assetpipe.steps)."""
    from assetpipe.model_import import import_model
    from assetpipe.pipelines.mesh_options import ATTRIBUTE_COMPONENTS, DEFAULT_MESH_OPTIONS
    from assetpipe.pipelines.mesh_process import process_mesh

    layout = DEFAULT_MESH_OPTIONS.layout
    cols, c = {}, 0
    for a in layout:
        cols[a] = slice(c, c + ATTRIBUTE_COMPONENTS[a])
        c += ATTRIBUTE_COMPONENTS[a]
    out = []
    for mesh in import_model(path).meshes:
        pm = process_mesh(mesh, DEFAULT_MESH_OPTIONS)
        if pm.indices.shape[0] == 0:
            continue
        v = pm.vertices
        uv = v[:, cols["uv0"]] if "uv0" in cols and mesh.uv0 is not None else None
        normals = v[:, cols["normal"]] if "normal" in cols else None
        out.append((v[:, :3], pm.indices, uv, normals))
    return out


def union_levels(build, per_mesh):
    """(all positions, level k of every mesh concatenated, for each k).

    per_mesh: for each mesh of ``build``, its levels' (K, 3) index arrays, finest first. A mesh
    whose chain stopped early contributes its coarsest level to the deeper levels."""
    pos, offsets, off = [], [], 0
    for p, *_ in build:
        pos.append(p), offsets.append(off)
        off += len(p)
    depth = max(len(lv) for lv in per_mesh)
    levels = [np.concatenate([lv[min(k, len(lv) - 1)].astype(np.int64) + o
                              for lv, o in zip(per_mesh, offsets)]) for k in range(depth)]
    return np.concatenate(pos), levels


def gltfpack_run(exe: str, src: Path, ratio: float, tmp: Path):
    import trimesh

    out = tmp / f"gp-{ratio:.4f}.glb"
    t = time.perf_counter()
    r = subprocess.run([exe, "-i", str(src), "-o", str(out), "-si", f"{ratio}", "-se", "1",
                        "-noq"], capture_output=True, text=True)
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
    ap.add_argument("--no-gltfpack", action="store_true")
    ap.add_argument("--samples", type=int, default=DEFAULT_LOD_OPTIONS.error_samples)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()

    only = set(args.only.split(",")) if args.only else None
    if args.quick and only is None:
        only = {"Duck", "fuze", "spider", "stanford-bunny"}
    gltfpack = None if args.no_gltfpack else find_gltfpack()
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="lodbench-"))

    meshes = []
    for name, path in corpus_files(only):
        m = load_merged(path)
        if m is None or len(m[1]) < MIN_TRIANGLES:
            continue
        meshes.append((name, path, m))
    if not (args.quick or args.no_big):
        import trimesh

        big = displaced_torus()
        big_path = tmp / "torus-1M.glb"
        trimesh.Trimesh(big[0], big[1], process=False).export(str(big_path))
        meshes.append(("torus-1M (generated)", big_path, big))

    rows, chains, compare = [], [], []
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
        ref = prepare_reference(pos, tri, samples=args.samples)

        def emit(kind, ratio, out_tri, seconds, err):
            row = dict(mesh=name, simplifier=kind, ratio=ratio, input_triangles=m0,
                       triangles=int(out_tri), seconds=seconds,
                       mtris_per_s=m0 / seconds / 1e6 if seconds > 0 else math.nan,
                       hausdorff_pct=100 * err.hausdorff_rel, rms_pct=100 * err.rms_rel)
            rows.append(row)
            print(f"{name[:24]:24} {kind:20} {ratio:6.4f} {row['triangles']:8d} {1e3 * seconds:9.1f} "
                  f"{row['mtris_per_s']:7.2f} {row['hausdorff_pct']:8.4f} {row['rms_pct']:8.5f}",
                  flush=True)

        for kind in SIMPLIFIERS:
            outs, times = [], []
            for r in RATIOS:
                target = max(1, int(round(r * m0)))
                t = time.perf_counter()
                out = run_simplifier(kind, pos32, welded, target, uv, normals)
                times.append(time.perf_counter() - t)
                outs.append(out)
            for r, out, dt, err in zip(RATIOS, outs, times, measure_levels(ref, outs)):
                emit(kind, r, len(out), dt, err)
        # --- as the build does it: one chain per mesh
        build = load_build_meshes(path)
        bpos = np.concatenate([b[0] for b in build])
        bref = prepare_reference(bpos, union_levels(build, [[b[1]] for b in build])[1][0],
                                 samples=args.samples)
        if gltfpack:
            gp = []
            for r in RATIOS:
                res = gltfpack_run(gltfpack, path, r, tmp)
                if res is None:
                    print(f"{name[:24]:24} gltfpack failed at {r}")
                    continue
                gpos, gtri, dt = res
                gerr = measure_against(bref, [(gpos, gtri)])[0]
                emit("gltfpack", r, len(gtri), dt, gerr)
                gp.append((r, len(gtri), gerr))
            if gp:
                # ours at gltfpack's triangle counts: every mesh's chain at gltfpack's ratios
                ratios = (1.0, *[max(g / m0, 1e-9) for _, g, _ in gp])
                opts = LodOptions(ratios=ratios, min_triangles=1, error_samples=args.samples)
                chains_eq = [build_lod_chain(p, i, uv=u, normals=nn, options=opts) for p, i, u, nn in build]
                _, levels = union_levels(build, [[x.indices for x in ch.levels] for ch in chains_eq])
                errs = measure_levels(bref, levels[1:])
                for k, ((r, g, gerr), lv, oerr) in enumerate(zip(gp, levels[1:], errs), start=1):
                    compare.append(dict(mesh=name, ratio=r, meshes=len(build), gltfpack_triangles=g,
                                        our_triangles=len(lv), gltfpack_hausdorff_pct=100 * gerr.hausdorff_rel,
                                        our_hausdorff_pct=100 * oerr.hausdorff_rel,
                                        gltfpack_rms_pct=100 * gerr.rms_rel, our_rms_pct=100 * oerr.rms_rel,
                                        our_sloppy_meshes=sum(any(x.sloppy for x in ch.levels[:k + 1])
                                                              for ch in chains_eq)))
        # the whole chain per mesh, default options: with and without measurement
        t_chain = t_simplify = 0.0
        built = []
        for p, i, u, nn in build:
            t = time.perf_counter()
            built.append(build_lod_chain(p, i, uv=u, normals=nn, options=LodOptions(error_samples=args.samples)))
            t_chain += time.perf_counter() - t
            t = time.perf_counter()
            build_lod_chain(p, i, uv=u, normals=nn, options=LodOptions(error_samples=args.samples, measure=False))
            t_simplify += time.perf_counter() - t
        _, levels = union_levels(build, [[x.indices for x in ch.levels] for ch in built])
        errs = measure_levels(bref, levels[1:])
        m_build = sum(len(b[1]) for b in build)
        chains.append(dict(mesh=name, meshes=len(build), input_triangles=m_build, seconds=t_chain,
                           seconds_without_measuring=t_simplify,
                           levels=" ".join(str(len(lv)) for lv in levels),
                           hausdorff_pct=" ".join(f"{100 * e.hausdorff_rel:.4f}" for e in [ZERO, *errs]),
                           sloppy_meshes=sum(any(x.sloppy for x in ch.levels) for ch in built)))
        print(f"{name[:24]:24} chain ({len(build)} meshes) {chains[-1]['levels']}  Hausdorff% "
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
    for kind in (*SIMPLIFIERS, "gltfpack"):
        sel = [r for r in rows if r["simplifier"] == kind]
        if sel:
            print(f"  {kind:20} {np.median([1e9 * r['seconds'] / r['input_triangles'] for r in sel]):8.1f} ns/tri"
                  f"  haus {np.median([r['hausdorff_pct'] for r in sel]):7.4f}%"
                  f"  rms {np.median([r['rms_pct'] for r in sel]):8.5f}%")
    if compare:
        wins = sum(c["our_hausdorff_pct"] <= c["gltfpack_hausdorff_pct"] + 1e-9 for c in compare)
        print(f"our Hausdorff <= gltfpack's at equal triangle count: {wins}/{len(compare)} cells "
              f"= {100 * wins / len(compare):.0f}% (goal >= 90%; ours per mesh, as the build)")
        over = [c for c in compare if c["our_triangles"] > 1.05 * c["gltfpack_triangles"]]
        print(f"cells where our count exceeds gltfpack's by > 5%: {len(over)}")
        for c in over:
            print(f"  count: {c['mesh']} 1/{round(1 / c['ratio'])}: ours {c['our_triangles']} vs "
                  f"gltfpack {c['gltfpack_triangles']}")
        for c in compare:
            if c["our_hausdorff_pct"] > c["gltfpack_hausdorff_pct"] + 1e-9:
                print(f"  worse: {c['mesh']} 1/{round(1 / c['ratio'])}: ours {c['our_hausdorff_pct']:.4f}% "
                      f"({c['our_triangles']} tris) vs gltfpack {c['gltfpack_hausdorff_pct']:.4f}% "
                      f"({c['gltfpack_triangles']} tris)")
    else:
        print("gltfpack not run (not on PATH or --no-gltfpack): no comparison")
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
        print("matplotlib not installed: no plot (pip install matplotlib)")
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


if __name__ == "__main__":
    raise SystemExit(main())
