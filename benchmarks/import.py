"""Import throughput of our importers against the raw read of the same files, with trimesh as a peer.

    .venv/bin/python benchmarks/import.py [--quick] [--repeats 7] [--only NAME,...]

For every model file of the corpus (``$ASSETPIPE_CORPUS/models``, default
``../shared/corpus/models``; .gltf, .glb, .obj) three things are timed in this one process,
interleaved (each repeat runs every file, and within a file the three contenders in rotating
order), and the median of the repeats is reported:

* ours:    ``assetpipe.model_import.import_model(path)`` (pipelines/import_gltf.py, import_obj.py)
* raw:     reading every byte of the same file set with ``open(...).read()``: the model file plus
           every file our import read (``ImportedModel.dependencies``: .bin, .mtl, images), page
           cache warm (a warm-up pass reads everything first)
* trimesh: ``trimesh.load(path, force='scene')`` (default arguments, so ``process=True``), where
           it loads the file; otherwise "n/a" and the file is left out of the trimesh total

A single sample repeats its call enough times to last at least ``--min-sample`` seconds (tiny
files take microseconds) and is divided back to one call. Figures are ratios measured in this
run; absolute times vary from run to run on a shared machine.

Columns: MB = bytes of the file set (MB = 1e6 bytes); tris = triangles our importer returned
(instances flattened, so 2CylinderEngine and CesiumMilkTruck count more than trimesh's scene
geometry); MB/s and Mtri/s of our import; ours/raw and ours/trimesh time ratios. Totals use the
sums of the per-file medians (the trimesh ratio over the files trimesh loaded).

Our importer reads images to digest them (it does not decode them); trimesh's glTF loader
opens images with Pillow lazily. Neither does mesh processing beyond what load() does.
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
SUFFIXES = (".gltf", ".glb", ".obj")


def corpus_files(only: set[str] | None) -> list[Path]:
    files = sorted(p for p in CORPUS.rglob("*") if p.is_file() and p.suffix.lower() in SUFFIXES)
    if only:
        files = [p for p in files if p.relative_to(CORPUS).parts[0] in only or p.stem in only]
    return files


def read_all(paths: list[Path]) -> int:
    n = 0
    for p in paths:
        with open(p, "rb") as f:
            n += len(f.read())
    return n


def calls_for(seconds: float, min_sample: float) -> int:
    return max(1, min(1000, math.ceil(min_sample / max(seconds, 1e-7))))


def timed(fn, calls: int) -> float:
    """Seconds per call of ``fn`` over ``calls`` calls."""
    gc.collect()
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls


def short(name: str, width: int = 58) -> str:
    """The tail of a long relative path (the file name is what tells files apart)."""
    return name if len(name) <= width else "..." + name[-(width - 3):]


def fmt_ratio(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.1f}x" if x >= 10 else f"{x:.2f}x"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 repeats, 2 ms samples")
    ap.add_argument("--repeats", type=int, default=None, help="repeats per contender (default 7, quick 3)")
    ap.add_argument("--min-sample", type=float, default=None,
                    help="minimum seconds per timed sample (default 0.01, quick 0.002)")
    ap.add_argument("--only", help="comma-separated corpus folder names or file stems")
    ap.add_argument("--no-trimesh", action="store_true")
    args = ap.parse_args()
    repeats = args.repeats or (3 if args.quick else 7)
    min_sample = args.min_sample or (0.002 if args.quick else 0.01)

    from assetpipe.model_import import import_model

    trimesh = None
    if not args.no_trimesh:
        try:
            import trimesh  # noqa: F811
        except ImportError:
            print("trimesh not installed: peer column left out")

    files = corpus_files(set(args.only.split(",")) if args.only else None)
    if not files:
        print(f"no model files under {CORPUS}")
        return 1

    # -- warm-up: import once (dependencies, triangles, errors), read everything, try trimesh
    rows = []
    for path in files:
        row = {"path": path, "name": str(path.relative_to(CORPUS)), "error": None, "tm_error": None}
        try:
            t0 = time.perf_counter()
            model = import_model(path)
            row["t_ours"] = time.perf_counter() - t0
        except Exception as exc:  # an AssetError is a result too: report it, time nothing
            row["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0][:80]}"
            rows.append(row)
            continue
        deps = list(dict.fromkeys(Path(d).resolve() for d in model.dependencies))
        fileset = [path.resolve()] + [d for d in deps if d != path.resolve()]
        row["fileset"] = fileset
        row["bytes"] = sum(p.stat().st_size for p in fileset)
        row["tris"] = sum(m.triangle_count for m in model.meshes)
        row["deps"] = len(fileset) - 1
        t0 = time.perf_counter()
        read_all(fileset)
        row["t_raw"] = time.perf_counter() - t0
        if trimesh is not None:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t0 = time.perf_counter()
                    trimesh.load(str(path), force="scene")
                    row["t_tm"] = time.perf_counter() - t0
            except Exception as exc:
                row["tm_error"] = f"{type(exc).__name__}: {str(exc)[:60]}"
        rows.append(row)
    live = [r for r in rows if r["error"] is None]

    # second warm-up call to size the samples (the first call paid for module imports)
    contenders = {}
    for r in live:
        path, fileset = r["path"], r["fileset"]
        fns = {"ours": (lambda p=path: import_model(p)), "raw": (lambda fs=fileset: read_all(fs))}
        if trimesh is not None and r["tm_error"] is None:
            def tm(p=str(path)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    trimesh.load(p, force="scene")
            fns["trimesh"] = tm
        contenders[r["name"]] = {k: (fn, calls_for(timed(fn, 1), min_sample)) for k, fn in fns.items()}
        r["samples"] = {k: [] for k in fns}

    # -- the measurement: repeats x files x contenders (rotating order within a file)
    for rep in range(repeats):
        for i, r in enumerate(live):
            names = list(contenders[r["name"]])
            shift = (rep + i) % len(names)
            for k in names[shift:] + names[:shift]:
                fn, calls = contenders[r["name"]][k]
                r["samples"][k].append(timed(fn, calls))

    # -- report
    print(f"Import throughput: {len(files)} model files under {CORPUS}, {repeats} repeats, "
          f"median per file (samples >= {min_sample * 1000:g} ms)")
    hdr = (f"{'file':58s} {'deps':>4s} {'MB':>7s} {'tris':>9s} {'ours ms':>9s} {'raw ms':>8s} {'tm ms':>8s} "
           f"{'MB/s':>7s} {'Mtri/s':>7s} {'ours/raw':>9s} {'ours/tm':>8s}")
    print(hdr)
    print("-" * len(hdr))
    tot = {"bytes": 0, "tris": 0, "ours": 0.0, "raw": 0.0, "ours_tm": 0.0, "tm": 0.0, "n_tm": 0}
    for r in rows:
        if r["error"]:
            print(f"{short(r['name']):58s} import failed: {r['error']}")
            continue
        med = {k: statistics.median(v) for k, v in r["samples"].items()}
        tm = med.get("trimesh")
        tot["bytes"] += r["bytes"]
        tot["tris"] += r["tris"]
        tot["ours"] += med["ours"]
        tot["raw"] += med["raw"]
        if tm is not None:
            tot["ours_tm"] += med["ours"]
            tot["tm"] += tm
            tot["n_tm"] += 1
        print(f"{short(r['name']):58s} {r['deps']:4d} {r['bytes'] / 1e6:7.3f} {r['tris']:9d} {med['ours'] * 1e3:9.3f} "
              f"{med['raw'] * 1e3:8.3f} {(f'{tm * 1e3:8.3f}' if tm is not None else 'n/a'):>8s} "
              f"{r['bytes'] / 1e6 / med['ours']:7.1f} {r['tris'] / 1e6 / med['ours']:7.2f} "
              f"{fmt_ratio(med['ours'] / med['raw']):>9s} {fmt_ratio(med['ours'] / tm if tm else None):>8s}"
              + (f"  (trimesh: {r['tm_error']})" if r["tm_error"] else ""))
    print("-" * len(hdr))
    print(f"{'TOTAL (' + str(len(live)) + ' files imported)':58s} {'':4s} {tot['bytes'] / 1e6:7.3f} {tot['tris']:9d} "
          f"{tot['ours'] * 1e3:9.3f} {tot['raw'] * 1e3:8.3f} {tot['tm'] * 1e3:8.3f} "
          f"{tot['bytes'] / 1e6 / tot['ours']:7.1f} {tot['tris'] / 1e6 / tot['ours']:7.2f} "
          f"{fmt_ratio(tot['ours'] / tot['raw']):>9s} "
          f"{fmt_ratio(tot['ours_tm'] / tot['tm'] if tot['tm'] else None):>8s}")
    print()
    print(f"ours: {tot['bytes'] / 1e6 / tot['ours']:.1f} MB/s, {tot['tris'] / 1e6 / tot['ours']:.2f} M triangles/s; "
          f"raw read: {tot['bytes'] / 1e6 / tot['raw']:.0f} MB/s")
    print(f"ours / raw read time: {tot['ours'] / tot['raw']:.1f}x (all {len(live)} files)")
    if tot["tm"]:
        print(f"ours / trimesh time:  {tot['ours_tm'] / tot['tm']:.2f}x (the {tot['n_tm']} files trimesh loaded; "
              f"ours {tot['ours_tm'] * 1e3:.1f} ms vs trimesh {tot['tm'] * 1e3:.1f} ms)")
    failed = [r for r in rows if r["error"]]
    if failed:
        print(f"{len(failed)} file(s) failed to import and are left out of the totals")
    return 0


if __name__ == "__main__":
    sys.exit(main())
