"""Per-model validation time over built models, all checks on, split set-up/load/upload/render/compare.

Usage::

    .venv/bin/python benchmarks/validate.py                 # build the corpus models, then validate
    .venv/bin/python benchmarks/validate.py OUT_DIR ...     # validate already built models
    .venv/bin/python benchmarks/validate.py --fixtures      # the renderer's hand-made fixtures only

Models are built once with ``assetpipe build`` into a temporary directory (models that fail
to build are listed and left out). Validation runs in one renderer subprocess (device set-up
once, charged to the first model), 256x256, validation layer and every check on. Goal: 1 s
per model on average.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from assetpipe.renderer.cli_commands import find_built_models  # noqa: E402
from assetpipe.renderer.batch import validate_batch  # noqa: E402
from assetpipe.renderer.validate import ValidateOptions  # noqa: E402

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"


def build_corpus(out: Path) -> tuple[list[Path], list[str]]:
    """Build every corpus model into ``out``; (built ID.json files, failures)."""
    exe = Path(sys.executable).with_name("assetpipe")
    built, failed = [], []
    for src in sorted(p for p in CORPUS.iterdir() if p.is_dir() and not p.name.startswith(".")):
        dest = out / src.name
        proc = subprocess.run([str(exe), "build", str(src), "-o", str(dest), "--cache", str(out / ".cache"), "-q"],
                              capture_output=True, text=True, timeout=900)
        models = find_built_models([str(dest)]) if dest.is_dir() else []
        if proc.returncode != 0 or not models:
            last = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            failed.append(f"{src.name}: {last[0][:150]}")
        built += models
    return built, failed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", help="built models or output directories")
    ap.add_argument("--fixtures", action="store_true", help="validate tests/data/built only")
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args()
    failed_builds: list[str] = []
    with tempfile.TemporaryDirectory(prefix="assetpipe-bench-") as tmp:
        if args.fixtures:
            models = find_built_models([str(REPO / "tests" / "data" / "built")])
        elif args.paths:
            models = find_built_models(args.paths)
        else:
            t0 = time.perf_counter()
            models, failed_builds = build_corpus(Path(tmp))
            print(f"built {len(models)} models in {time.perf_counter() - t0:.1f} s "
                  f"({len(failed_builds)} corpus entries failed to build)")
            if not models:
                models = find_built_models([str(REPO / "tests" / "data" / "built")])
                print("falling back to the fixtures")
        opts = ValidateOptions(width=args.size, height=args.size, source_root=str(CORPUS))
        t0 = time.perf_counter()
        results = validate_batch(models, opts)
        wall = time.perf_counter() - t0

    cols = ("setup", "load", "upload", "render", "compare")
    head = f"{'model':<34} {'tris':>9} " + " ".join(f"{c:>8}" for c in cols) + f" {'total':>8}  result"
    print(head)
    print("-" * len(head))
    sums = dict.fromkeys(cols, 0.0)
    for r in results:
        load = r.check("load")
        tris = load.figures.get("triangles", 0) if load else 0
        t = [r.timings.get(c, 0.0) for c in cols]
        for c, v in zip(cols, t):
            sums[c] += v
        status = "pass" if r.passed else "FAIL " + ",".join(c.name for c in r.checks if not c.passed)
        if r.error:
            status = "ERROR " + r.error[:60]
        skipped = [c.name for c in r.checks if c.status == "skip"]
        if skipped:
            status += f" (skipped {','.join(skipped)})"
        print(f"{Path(r.model).name[:34]:<34} {tris:>9,} " + " ".join(f"{v:8.3f}" for v in t)
              + f" {sum(t):8.3f}  {status}")
    n = max(len(results), 1)
    print("-" * len(head))
    print(f"{'mean per model':<34} {'':>9} " + " ".join(f"{sums[c] / n:8.3f}" for c in cols)
          + f" {sum(sums.values()) / n:8.3f}")
    print(f"{len(results)} models, wall time {wall:.2f} s ({wall / n:.3f} s per model, goal 1 s); "
          f"{sum(r.passed for r in results)} passed")
    for f in failed_builds:
        print(f"  not built: {f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
