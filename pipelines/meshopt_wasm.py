"""meshoptimizer 1.3's simplifier, run in-process from its official WebAssembly build.

The native library we call (:mod:`pipelines.simplify`, PyPI ``meshoptimizer`` 0.2.30a0) predates
``meshopt_simplifyWithUpdate``, the simplifier that *moves* the kept vertices to where they
minimise the quadric error (gltfpack's ``-sv``). No Python package ships a newer build, so we
run the one meshoptimizer itself publishes: npm ``meshoptimizer@1.3.0``'s
``meshopt_simplifier.js`` embeds the library compiled to WebAssembly, and ``wasmtime`` (PyPI)
compiles and runs it. The exports are meshoptimizer's C functions; memory is taken with the
module's own ``sbrk`` and given back after each call.

Where the file comes from: ``ASSETPIPE_MESHOPT_JS`` (a path to ``meshopt_simplifier.js``), else
the project's ``.venv/node`` (``scripts/setup.sh`` installs the npm package there, beside
gltfpack). :func:`available` says whether it was found; :func:`version` is part of the LOD
step's cache key (``assetpipe.versions``), so a build with it and one without never share a
cached level.

Measured (the bunny, 69k triangles, to 1/2): 0.03-0.04 s a call (the native ``meshopt_simplify``
of :mod:`pipelines.simplify`: 0.079 s); a generated 1M-triangle torus to 1/2: 0.78 s, 102 MB of
WASM memory. Instances are pooled (one per call running at once) and keep the memory they
grew to; a call that needs more than :data:`MEMORY_LIMIT` fails with :class:`SimplifierFailed`.
"""

from __future__ import annotations

import atexit
import json
import os
import re
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

#: the npm package the WASM comes from (scripts/setup.sh installs exactly this)
NPM_PACKAGE = "meshoptimizer@1.3.0"

# meshopt_SimplifyXxx option bits (meshoptimizer.h)
LOCK_BORDER = 1
SPARSE = 2
ERROR_ABSOLUTE = 4
PRUNE = 8
REGULARIZE = 16
PERMISSIVE = 32

#: wasmtime's own cache of compiled modules, in the folder :func:`use_compile_cache` names (the
#: build cache's ``wasmtime/``; keyed by the module's bytes, wasmtime's version and the CPU's
#: features): each LOD worker process otherwise compiles the module again, 0.09-0.12 s of CPU
#: (on threads) against 0.006 s to load it from the cache. Without a folder, or where the cache
#: cannot be set up, the module is compiled as before.
COMPILE_CACHE = True
_cache_dir: list = []  # [folder] once use_compile_cache named one

#: bytes of WASM memory one instance may grow to (wasm32 addresses 4 GiB at most); a mesh that
#: needs more fails with :class:`SimplifierFailed` and its level is made without moved vertices
MEMORY_LIMIT = 3 << 30


class SimplifierFailed(RuntimeError):
    """The WASM simplifier trapped (the instance is closed; the next call makes a new one) or
    its heap could not grow for the call's arrays."""


_lock = threading.Lock()
_module = None  # (engine, module) compiled once per process
_path_cache: list = []
_version_cache: list = []
# idle instances (store, exports, memory, sbrk): a call takes one (or makes one) and gives it
# back, so there are never more than the calls running at once (a wasmtime store is used by one
# thread at a time), whichever threads make them; each keeps the memory it grew to
_idle: list = []
_live: set = set()  # every store not yet closed, closed at exit before the module and engine


@atexit.register
def _close() -> None:
    """Free wasmtime's objects in order while the interpreter still can (their finalisers fail
    once it has torn wasmtime's module down)."""
    global _module
    with _lock:
        for store in list(_live):
            store.close()
        _live.clear()
        _idle.clear()
    if _module is not None:
        _module[1].close()
        _module[0].close()
        _module = None


def _candidates() -> list[Path]:
    env = os.environ.get("ASSETPIPE_MESHOPT_JS")
    if env:
        return [Path(env)]
    rel = Path("node") / "node_modules" / "meshoptimizer" / "meshopt_simplifier.js"
    out = [Path(sys.prefix) / rel]
    here = Path(__file__).resolve()
    for up in here.parents[:3]:
        out.append(up / ".venv" / rel)
    return out


def js_path() -> Path | None:
    """The ``meshopt_simplifier.js`` used, or None when none is installed."""
    if not _path_cache:
        found = next((p for p in _candidates() if p.is_file()), None)
        _path_cache.append(found)
    return _path_cache[0]


def version() -> str | None:
    """The npm package's version (``"1.3.0"``), or None when it is not installed or wasmtime
    is missing. Found once per process (the LOD step asks at every candidate)."""
    if not _version_cache:
        _version_cache.append(_find_version())
    return _version_cache[0]


def _find_version() -> str | None:
    p = js_path()
    if p is None:
        return None
    import importlib.util

    if importlib.util.find_spec("wasmtime") is None:
        return None
    try:
        return str(json.loads((p.parent / "package.json").read_text())["version"])
    except (OSError, ValueError, KeyError):
        return "unknown"


def available() -> bool:
    return version() is not None


def _decode(js: str) -> bytes:
    """The WASM bytes embedded in meshopt_simplifier.js (its own ``unpack``: characters map to
    0..63; values below 60 index a byte table, values from 60 pair with the next one)."""
    import numpy as np

    data = re.search(r"var wasm =\s*'([^']*)'", js)
    pack = re.search(r"var wasmpack = new Uint8Array\(\[([^\]]*)\]", js)
    if data is None or pack is None:
        raise RuntimeError("meshopt_simplifier.js: no embedded WASM found (not meshoptimizer's file?)")
    table = np.array([int(x) for x in pack.group(1).replace("\n", "").split(",") if x.strip()], np.int64)
    c = np.frombuffer(data.group(1).encode("ascii"), np.uint8).astype(np.int64)
    raw = np.where(c > 96, c - 97, np.where(c > 64, c - 39, c + 4))
    out = bytearray()
    i, n = 0, raw.size
    # pairs are rare: walk runs of single values vectorised
    big = np.flatnonzero(raw >= 60)
    for j in big:
        if j < i:
            continue
        out += table[raw[i:j]].astype(np.uint8).tobytes()
        out.append(int(((raw[j] - 60) * 64 + raw[j + 1]) & 0xFF))
        i = j + 2
    out += table[raw[i:n]].astype(np.uint8).tobytes()
    return bytes(out)


def _acquire():
    """An idle instance, or a new one."""
    with _lock:
        if _idle:
            return _idle.pop()
    return _new_instance()


def _release(inst, broken: bool = False) -> None:
    """Give ``inst`` back (or, ``broken``: close it: a trap can leave its stack and heap
    inconsistent)."""
    with _lock:
        if broken:
            _live.discard(inst[0])
            inst[0].close()
        else:
            _idle.append(inst)


def reset() -> None:
    """Close the idle instances (the next call makes a new one, under the current
    :data:`MEMORY_LIMIT`)."""
    with _lock:
        for inst in _idle:
            _live.discard(inst[0])
            inst[0].close()
        _idle.clear()


def use_compile_cache(directory) -> None:
    """Keep wasmtime's compiled module in ``directory`` (made when needed): the engine this
    process makes next (its first simplification) loads it from there or compiles it there.
    Nothing is written elsewhere (not in ``~/.cache``, wasmtime's default)."""
    with _lock:
        _cache_dir[:] = [Path(directory)]


def _config(wasmtime):
    """The engine's configuration: wasmtime's compile cache in :func:`use_compile_cache`'s
    folder (:data:`COMPILE_CACHE`), where one is named and it can be set up."""
    config = wasmtime.Config()
    if COMPILE_CACHE and _cache_dir:
        folder = _cache_dir[0]
        try:
            folder.mkdir(parents=True, exist_ok=True)
            toml = folder / "config.toml"
            text = f"[cache]\ndirectory = {json.dumps(str(folder))}\n"
            if not toml.is_file() or toml.read_text() != text:  # written whole (workers race)
                tmp = folder / f".config.{os.getpid()}.{threading.get_ident()}.tmp"
                tmp.write_text(text)
                os.replace(tmp, toml)
            config.cache = str(toml)
        except Exception:  # noqa: BLE001 - an unwritable folder, wasmtime's own error type: compile as before
            config = wasmtime.Config()
    return config


def _new_instance():
    global _module
    import wasmtime

    with _lock:
        if _module is None:
            p = js_path()
            if p is None:
                raise RuntimeError(f"meshoptimizer's WASM simplifier is not installed (npm {NPM_PACKAGE}; "
                                   "scripts/setup.sh installs it)")
            engine = wasmtime.Engine(_config(wasmtime))
            _module = (engine, wasmtime.Module(engine, _decode(p.read_text())))
    engine, module = _module
    store = wasmtime.Store(engine)
    store.set_limits(memory_size=MEMORY_LIMIT)
    with _lock:
        _live.add(store)
    instance = wasmtime.Instance(store, module, [])
    ex = instance.exports(store)
    ex["__wasm_call_ctors"](store)
    return (store, ex, ex["memory"], ex["sbrk"])


def simplify_with_update(positions: "np.ndarray", indices: "np.ndarray", target_triangles: int, *,
                         target_error: float = 1.0e30, options: int = 0,
                         vertex_lock: "np.ndarray | None" = None) -> "tuple[np.ndarray, np.ndarray, float]":
    """``meshopt_simplifyWithUpdate`` on positions alone.

    Args: positions (N, 3) float32 (a normalised frame: meshoptimizer works in float32);
    indices (M, 3) uint32 < N; ``target_error`` in meshoptimizer's units (relative to the
    extent unless ``ERROR_ABSOLUTE``); ``options``: the bits above; vertex_lock (N,) uint8/bool.

    Returns ``(indices (K, 3) uint32 into the same N vertices, positions (N, 3) float32 with
    the kept vertices moved (the others as given), meshoptimizer's error)``.
    """
    import numpy as np

    pos = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    idx = np.ascontiguousarray(indices, np.uint32).reshape(-1)
    if idx.size == 0:
        return np.zeros((0, 3), np.uint32), pos.copy(), 0.0
    import wasmtime

    inst = _acquire()
    store, ex, mem, sbrk = inst
    base = sbrk(store, 0)
    broken = False
    try:
        def put(a) -> int:
            b = a.tobytes()
            p = sbrk(store, len(b))
            if p < 0 or p == 0xFFFFFFFF:
                raise SimplifierFailed(f"meshoptimizer's WASM simplifier: out of memory ({len(b)} more bytes)")
            mem.write(store, b, p)
            return p

        te = put(np.zeros(1, np.float32))
        pp = put(pos)
        ip = put(idx)
        lp = put(np.ascontiguousarray(vertex_lock, np.uint8).reshape(-1)) if vertex_lock is not None else 0
        n = ex["meshopt_simplifyWithUpdate"](store, ip, idx.size, pp, pos.shape[0], 12, 0, 0, 0, 0, lp,
                                             int(target_triangles) * 3, float(target_error), int(options), te)
        out = np.frombuffer(mem.read(store, ip, ip + 4 * n), np.uint32).reshape(-1, 3).copy()
        moved = np.frombuffer(mem.read(store, pp, pp + pos.nbytes), np.float32).reshape(-1, 3).copy()
        err = float(np.frombuffer(mem.read(store, te, te + 4), np.float32)[0])
    except (wasmtime.Trap, wasmtime.WasmtimeError) as e:
        broken = True
        # wasmtime's message: a backtrace, then the cause ("wasm trap: out of bounds memory
        # access" when its allocator ran out of the memory limit)
        cause = [ln.strip() for ln in str(e).splitlines() if "trap" in ln or "fault" in ln]
        raise SimplifierFailed("meshoptimizer's WASM simplifier failed: "
                               + ("; ".join(cause) or str(e).splitlines()[0])) from e
    finally:
        if not broken:
            sbrk(store, base - sbrk(store, 0))
        _release(inst, broken)
    return out, moved, err


__all__ = ["available", "version", "js_path", "simplify_with_update", "NPM_PACKAGE", "SimplifierFailed",
           "MEMORY_LIMIT", "reset"]
