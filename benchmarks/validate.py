"""Per-model validation time over built models, all checks on, split set-up/load/upload/render/compare.

Usage::

    .venv/bin/python benchmarks/validate.py                 # build the corpus models, then validate
    .venv/bin/python benchmarks/validate.py OUT_DIR ...     # validate already built models
    .venv/bin/python benchmarks/validate.py --fixtures      # the renderer's hand-made fixtures only
    .venv/bin/python benchmarks/validate.py -j 2 OUT_DIR    # two renderer processes in parallel
    .venv/bin/python benchmarks/validate.py --mutations OUT_DIR   # catch rate of every mutation kind
    .venv/bin/python benchmarks/validate.py --against /tmp/old OUT_DIR  # side by side with another tree

Models are built once with ``assetpipe build`` into a temporary directory (models that fail
to build are listed and left out). Validation runs in ``-j`` renderer subprocesses (device
set-up once each, before its first model, printed on its own line), 256x256, validation layer and
every check on.
Prints per-model time, its average and maximum, and the wall time. Goal: 1 s per model on
average, 2 s at most. ``--mutations`` applies every mutation of ``tests/validate_mutations.py``
to every model it applies to (plus the generated assets of ``tests/validate_assets.py``) and
prints the catch rate per kind, and the false alarms on the unmutated models. ``--against TREE``
(a checkout of another commit, e.g. ``git archive BASE | tar -x -C /tmp/old``) validates each
model with that tree's renderer worker and with this one's, one after the other (who goes first
alternates from model to model), both warm, in one run,
and prints both times and their ratio per model (times under shared load are comparable only
side by side).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

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
    ap.add_argument("-j", "--jobs", type=int, default=1, help="renderer processes in parallel")
    ap.add_argument("--mutations", action="store_true", help="catch rate of every mutation kind")
    ap.add_argument("--against", metavar="TREE", help="another checkout's renderer, side by side")
    args = ap.parse_args()
    if args.mutations:
        return mutations(args)
    if args.against:
        return against(args)
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
        stats: dict = {}
        results = validate_batch(models, opts, jobs=args.jobs, stats=stats)
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
    totals = [sum(r.timings.values()) for r in results]
    worst = max(range(len(results)), key=lambda i: totals[i]) if results else 0
    print(f"{len(results)} models, -j {args.jobs}: per-model time average {sum(totals) / n:.3f} s (goal 1 s), "
          f"maximum {max(totals, default=0):.3f} s ({Path(results[worst].model).name if results else '-'}; "
          f"goal 2 s); wall time {wall:.2f} s ({wall / n:.3f} s per model); {sum(r.passed for r in results)} passed")
    print("device set-up per renderer process (once, before its first model; in no model's time): "
          + ", ".join(f"{x:.3f} s" for x in stats.get("setup", [])))
    try:
        print(f"load average (1, 5, 15 min) at the end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    except OSError:
        pass
    for f in failed_builds:
        print(f"  not built: {f}")
    return 0


def against(args: argparse.Namespace) -> int:
    """Each model by ``args.against``'s renderer worker and by ours, alternately, in one run."""
    from assetpipe.renderer._vk import renderer_env  # noqa: PLC0415
    from assetpipe.renderer.worker import WorkerPool  # noqa: PLC0415

    class TreePool(WorkerPool):
        """A renderer worker running another tree's code."""

        def __init__(self, options: ValidateOptions, root: str) -> None:
            super().__init__(options)
            self.root = root

        def _start(self) -> None:
            if self._stderr is not None:
                self._stderr.close()
            self._stderr = tempfile.TemporaryFile()
            env = renderer_env()
            env["PYTHONPATH"] = self.root
            # -P: no working directory on sys.path, so PYTHONPATH decides whose code runs (without it,
            # a run from inside a checkout validated with that checkout's code on both sides)
            self.proc = subprocess.Popen([sys.executable, "-P", "-m", "assetpipe.renderer.worker"], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=self._stderr, env=env, cwd=os.getcwd())
            self._buf = b""
            self._ready = False

    def cpu(pool: WorkerPool) -> float:
        """CPU seconds the worker process has used (all its threads: lavapipe's too), from /proc:
        far less sensitive to other users' load than wall time."""
        try:
            f = Path(f"/proc/{pool.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, AttributeError, IndexError, ValueError):
            return float("nan")

    def timed(pool: WorkerPool, m: Path):  # noqa: ANN202
        m = Path(m).resolve()
        c0 = cpu(pool)
        r = pool.validate(m)
        return r, cpu(pool) - c0

    opts = ValidateOptions(width=args.size, height=args.size, source_root=str(CORPUS))
    models = find_built_models(args.paths)
    other, ours = TreePool(opts, str(Path(args.against).resolve())), TreePool(opts, str(REPO))
    print(f"set-up: {args.against} {other.warm() or 0:.3f} s, this tree {ours.warm() or 0:.3f} s (in no model's time)")
    rows = []
    try:
        for i, m in enumerate(models):  # who goes first alternates: the second reads warm file caches
            if i % 2:
                rn, cn = timed(ours, m)
                ro, co = timed(other, m)
            else:
                ro, co = timed(other, m)
                rn, cn = timed(ours, m)
            to, tn = (sum(v for k, v in r.timings.items() if k != "setup") for r in (ro, rn))
            rows.append((Path(m).name, to, tn, ro.passed, rn.passed, co, cn))
            print(f"{Path(m).name[:34]:<34} wall: other {to:7.3f} s  this {tn:7.3f} s  ratio {tn / max(to, 1e-9):5.2f}"
                  f"  cpu: other {co:6.2f} s  this {cn:6.2f} s  "
                  f"{'pass' if ro.passed else 'FAIL'}/{'pass' if rn.passed else 'FAIL'}", flush=True)
    finally:
        other.close()
        ours.close()
    n = max(len(rows), 1)
    for label, i in (("other", 1), ("this", 2)):
        ts = [r[i] for r in rows]
        worst = max(rows, key=lambda r: r[i])[0] if rows else "-"
        cs = [r[i + 4] for r in rows]
        print(f"{label}: per-model average {sum(ts) / n:.3f} s, maximum {max(ts, default=0):.3f} s ({worst}); "
              f"over 2 s: {sum(t > 2 for t in ts)}, over 1 s: {sum(t > 1 for t in ts)}; passed "
              f"{sum(r[i + 2] for r in rows)} of {len(rows)}; CPU time: total {sum(cs):.2f} s, "
              f"maximum {max(cs, default=0):.2f} s ({max(rows, key=lambda r: r[i + 4])[0] if rows else '-'})")
    print(f"load average (1, 5, 15 min) at the end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


def copy_model(model_json: Path, dest: Path) -> Path:
    """Copy one built model (its files, the textures it names, the build's state that records its
    source) into ``dest``; returns the copy's ID.json."""
    import json  # noqa: PLC0415
    import shutil  # noqa: PLC0415

    src = model_json.parent
    stem = model_json.name[: -len(".json")]
    (dest / ".assetpipe").mkdir(parents=True)
    shutil.copy2(src / ".assetpipe" / "state.json", dest / ".assetpipe" / "state.json")
    seed = json.loads(model_json.read_text())
    side = json.loads((src / f"{stem}.asset.json").read_text())
    names = {model_json.name, f"{stem}.asset.json", f"{stem}-mat.json", seed["idxFilename"], seed["vtxFilename"]}
    for mat in side.get("materials", []):
        for tex in (mat.get("textures") or {}).values():
            names |= {tex[k] for k in ("path", "ktx2") if tex.get(k)}
    for name in names:
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src / name, dest / name)
    return dest / model_json.name


def rendered_change(original: Path, mutated: Path, opts: ValidateOptions) -> dict:
    """What a mutation changes in what the model renders: the unmutated and the mutated build drawn
    by one renderer (this process), every LOD, every view of the validation at its size, shaded and
    facing, and every texel of every mip level of every texture the renderer samples. ``identity``
    is True only when no rendered pixel channel differs by more than 1 code (the 8-bit target's
    rounding) and the largest texel difference, mip levels included, is below the roles check's
    tolerance: the mutation then did not change the asset in anything a viewer can see, and the
    suite does not count it (per case, from these figures)."""
    import numpy as np  # noqa: PLC0415

    from assetpipe.core.errors import AssetpipeError  # noqa: PLC0415
    from assetpipe.renderer.camera import fit_camera  # noqa: PLC0415
    from assetpipe.renderer.loader import load_built_model  # noqa: PLC0415
    from assetpipe.renderer.session import shared_renderer  # noqa: PLC0415

    try:
        a, b = load_built_model(original), load_built_model(mutated)
    except AssetpipeError as exc:
        return {"identity": False, "summary": f"the mutated build does not load ({str(exc)[:80]})"}
    if a.lod_count != b.lod_count or len(a.materials) != len(b.materials):
        return {"identity": False, "summary": "LOD or material counts differ"}
    texel = 0.0
    roles = ("texture", "normal_texture", "metallic_roughness_texture", "occlusion_texture", "emissive_texture")
    for ma, mb in zip(a.materials, b.materials):
        for attr in roles:
            ta, tb = getattr(ma, attr), getattr(mb, attr)
            if (ta is None) != (tb is None) or (ta is not None and len(ta.levels) != len(tb.levels)):
                return {"identity": False, "summary": f"{attr} differs in presence or levels"}
            if ta is not None:
                for la, lb in zip(ta.levels, tb.levels):
                    if la.shape != lb.shape:
                        return {"identity": False, "summary": f"{attr} level shapes differ"}
                    texel = max(texel, float(np.abs(la.astype(np.int16) - lb.astype(np.int16)).mean()) / 255)
    renderer = shared_renderer(opts.width, opts.height, validation=False)
    ga, gb = renderer.upload(a), renderer.upload(b)
    worst_px, worst_block = 0, 0.0
    try:
        for view in opts.views:
            cam = fit_camera(a.center, a.radius, view, opts.width, opts.height)
            for lod in range(a.lod_count):
                for mode in ("shaded", "facing"):
                    ia = renderer.render(ga, cam, mode=mode, lod=lod)
                    ib = renderer.render(gb, cam, mode=mode, lod=lod)
                    worst_px = max(worst_px, int(np.abs(ia.astype(np.int16) - ib.astype(np.int16)).max()))
                    from assetpipe.renderer.compare import block_color_difference  # noqa: PLC0415

                    worst_block = max(worst_block, block_color_difference(ia, ib)[0])
    finally:
        renderer.release(ga)
        renderer.release(gb)
    identity = worst_px <= 1 and texel < opts.role_tolerance
    return {"identity": identity, "summary": f"largest rendered pixel difference {worst_px} codes, block colour "
                                            f"difference {worst_block:.4f}, largest mean texel difference of a "
                                            f"mip level {texel:.4f} (identity: <= 1 code and < "
                                            f"{opts.role_tolerance:.4f})"}


def _triangles(model: Path) -> int:
    side = json.loads(model.with_name(model.name[:-5] + ".asset.json").read_text())
    return int(side.get("stats", {}).get("triangles", 0))


def mutations(args: argparse.Namespace) -> int:
    """Apply every mutation to every model it applies to; print the catch rate per kind."""
    import shutil  # noqa: PLC0415

    from validate_assets import write_assets  # noqa: PLC0415
    from validate_mutations import MUTATIONS, NotApplicable, caught, caught_by  # noqa: PLC0415

    with tempfile.TemporaryDirectory(prefix="assetpipe-mut-") as tmp:
        tmp_p = Path(tmp)
        write_assets(tmp_p / "gen")
        exe = Path(sys.executable).with_name("assetpipe")
        subprocess.run([str(exe), "build", str(tmp_p / "gen"), "-o", str(tmp_p / "genout"), "--cache",
                        str(tmp_p / "cache"), "-q"], check=True)
        models = find_built_models([str(tmp_p / "genout")] + list(args.paths))
        opts = ValidateOptions(width=args.size, height=args.size, source_root=str(CORPUS))
        clean = validate_batch(models, opts, jobs=args.jobs)
        false_alarms = [f for r in clean for f in r.failures()]
        # a model without triangles (points and lines only) has no geometry to mutate
        good = [Path(r.model) for r in clean if r.passed and _triangles(Path(r.model))]
        jobs: list[tuple[str, Path]] = []
        sources: list[Path] = []
        for kind, (mutate, _, _) in MUTATIONS.items():
            for i, m in enumerate(good):
                dest = tmp_p / "mut" / f"{len(jobs)}"
                target = copy_model(m, dest)
                try:
                    mutate(target)
                except NotApplicable:
                    shutil.rmtree(dest)
                    continue
                jobs.append((kind, target))
                sources.append(m)
        results = validate_batch([t for _, t in jobs], opts, jobs=args.jobs)
        print(f"{'mutation kind':<38} {'models':>6} {'caught':>6} {'rate':>6}  caught by (check: models)")
        total = hit = identities = 0
        originals = dict(zip((str(t) for _, t in jobs), (src for src in sources)))
        for kind, (_, checks, phrase) in MUTATIONS.items():
            rs = [(t, r) for (k, t), r in zip(jobs, results) if k == kind]
            got = [caught(r, checks, phrase) for _, r in rs]
            by = {c: sum(c in caught_by(r, checks, phrase) for _, r in rs) for c in checks}
            n_hit = sum(ok for ok, _ in got)
            misses = []
            for (ok, line), (t, r) in zip(got, rs):
                if ok:
                    continue
                same = rendered_change(Path(originals[str(t)]), t, opts)
                misses.append((r.id, line, same))
            n_ident = sum(1 for _, _, same in misses if same["identity"])
            total, hit, identities = total + len(rs) - n_ident, hit + n_hit, identities + n_ident
            print(f"{kind:<38} {len(rs) - n_ident:>6} {n_hit:>6} {n_hit / max(len(rs) - n_ident, 1):>6.0%}  "
                  + ", ".join(f"{c}: {n}" for c, n in by.items()))
            for mid, line, same in misses:
                print(f"    {'IDENTITY' if same['identity'] else 'MISSED'} on {mid}: {line or 'passed'}; "
                      f"against the unmutated build: {same['summary']}")
        print(f"all kinds: {hit} of {total} caught; {identities} identity mutations not counted (each shown by "
              f"its figures above); false alarms on the {len(clean)} unmutated models: {len(false_alarms)}")
        for f in false_alarms:
            print(f"    false alarm: {f[:200]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
