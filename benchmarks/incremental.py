"""Incremental build benchmark: no-op rebuild, one-texture rebuild, hashing share, 10,000 assets.

    .venv/bin/python benchmarks/incremental.py [--quick] [--repeats 7] [--scale 10000] [--keep]

Everything runs under a private temporary directory (source copies, out dirs, caches); the
corpus (``$ASSETPIPE_CORPUS/models``, default ``../shared/corpus/models``) is only read. Builds
are subprocesses of the real CLI (``.venv/bin/assetpipe build ... -o OUT --cache CACHE -q``),
except the cold build of part 3, which runs ``run_build`` in this process to instrument it.
Every compared pair is interleaved in one run and reported as a ratio of medians.

1. Cold corpus build, hashing share (issue 3). ``run_build`` on the whole corpus with the
   default options (LODs on; ``--quick``: ``--no-lod``) and ``jobs=1``, in this process, with
   timing wrappers on ``assetpipe.core.hashing.digest_file`` / ``digest_bytes`` (at every module
   that imported them by name: hashing, state, stat_cache, store, image_source) and on
   ``cache.stat_cache.StatCache.digest`` (a wrapper inside a wrapper counts once). Hashing
   time here includes reading the file for ``digest_file`` and the stat calls of the stat
   cache: it is what hashing costs the build. Also shown: bytes hashed vs distinct bytes
   (content hashed more than once) and bytes x the xxh3-128 rate measured in this run (the
   pure hashing floor). Goal: hashing < 5% of the cold build wall time.
2. No-op rebuild of the corpus (same out dir and cache as 1, same options, so nothing is
   stale): wall time of the CLI process including interpreter start-up, as a ratio to
   ``.venv/bin/python -c pass``, interleaved, median of ``--repeats`` each. Goal <= 3x. One
   extra no-op run under ``-X importtime`` lists the heavy modules it imports and the import
   chain that pulled each in; numpy, PIL, cv2, pygltflib, trimesh, vulkan must be absent.
3. One texture touched. A textured corpus model (``--touch-model``, default Duck/glTF) is
   copied to a temporary source tree and built (default options). Then, per repeat, one more
   pixel of its texture is changed (a real content change, never seen before: repeat i
   changes pixel i, in the image's own mode; the file is re-saved by Pillow) and the CLI
   rebuilds it. The baseline is the cold cost of that texture's steps alone: a fresh process
   of the same interpreter that imports ``assetpipe.steps`` and runs ``task_texture`` for
   every (role, alpha mode) job of that image (the arguments the build's graph would pass,
   taken from the model's import record) into an empty store. Both include interpreter
   start-up and the imports the work needs, so the ratio is the rebuild's overhead over the
   unavoidable work. Interleaved; goal <= 1.2x. One more rebuild with ``--explain`` checks
   that only the texture and encode steps ran.
4. Scale. ``--scale`` (default 10,000) tiny OBJ files (a 12-triangle box, every corner moved
   by a random offset, so each is distinct; no materials, no textures; 100 per folder) under
   the temp dir: a cold build with ``-j 2 --no-lod`` (wall time, per-asset cost, peak RSS),
   then no-op rebuilds (median wall time over ``--repeats``, goal < 1 s; peak RSS). Peak RSS
   is reported two ways: the largest single process (``wait4`` rusage, which covers the
   reaped worker processes too) and the sampled sum over the process tree (every 50 ms).

Every figure is printed with its goal and PASS/FAIL in one table at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
PY = str(Path(sys.executable))
CLI = str(Path(sys.executable).with_name("assetpipe"))
HEAVY = ("numpy", "PIL", "cv2", "pygltflib", "trimesh", "vulkan")


# -- running processes ----------------------------------------------------------------------

def _tree_rss_kb(pid: int) -> int:
    """Sum of VmRSS over ``pid`` and its descendants (0 once gone)."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1])
                        break
            with open(f"/proc/{p}/task/{p}/children") as f:
                stack.extend(int(c) for c in f.read().split())
        except (OSError, ValueError):
            pass
    return total


TIME = "/usr/bin/time"


#: Environment of every subprocess: bytecode caching on, into a private prefix (set in main).
#: An installed tool runs from .pyc files; an inherited PYTHONDONTWRITEBYTECODE=1 would make
#: every CLI start-up compile the project's modules from source (tens of ms) while a bare
#: ``python -c pass`` compiles nothing, which would skew every start-up ratio.
ENV = dict(os.environ)
INHERITED_NO_PYC = os.environ.get("PYTHONDONTWRITEBYTECODE", "") != ""


def run(cmd: list[str], *, rss: bool = False, timeout: float | None = None, cwd=None, env=None) -> dict:
    """Run ``cmd``: wall seconds, exit code, output; with ``rss``, peak RSS in KB of its largest
    single process (GNU time's %M: the process and its reaped children, e.g. pool workers) and
    the sampled peak of the whole process tree's total RSS (every 50 ms). Untimed runs only
    should ask for ``rss`` (the wrapper and the sampler cost a little)."""
    out = tempfile.TemporaryFile()
    err = tempfile.TemporaryFile()
    rss_file = None
    if rss and os.access(TIME, os.X_OK):
        fd, rss_file = tempfile.mkstemp(prefix="assetpipe-bench-rss-")
        os.close(fd)
        cmd = [TIME, "-f", "%M", "-o", rss_file, *cmd]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=out, stderr=err, cwd=cwd, env=env or ENV)
    peak_tree = [0]
    stop = threading.Event()

    def sampler():
        while not stop.wait(0.05):
            peak_tree[0] = max(peak_tree[0], _tree_rss_kb(proc.pid))

    th = threading.Thread(target=sampler, daemon=True) if rss else None
    if th:
        th.start()
    try:
        proc.wait(timeout=timeout)
        timed_out = False
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        timed_out = True
    wall = time.perf_counter() - t0
    if th:
        stop.set()
        th.join()
    maxrss = None
    if rss_file:
        try:
            maxrss = int(Path(rss_file).read_text().split()[-1])
        except (OSError, ValueError, IndexError):
            pass
        os.unlink(rss_file)
    out.seek(0)
    err.seek(0)
    return {"wall": wall, "rc": proc.returncode, "stdout": out.read().decode(errors="replace"),
            "stderr": err.read().decode(errors="replace"), "maxrss_kb": maxrss,
            "tree_kb": peak_tree[0], "timed_out": timed_out}


def mb(kb) -> str:
    return "n/a" if not kb else f"{kb / 1024:.0f} MB"


def build_cmd(src, out, cache, *extra) -> list[str]:
    return [CLI, "build", str(src), "-o", str(out), "--cache", str(cache), "-q", *extra]


def check_ok(r: dict, what: str) -> None:
    if r["rc"] != 0:
        tail = (r["stderr"] or r["stdout"]).strip().splitlines()[-3:]
        raise SystemExit(f"{what} failed (exit {r['rc']}): " + " | ".join(tail))


def summary_counts(stdout: str) -> dict[str, int]:
    """{'built': n, 'cached': n, ...} from the CLI's summary line."""
    line = next((l for l in stdout.splitlines() if l.startswith("assetpipe:")), "")
    counts = {}
    for part in line.split(" in ")[0].removeprefix("assetpipe:").split(","):
        words = part.split()
        if len(words) >= 2 and words[0].isdigit():
            counts[words[1]] = int(words[0])
    return counts


def interleave(fns: dict, repeats: int) -> dict[str, list]:
    """Call each of ``fns`` ``repeats`` times, rotating the order every round."""
    names = list(fns)
    res = {k: [] for k in names}
    for i in range(repeats):
        order = names[i % len(names):] + names[:i % len(names)]
        for k in order:
            res[k].append(fns[k]())
    return res


# -- 1. hashing share of a cold build --------------------------------------------------------

class HashMeter:
    """Timing wrappers around the digest functions; nested wrapped calls count once.

    Bytes are attributed to the innermost context among: Store.put_blob (naming a blob),
    Store.get_blob (verifying a blob on read), StatCache.digest (source files), or the digest
    function's module (state: outputs; steps/hashing: import deps, digest_json, task_texture;
    image_source: images read by the importers)."""

    def __init__(self):
        self.depth = 0
        self.seconds = 0.0
        self.calls: dict[str, int] = {}
        self.bytes: dict[str, int] = {}
        self.distinct: dict[str, int] = {}  # digest -> size: content actually distinct
        self.context: list[str] = []
        self.stat_hits = 0
        self._undo = []

    def _timed(self, fn, context=None, size_of=None, label=None):
        meter = self

        def wrapper(*args, **kwargs):
            meter.depth += 1
            if context:
                meter.context.append(context)
            t0 = time.perf_counter()
            try:
                result = fn(*args, **kwargs)
            finally:
                dt = time.perf_counter() - t0
                meter.depth -= 1
                if context:
                    meter.context.pop()
            if meter.depth == 0 and (size_of is not None or context == "StatCache.digest"):
                meter.seconds += dt
            if size_of is not None:
                n = size_of(*args)
                key = f"{label}[{meter.context[-1] if meter.context else 'other'}]"
                meter.calls[key] = meter.calls.get(key, 0) + 1
                meter.bytes[key] = meter.bytes.get(key, 0) + n
                meter.distinct[result] = n
            return result
        wrapper.__wrapped__ = fn
        return wrapper

    def _set(self, owner, name, value):
        self._undo.append((owner, name, getattr(owner, name)))
        setattr(owner, name, value)

    def install(self):
        import assetpipe.core.hashing as hashing
        import assetpipe.state as state
        import assetpipe.cache.stat_cache as stat_cache
        import assetpipe.cache.store as store
        import assetpipe.pipelines.image_source as image_source

        raw_file, raw_bytes = hashing.digest_file, hashing.digest_bytes
        size_file = lambda p, *a: os.path.getsize(p)  # noqa: E731
        size_bytes = lambda d, *a: len(d)  # noqa: E731
        for mod in (hashing, state, stat_cache):
            tag = mod.__name__.split(".")[-1]
            self._set(mod, "digest_file", self._timed(raw_file, None, size_file, f"digest_file@{tag}"))
        for mod in (hashing, store, image_source):
            tag = mod.__name__.split(".")[-1]
            self._set(mod, "digest_bytes", self._timed(raw_bytes, None, size_bytes, f"digest_bytes@{tag}"))
        # digest_json calls digest_bytes through the hashing module's global: wrapped above
        for name in ("put_blob", "get_blob"):
            self._set(store.Store, name, self._passthrough(getattr(store.Store, name), f"Store.{name}"))
        raw_stat = stat_cache.StatCache.digest
        timed_stat = self._timed(raw_stat, "StatCache.digest")
        meter = self

        def stat_digest(sc, path):
            before = sc.hashed
            r = timed_stat(sc, path)
            if sc.hashed == before:
                meter.stat_hits += 1
            return r
        self._set(stat_cache.StatCache, "digest", stat_digest)

    def _passthrough(self, fn, context):
        """Sets the attribution context; its own time is not hashing (I/O, mkdir, rename)."""
        meter = self

        def wrapper(*args, **kwargs):
            meter.context.append(context)
            try:
                return fn(*args, **kwargs)
            finally:
                meter.context.pop()
        return wrapper

    def uninstall(self):
        for owner, name, orig in reversed(self._undo):
            setattr(owner, name, orig)
        self._undo.clear()


def xxh3_rate() -> float:
    """Bytes per second of xxh3-128 over a 64 MiB in-memory buffer (best of 5)."""
    import xxhash

    buf = os.urandom(1 << 26)
    best = min(_timeit(lambda: xxhash.xxh3_128_hexdigest(buf)) for _ in range(5))
    return len(buf) / best


def _timeit(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def cold_build_hashing(out: Path, cache: Path, no_lod: bool) -> dict:
    import dataclasses

    from assetpipe.build import run_build
    from assetpipe.options import DEFAULT_BUILD_OPTIONS

    options = dataclasses.replace(DEFAULT_BUILD_OPTIONS, lod=None) if no_lod else DEFAULT_BUILD_OPTIONS
    meter = HashMeter()
    meter.install()
    try:
        t0 = time.perf_counter()
        report = run_build([CORPUS], out, options, jobs=1, cache_dir=cache)
        wall = time.perf_counter() - t0
    finally:
        meter.uninstall()
    return {"wall": wall, "meter": meter, "counts": report.counts(), "rate": xxh3_rate()}


# -- 2. no-op rebuild of the corpus -----------------------------------------------------------

def import_chains(stderr: str) -> dict[str, tuple[int, str]]:
    """For each heavy top-level module in a ``-X importtime`` log: (cumulative us, chain that
    imported it first, e.g. 'numpy <- pipelines.lod <- assetpipe.options <- assetpipe.cli')."""
    rows = []
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cum, name = line[len("import time:"):].split("|", 2)
        if not cum.strip().isdigit():
            continue
        indent = len(name) - len(name.lstrip())
        rows.append((int(cum), indent, name.strip()))
    found = {}
    for i, (cum, indent, name) in enumerate(rows):
        top = name.split(".")[0]
        if top in HEAVY and top not in found and name == top:
            chain, level = [name], indent
            for cum2, ind2, name2 in rows[i + 1:]:  # children print before their parent
                if ind2 < level:
                    chain.append(name2)
                    level = ind2
            found[top] = (cum, " <- ".join(chain))
    return found


NOOP_PARTS = r"""
import json, subprocess, sys, time
t0 = time.perf_counter()
import assetpipe.cli
t1 = time.perf_counter()
from assetpipe import versions
versions.library_versions()
t2 = time.perf_counter()
np = subprocess.run([sys.executable, "-c", "import time; t=time.perf_counter(); import numpy; "
                     "print(time.perf_counter() - t)"], capture_output=True, text=True).stdout
print(json.dumps({"cli": t1 - t0, "libs": t2 - t1, "numpy": float(np)}))
"""


# -- 3. one texture touched -------------------------------------------------------------------

BASELINE = r"""
import json, sys
args = json.loads(sys.argv[1])
from assetpipe.steps import task_texture
for job in args["jobs"]:
    task_texture(args["store"], *job)
"""


def change_pixel(path: Path, i: int) -> None:
    """Change pixel number ``i`` (row-major) of the image to a value it never had."""
    from PIL import Image

    im = Image.open(path)
    im.load()
    fmt = im.format
    x, y = i % im.width, (i // im.width) % im.height
    v = im.getpixel((x, y))
    if im.mode == "P":
        pal = im.getpalette()
        n = len(pal) // 3
        rgb = pal[3 * v:3 * v + 3]
        new = next((j for j in range(1, n) if pal[3 * ((v + j) % n):3 * ((v + j) % n) + 3] != rgb), None)
        if new is None:
            raise SystemExit(f"{path}: palette has a single colour; choose another --touch-model")
        im.putpixel((x, y), (v + new) % n)
    elif isinstance(v, tuple):
        im.putpixel((x, y), (v[0] ^ 0x40,) + tuple(v[1:]))
    else:
        im.putpixel((x, y), v ^ 0x40)
    im.save(path, format=fmt, **({"transparency": im.info["transparency"]} if "transparency" in im.info else {}))


def texture_jobs(source: Path, image_rel: str) -> list[list]:
    """The task_texture argument lists the graph would pass for every use of ``image_rel``."""
    from assetpipe.options import DEFAULT_BUILD_OPTIONS
    from assetpipe.steps import options_to_json, task_import

    with tempfile.TemporaryDirectory(prefix="assetpipe-bench-imp-") as tmp:
        rec = task_import(tmp, str(source))
    meta = rec["meta"]
    tex_opts = options_to_json(DEFAULT_BUILD_OPTIONS.texture)
    jobs, seen = [], set()
    for mat in meta["materials"]:
        for role, tex in mat["textures"].items():
            image = meta["images"][tex["image"]]
            if image["path"] != image_rel:
                continue
            alpha = mat["alphaMode"] if role == "baseColor" else "OPAQUE"
            cutoff = mat["alphaCutoff"] if alpha == "MASK" else 0.5
            key = (role, alpha, cutoff)
            if key not in seen:
                seen.add(key)
                jobs.append([dict(image), str(source.parent), role, alpha, cutoff, tex_opts])
    return jobs


def pick_texture(model_dir: Path) -> tuple[Path, str]:
    """(model file, relative path of the image used by the most material slots)."""
    from assetpipe.steps import task_import

    src = next(p for p in sorted(model_dir.iterdir()) if p.suffix.lower() in (".gltf", ".glb", ".obj"))
    with tempfile.TemporaryDirectory(prefix="assetpipe-bench-imp-") as tmp:
        rec = task_import(tmp, str(src))
    uses: dict[str, int] = {}
    for mat in rec["meta"]["materials"]:
        for tex in mat["textures"].values():
            p = rec["meta"]["images"][tex["image"]]["path"]
            if p is not None:
                uses[p] = uses.get(p, 0) + 1
    if not uses:
        raise SystemExit(f"{src}: no texture file; choose another --touch-model")
    return src, max(sorted(uses), key=lambda p: uses[p])


# -- 4. scale ---------------------------------------------------------------------------------

BOX_V = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
BOX_F = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]


def make_tree(root: Path, n: int, seed: int = 7) -> int:
    """``n`` distinct 12-triangle OBJ boxes, 100 per folder; total bytes."""
    rng = random.Random(seed)
    total = 0
    for i in range(n):
        d = root / f"d{i // 100:03d}"
        if i % 100 == 0:
            d.mkdir(parents=True, exist_ok=True)
        lines = [f"# box {i}"]
        lines += ["v %.6f %.6f %.6f" % tuple(c + rng.uniform(-0.1, 0.1) for c in v) for v in BOX_V]
        for a, b, c, e in BOX_F:
            lines += [f"f {a} {b} {c}", f"f {a} {c} {e}"]
        data = ("\n".join(lines) + "\n").encode()
        (d / f"a{i:05d}.obj").write_bytes(data)
        total += len(data)
    return total


# -- main -------------------------------------------------------------------------------------

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="3 repeats, --scale 1000, corpus cold build with --no-lod")
    ap.add_argument("--repeats", type=int, default=None, help="repeats of each timed pair (default 7, quick 3)")
    ap.add_argument("--scale", type=int, default=None, help="number of generated assets (default 10000, quick 1000)")
    ap.add_argument("--scale-timeout", type=float, default=1800.0, help="give up the scale cold build after this")
    ap.add_argument("--touch-model", default="Duck/glTF", help="corpus folder of the textured model to touch")
    ap.add_argument("--skip", default="", help="comma-separated parts to skip: hashing,noop,touch,scale "
                    "(noop needs hashing's build)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary directory")
    args = ap.parse_args()
    repeats = args.repeats or (3 if args.quick else 7)
    scale = args.scale or (1000 if args.quick else 10000)
    corpus_lod = not args.quick
    skip = set(filter(None, args.skip.split(",")))
    if "hashing" in skip:
        skip.add("noop")

    table: list[tuple[str, str, str, str]] = []  # (figure, measured, goal, verdict)

    def row(figure, measured, goal="-", ok=None):
        table.append((figure, measured, goal, "-" if ok is None else "PASS" if ok else "FAIL"))

    tmp = Path(tempfile.mkdtemp(prefix="assetpipe-bench-incr-"))
    ENV.pop("PYTHONDONTWRITEBYTECODE", None)
    ENV["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
    print(f"subprocesses: bytecode cache in {tmp / 'pycache'} (warm-up runs fill it first)"
          + ("; PYTHONDONTWRITEBYTECODE=1 was inherited and is dropped for them" if INHERITED_NO_PYC else ""))
    print(f"temp dir: {tmp}{' (kept)' if args.keep else ''}; corpus: {CORPUS}; repeats: {repeats}")
    try:
        pass_cmd = [PY, "-c", "pass"]
        corpus_out, corpus_cache = tmp / "corpus-out", tmp / "corpus-cache"
        lod_args = [] if corpus_lod else ["--no-lod"]

        # 1 -------------------------------------------------------------------------------
        if "hashing" not in skip:
            print(f"\n[1] cold build of the corpus in-process (run_build, jobs=1, "
                  f"{'default options, LODs on' if corpus_lod else 'no LOD'}), hashing instrumented ...", flush=True)
            h = cold_build_hashing(corpus_out, corpus_cache, no_lod=not corpus_lod)
            m = h["meter"]
            hashed = sum(m.bytes.values())
            distinct = sum(m.distinct.values())
            share = m.seconds / h["wall"]
            floor = hashed / h["rate"]
            print(f"    cold build {h['wall']:.1f} s, counts {h['counts']}")
            for label in sorted(m.calls, key=lambda k: -m.bytes[k]):
                print(f"    {label:45s} {m.calls[label]:7d} calls {m.bytes[label] / 1e6:10.1f} MB")
            print(f"    StatCache.digest hits without reading: {m.stat_hits}")
            print(f"    hashing wall (wrapped calls, outermost only) {m.seconds:.3f} s = {share * 100:.2f}% of the build")
            print(f"    bytes hashed {hashed / 1e6:.1f} MB, distinct content {distinct / 1e6:.1f} MB "
                  f"({hashed / max(distinct, 1):.2f}x); xxh3-128 in memory here {h['rate'] / 1e9:.1f} GB/s "
                  f"-> pure hashing floor {floor * 1e3:.1f} ms = {floor / h['wall'] * 100:.3f}%")
            row(f"cold corpus build: hashing share ({'LODs on' if corpus_lod else 'no LOD'})",
                f"{share * 100:.2f}% ({m.seconds:.2f} s of {h['wall']:.1f} s)", "< 5%", share < 0.05)
            row("cold corpus build: bytes hashed / distinct bytes", f"{hashed / max(distinct, 1):.2f}x "
                f"({hashed / 1e6:.0f} / {distinct / 1e6:.0f} MB)")

        # 2 -------------------------------------------------------------------------------
        if "noop" not in skip:
            print(f"\n[2] no-op rebuild of the corpus vs python -c pass, {repeats} each, interleaved ...", flush=True)
            cmd = build_cmd(CORPUS, corpus_out, corpus_cache, *lod_args)
            first = run(cmd)
            run(pass_cmd)  # warm-up: fills the bytecode cache for both
            check_ok(first, "no-op rebuild")
            counts = summary_counts(first["stdout"])
            print(f"    first no-op: {first['stdout'].strip()}")
            series = {"noop": lambda: run(cmd), "pass": lambda: run(pass_cmd)}
            if INHERITED_NO_PYC:  # what the inherited environment costs, for the record
                env_nopyc = {**ENV, "PYTHONDONTWRITEBYTECODE": "1"}
                env_nopyc.pop("PYTHONPYCACHEPREFIX")
                series["noop_nopyc"] = lambda: run(cmd, env=env_nopyc)
            res = interleave(series, repeats)
            for r in res["noop"]:
                check_ok(r, "no-op rebuild")
            noop = statistics.median(r["wall"] for r in res["noop"])
            bare = statistics.median(r["wall"] for r in res["pass"])
            if "noop_nopyc" in res:
                nopyc = statistics.median(r["wall"] for r in res["noop_nopyc"])
                print(f"    the same no-op with PYTHONDONTWRITEBYTECODE=1 (modules compiled from source at every "
                      f"start): median {nopyc * 1e3:.0f} ms, {nopyc / bare:.2f}x python -c pass")
                row("corpus no-op / python -c pass, no .pyc (inherited env)", f"{nopyc / bare:.2f}x", "(info)")
            rss_noop, rss_pass = run(cmd, rss=True), run(pass_cmd, rss=True)
            print(f"    no-op median {noop * 1e3:.0f} ms, python -c pass median {bare * 1e3:.0f} ms, "
                  f"ratio {noop / bare:.2f}x; peak RSS {mb(rss_noop['maxrss_kb'])} vs {mb(rss_pass['maxrss_kb'])}")
            parts = [json.loads(run([PY, "-c", NOOP_PARTS])["stdout"]) for _ in range(repeats)]
            med = {k: statistics.median(p[k] for p in parts) for k in parts[0]}
            print(f"    where the no-op's time goes (fresh process, median of {repeats}): import assetpipe.cli "
                  f"{med['cli'] * 1e3:.0f} ms (import numpy alone, in its own fresh process: {med['numpy'] * 1e3:.0f} ms), "
                  f"versions.library_versions() {med['libs'] * 1e3:.0f} ms; python -c pass {bare * 1e3:.0f} ms")
            row("corpus no-op: nothing rebuilt", ", ".join(f"{v} {k}" for k, v in counts.items()),
                "0 built", counts.get("built", 0) == 0 and counts.get("failed", 0) == 0)
            row("corpus no-op / python -c pass (wall, incl. start-up)", f"{noop / bare:.2f}x", "<= 3x",
                noop / bare <= 3.0)
            row("corpus no-op: peak RSS (python -c pass)", f"{mb(rss_noop['maxrss_kb'])} ({mb(rss_pass['maxrss_kb'])})")
            it = run([PY, "-X", "importtime", CLI, "build", str(CORPUS), "-o", str(corpus_out), "--cache",
                      str(corpus_cache), "-q", *lod_args])
            check_ok(it, "no-op rebuild under -X importtime")
            chains = import_chains(it["stderr"])
            total_us = sum(int(l.split("|")[1]) for l in it["stderr"].splitlines()
                           if l.startswith("import time:") and l.split("|")[1].strip().isdigit()
                           and not l.split("|")[2].startswith("  "))
            print(f"    imports of the no-op process: {total_us / 1e3:.0f} ms cumulative over top-level imports "
                  f"(under -X importtime, which inflates them)")
            for top in HEAVY:
                if top in chains:
                    print(f"    heavy: {top:9s} {chains[top][0] / 1e3:6.1f} ms  {chains[top][1]}")
            row("corpus no-op: heavy modules imported", ", ".join(
                f"{k} ({chains[k][0] / 1e3:.0f} ms)" for k in HEAVY if k in chains) or "none",
                "none of " + "/".join(HEAVY), not chains)

        # 3 -------------------------------------------------------------------------------
        if "touch" not in skip:
            model_dir = CORPUS / args.touch_model
            src_root = tmp / "touch-src" / args.touch_model.replace("/", "_")
            shutil.copytree(model_dir, src_root)
            source, image_rel = pick_texture(src_root)
            image_path = src_root / image_rel
            out, cache = tmp / "touch-out", tmp / "touch-cache"
            print(f"\n[3] touch one texture: {source.relative_to(tmp)} uses {image_rel} "
                  f"({image_path.stat().st_size} bytes); {repeats} rebuilds vs cold texture step ...", flush=True)
            cmd = build_cmd(source, out, cache)
            check_ok(run(cmd), "initial build of the touched model")
            warm = Path(tempfile.mkdtemp(prefix="store-", dir=tmp))  # warm-up of the baseline's imports
            check_ok(run([PY, "-c", BASELINE, json.dumps({"store": str(warm),
                                                           "jobs": texture_jobs(source, image_rel)})]), "warm-up")
            counter = [0]

            def rebuild():
                counter[0] += 1
                change_pixel(image_path, counter[0])
                r = run(cmd)
                check_ok(r, "rebuild after a texture edit")
                r["counts"] = summary_counts(r["stdout"])
                return r

            def baseline():
                store = Path(tempfile.mkdtemp(prefix="store-", dir=tmp))
                jobs = texture_jobs(source, image_rel)
                r = run([PY, "-c", BASELINE, json.dumps({"store": str(store), "jobs": jobs})])
                check_ok(r, "cold texture step")
                shutil.rmtree(store, ignore_errors=True)
                r["n_jobs"] = len(jobs)
                return r

            res = interleave({"rebuild": rebuild, "baseline": baseline}, repeats)
            reb = statistics.median(r["wall"] for r in res["rebuild"])
            base = statistics.median(r["wall"] for r in res["baseline"])
            rebuilt = all(r["counts"].get("built") == 1 for r in res["rebuild"])
            print(f"    rebuild median {reb * 1e3:.0f} ms (every one rebuilt the model: {rebuilt}); cold texture "
                  f"step process ({res['baseline'][0]['n_jobs']} texture job(s)) median {base * 1e3:.0f} ms; "
                  f"ratio {reb / base:.2f}x")
            counter[0] += 1
            change_pixel(image_path, counter[0])
            ex = run([CLI, "build", str(source), "-o", str(out), "--cache", str(cache), "--explain"])
            check_ok(ex, "rebuild with --explain")
            ran = [l.strip() for l in ex["stdout"].splitlines() if l.startswith("    ")]
            print("    --explain after one more pixel change:")
            for l in ex["stdout"].strip().splitlines():
                print(f"      {l}")
            steps_ran = [l.split(":")[0] for l in ran]
            only = bool(steps_ran) and all(s.startswith("texture") or s == "encode" for s in steps_ran) \
                and any(s.startswith("texture") for s in steps_ran)
            row("touch one texture: rebuild / cold texture step process", f"{reb / base:.2f}x", "<= 1.2x",
                rebuilt and reb / base <= 1.2)
            row("touch one texture: steps that ran (--explain)", ", ".join(steps_ran) or "none",
                "texture + encode only", only)

        # 4 -------------------------------------------------------------------------------
        if "scale" not in skip:
            src, out, cache = tmp / "scale-src", tmp / "scale-out", tmp / "scale-cache"
            nbytes = make_tree(src, scale)
            print(f"\n[4] scale: {scale} OBJ boxes ({nbytes / 1e6:.1f} MB); cold build -j 2 --no-lod ...", flush=True)
            cmd = build_cmd(src, out, cache, "-j", "2", "--no-lod")
            cold = run(cmd, rss=True, timeout=args.scale_timeout)
            if cold["timed_out"]:
                print(f"    cold build killed after {args.scale_timeout:.0f} s: rerun with a smaller --scale")
                row(f"scale {scale}: cold build", f"> {args.scale_timeout:.0f} s (killed)", "-", False)
            else:
                check_ok(cold, "scale cold build")
                counts = summary_counts(cold["stdout"])
                print(f"    {cold['stdout'].strip()}")
                print(f"    cold: {cold['wall']:.1f} s, {cold['wall'] / scale * 1e3:.1f} ms per asset, peak RSS "
                      f"largest process {mb(cold['maxrss_kb'])}, process tree {mb(cold['tree_kb'])}")
                row(f"scale {scale}: cold build -j 2 --no-lod", f"{cold['wall']:.1f} s "
                    f"({cold['wall'] / scale * 1e3:.1f} ms/asset; {counts.get('built', 0)} built)", "all built",
                    counts.get("built", 0) == scale)
                row(f"scale {scale}: cold build peak RSS (largest / tree)",
                    f"{mb(cold['maxrss_kb'])} / {mb(cold['tree_kb'])}")
                run(pass_cmd)  # warm-ups
                check_ok(run(cmd), "scale no-op (warm-up)")
                res = interleave({"noop": lambda: run(cmd), "pass": lambda: run(pass_cmd)}, repeats)
                for r in res["noop"]:
                    check_ok(r, "scale no-op")
                ncounts = summary_counts(res["noop"][0]["stdout"])
                noop = statistics.median(r["wall"] for r in res["noop"])
                bare = statistics.median(r["wall"] for r in res["pass"])
                rss = run(cmd, rss=True)["maxrss_kb"]
                print(f"    no-op: {res['noop'][0]['stdout'].strip()}")
                print(f"    no-op median {noop:.3f} s ({noop / bare:.1f}x python -c pass), "
                      f"{noop / scale * 1e6:.0f} us per asset, peak RSS {mb(rss)}")
                row(f"scale {scale}: no-op rebuild wall (median)", f"{noop:.2f} s ({noop / bare:.0f}x python -c pass; "
                    f"{ncounts.get('cached', 0)} cached)", "< 1 s", noop < 1.0 and ncounts.get("built", 0) == 0)
                row(f"scale {scale}: no-op peak RSS", mb(rss))
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    # -- the table ---------------------------------------------------------------------------
    print()
    w0 = max(len(r[0]) for r in table) if table else 10
    w1 = max(len(r[1]) for r in table) if table else 10
    w2 = max(len(r[2]) for r in table) if table else 10
    print(f"{'figure':{w0}s}  {'measured':{w1}s}  {'goal':{w2}s}  verdict")
    print("-" * (w0 + w1 + w2 + 13))
    for f, m, g, v in table:
        print(f"{f:{w0}s}  {m:{w1}s}  {g:{w2}s}  {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
