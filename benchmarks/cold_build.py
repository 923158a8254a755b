"""Cold build of the shared corpus against gltfpack, side by side in one run.

Run:  .venv/bin/python benchmarks/cold_build.py [--rounds 2] [--jobs 2] [--quick]

Ours: ``python -m assetpipe.cli build CORPUS -o OUT --cache CACHE -j JOBS`` into fresh folders
(cold: nothing cached), with the default options (LOD chains with error measurement on,
textures, everything the build does). gltfpack: ``gltfpack -i FILE -o OUT.glb -si 0.5`` for
every model file the build finds (assetpipe.inputs.discover_inputs), run JOBS at a time (one
process per file). The two alternate for ``--rounds`` rounds so that machine load hits both
alike; the ratio of the totals and each round's ratio are printed. gltfpack does less (one
level, no textures processed, no measurement), which is why the goal is a ratio, not parity:
<= 2x (stretch 1x). Each round also prints both sides' CPU time (user + system of every
process, the build's workers included: both keep the cores busy, so it shows where a speed-up
has to come from, and a loaded machine moves it less than the wall time). Our builds run with
bytecode caching on, the project's modules compiled before the first round (as an installed
tool runs; an inherited PYTHONDONTWRITEBYTECODE=1 is dropped for them).
``--quick``: one round. ``--also ARGS`` (repeatable): one more build of ours a round with these
extra build options (e.g. ``--also=--no-lod-move --also=--no-lod``), each timed and compared with
the same round's gltfpack run: where the time goes, in the same run. ``--cad``: the generated
CAD-style models of ``benchmarks/cad_models.py`` (an assembly of 62 parts, a piping plant of 15
bent tubes) instead of the corpus: models the corpus does not hold, few files with large
meshes, where gltfpack's start-up per file weighs little.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

_SHARED = REPO.parent / "shared" / "corpus"
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", _SHARED if _SHARED.is_dir() else "/work/shared/corpus")) / "models"


def find_gltfpack() -> str | None:
    """gltfpack on PATH, else the one npm installed beside a venv (this checkout's or main's)."""
    found = shutil.which("gltfpack")
    for venv in (REPO / ".venv", Path("/work/main/.venv")):
        exe = venv / "node" / "node_modules" / ".bin" / "gltfpack"
        if found is None and exe.exists():
            found = str(exe)
    return found


def _env() -> dict[str, str]:
    """Our builds' environment: the checkout on the path, bytecode caching on (the project's
    modules compiled once by :func:`compile_ours`; the installed packages have theirs). An
    installed tool runs from .pyc files; an inherited PYTHONDONTWRITEBYTECODE=1 (set in some of
    our shells) would make every build compile the project's modules from source (about 0.2 s of
    CPU, in the build process and again in the workers for the modules they import), which
    gltfpack, a compiled program, never pays. (A private PYTHONPYCACHEPREFIX is no use here: every
    installed package would then be compiled from source in the first build, 2.2 s of CPU.)"""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env.pop("PYTHONPYCACHEPREFIX", None)
    return env


def compile_ours() -> None:
    """The project's bytecode (its __pycache__ folders, as a first run writes them)."""
    dirs = [str(REPO / d) for d in ("assetpipe", "pipelines", "cache", "renderer") if (REPO / d).is_dir()]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *dirs], env=_env(), check=True,
                   capture_output=True)


def _children_cpu() -> float:
    """CPU seconds (user + system) of every child process waited for so far (a build's workers
    count: the build waits for them)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_ours(corpus: Path, jobs: int, tmp: Path, extra: tuple[str, ...] = ()) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the build and its workers)."""
    out, cache = tmp / "out", tmp / "cache"
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(cache, ignore_errors=True)
    env = _env()
    c = _children_cpu()
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "assetpipe.cli", "build", str(corpus), "-o", str(out),
                        "--cache", str(cache), "-j", str(jobs), "-q", *extra], env=env, capture_output=True,
                       text=True)
    dt = time.perf_counter() - t
    cpu = _children_cpu() - c
    if r.returncode not in (0, 1):  # 1: some asset failed (the corpus has none), still timed
        raise SystemExit(f"assetpipe build failed ({r.returncode}): {r.stderr[-2000:]}")
    return dt, cpu


def run_gltfpack(exe: str, files: list[Path], jobs: int, tmp: Path) -> tuple[float, int, float]:
    """(wall seconds, files converted, CPU seconds of the gltfpack processes)."""
    out = tmp / "gp"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)

    def one(i_f):
        i, f = i_f
        r = subprocess.run([exe, "-i", str(f), "-o", str(out / f"{i}.glb"), "-si", "0.5"],
                           capture_output=True, text=True)
        return r.returncode == 0

    c = _children_cpu()
    t = time.perf_counter()
    with ThreadPoolExecutor(max_workers=jobs) as ex:
        ok = sum(ex.map(one, enumerate(files)))
    return time.perf_counter() - t, ok, _children_cpu() - c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="one round")
    ap.add_argument("--corpus", type=Path, default=CORPUS)
    ap.add_argument("--cad", action="store_true", help="the generated CAD-style models instead of the corpus")
    ap.add_argument("--also", action="append", default=[], metavar="ARGS",
                    help="extra build options of one more variant of ours (repeatable)")
    args = ap.parse_args()
    variants = [tuple(v.split()) for v in args.also]
    from assetpipe.inputs import discover_inputs

    exe = find_gltfpack()
    if exe is None:
        print("gltfpack not found: nothing to compare with")
        return 1
    tmp = Path(tempfile.mkdtemp(prefix="coldbuild-"))
    if args.cad:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from cad_models import write_cad_models  # noqa: PLC0415 - beside this file

        args.corpus = tmp / "cad"
        write_cad_models(args.corpus)
    files = discover_inputs([args.corpus])
    compile_ours()
    ours, theirs, ours_cpu, theirs_cpu = [], [], [], []
    more: list[list[float]] = [[] for _ in variants]
    try:
        for k in range(1 if args.quick else args.rounds):
            a, a_cpu = run_ours(args.corpus, args.jobs, tmp)
            extra = [run_ours(args.corpus, args.jobs, tmp, v)[0] for v in variants]
            b, ok, b_cpu = run_gltfpack(exe, files, args.jobs, tmp)
            ours.append(a)
            theirs.append(b)
            ours_cpu.append(a_cpu)
            theirs_cpu.append(b_cpu)
            for times, t in zip(more, extra):
                times.append(t)
            print(f"round {k + 1}: assetpipe build -j {args.jobs}: {a:.2f} s; gltfpack -si 0.5, "
                  f"{args.jobs} at a time: {b:.2f} s ({ok}/{len(files)} files ok); ratio {a / b:.2f}x"
                  f" (CPU {a_cpu:.1f} s against {b_cpu:.1f} s)"
                  + "".join(f"; with {' '.join(v)}: {t:.2f} s, {t / b:.2f}x" for v, t in zip(variants, extra)),
                  flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ratios = sorted(a / b for a, b in zip(ours, theirs))
    print(f"cold build of {len(files)} files over {len(ours)} round(s): ours {sum(ours):.2f} s, "
          f"gltfpack {sum(theirs):.2f} s in total: {sum(ours) / sum(theirs):.2f}x; per-round ratios "
          f"{', '.join(f'{r:.2f}' for r in ratios)} (goal <= 2x, stretch <= 1x)")
    print(f"CPU time (user + system, every process): ours {sum(ours_cpu):.1f} s, gltfpack "
          f"{sum(theirs_cpu):.1f} s: {sum(ours_cpu) / sum(theirs_cpu):.2f}x")
    for v, times in zip(variants, more):
        print(f"  ours with {' '.join(v)}: {sum(times):.2f} s in total: {sum(times) / sum(theirs):.2f}x of "
              f"gltfpack's time, {sum(times) / sum(ours):.2f}x of the default build's")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
