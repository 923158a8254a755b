"""meshoptimizer 1.3's WASM simplifier run in-process (pipelines/meshopt_wasm.py)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import trimesh

from assetpipe.pipelines import meshopt_wasm


@pytest.fixture(scope="module", autouse=True)
def _installed():
    # scripts/setup.sh installs both; a missing one is a broken setup, not a reason to skip
    assert meshopt_wasm.available(), f"npm {meshopt_wasm.NPM_PACKAGE} (scripts/setup.sh) and wasmtime are needed"


def _seamed_sphere():
    """A UV sphere whose seam (u = 0 and u = 1) is split: two vertices at each seam position."""
    nu, nv = 48, 24
    u, w = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0.05, 0.95, nv), indexing="ij")
    th, ph = u * 2 * np.pi, w * np.pi
    r = 1 + 0.1 * np.sin(5 * th) * np.sin(3 * ph)
    pos = np.stack([r * np.cos(th) * np.sin(ph), r * np.sin(th) * np.sin(ph), r * np.cos(ph)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv - 1), indexing="ij")
    a, b = i * nv + j, (i + 1) * nv + j
    f = np.concatenate([np.stack([a, b, b + 1], -1).reshape(-1, 3), np.stack([a, b + 1, a + 1], -1).reshape(-1, 3)])
    return pos.astype(np.float32), f.astype(np.uint32)


def test_the_embedded_module_decodes_to_wasm():
    data = meshopt_wasm._decode(meshopt_wasm.js_path().read_text())
    assert data[:4] == b"\0asm" and len(data) > 10_000
    assert meshopt_wasm.version() == "1.3.0"


def test_simplify_with_update_moves_kept_vertices_and_keeps_seams_closed():
    pos, f = _seamed_sphere()
    out, moved, err = meshopt_wasm.simplify_with_update(pos, f, len(f) // 4)
    assert 0 < out.shape[0] <= len(f) // 4 and out.max() < len(pos) and err > 0
    used = np.unique(out)
    changed = np.any(moved != pos, axis=1)
    assert changed[used].mean() > 0.5  # most kept vertices moved
    assert not changed[np.setdiff1d(np.arange(len(pos)), used)].any()  # the others as given
    # the two vertices of each seam position move together: no crack opens
    nv = 24
    first, last = np.arange(nv), 48 * nv + np.arange(nv)
    both = np.isin(first, used) & np.isin(last, used)
    assert both.any()
    assert np.array_equal(moved[first[both]], moved[last[both]])


def test_results_do_not_depend_on_threads():
    v = np.asarray(trimesh.creation.icosphere(4).vertices, np.float32)
    v = v * (1 + 0.05 * np.sin(4 * v[:, :1]))
    f = np.asarray(trimesh.creation.icosphere(4).faces, np.uint32)
    targets = [len(f) // k for k in (2, 3, 5, 8)]
    alone = [meshopt_wasm.simplify_with_update(v, f, t) for t in targets]
    with ThreadPoolExecutor(2) as pool:
        threaded = list(pool.map(lambda t: meshopt_wasm.simplify_with_update(v, f, t), targets))
    for (a, pa, ea), (b, pb, eb) in zip(alone, threaded):
        assert np.array_equal(a, b) and np.array_equal(pa, pb) and ea == eb


def test_memory_is_given_back_and_instances_are_reused():
    """Each call gives its heap back, and its instance to the pool: calls one after another,
    from one thread or several, keep reusing the same instance."""
    meshopt_wasm.reset()
    pos, f = _seamed_sphere()
    meshopt_wasm.simplify_with_update(pos, f, len(f) // 2)
    assert len(meshopt_wasm._idle) == 1
    store, _, _, sbrk = meshopt_wasm._idle[0]
    top = sbrk(store, 0)
    for _ in range(3):
        meshopt_wasm.simplify_with_update(pos, f, len(f) // 2)
    with ThreadPoolExecutor(1) as pool:  # a new thread takes the idle instance too
        pool.submit(meshopt_wasm.simplify_with_update, pos, f, len(f) // 2).result()
    assert len(meshopt_wasm._idle) == 1 and meshopt_wasm._idle[0][0] is store
    assert sbrk(store, 0) == top


def test_out_of_memory_is_a_clear_failure_and_the_instance_recovers(monkeypatch):
    """A mesh beyond the instance's memory (here a 4 MiB limit; wasm32's is 4 GiB) fails with
    SimplifierFailed, and the next call in that thread works again on a fresh instance."""
    from assetpipe.pipelines import lod

    pos, f = _seamed_sphere()
    big = np.vstack([pos + [3.0 * k, 0, 0] for k in range(40)]).astype(np.float32)
    bigf = np.vstack([f + len(pos) * k for k in range(40)]).astype(np.uint32)
    monkeypatch.setattr(meshopt_wasm, "MEMORY_LIMIT", 4 << 20)
    meshopt_wasm.reset()  # a fresh instance under the limit
    with pytest.raises(meshopt_wasm.SimplifierFailed, match="WASM simplifier"):
        meshopt_wasm.simplify_with_update(big, bigf, len(bigf) // 2)
    # the LOD step takes it as "no moved candidate this step"
    out, _, err = lod._simplify_moving(big, bigf, len(bigf) // 2, 1e9)
    assert out.shape == (0, 3) and err == np.inf
    # a small mesh in the same thread, under the same limit, works: no state left from the failure
    out, moved, _ = meshopt_wasm.simplify_with_update(pos, f, len(f) // 2)
    assert 0 < out.shape[0] <= len(f) // 2
    assert np.array_equal(out, meshopt_wasm.simplify_with_update(pos, f, len(f) // 2)[0])
    meshopt_wasm.reset()  # later calls get an instance under the normal limit


def test_a_missing_simplifier_is_named_when_levels_would_move(monkeypatch, tmp_path):
    """Without the npm package the option does nothing: the build says so (and the WASM's
    version, None, is in the keys), and says nothing when it is installed or not asked for."""
    from assetpipe.cli import lod_move_note
    from assetpipe.pipelines.lod_options import LodOptions

    assert lod_move_note(LodOptions()) is None  # installed here
    monkeypatch.setenv("ASSETPIPE_MESHOPT_JS", str(tmp_path / "missing.js"))
    monkeypatch.setattr(meshopt_wasm, "_path_cache", [])  # looked up again under the variable
    monkeypatch.setattr(meshopt_wasm, "_version_cache", [])
    assert meshopt_wasm.js_path() is None and meshopt_wasm.version() is None
    note = lod_move_note(LodOptions())
    assert note is not None and "meshoptimizer@1.3.0" in note and "ASSETPIPE_MESHOPT_JS" in note
    assert lod_move_note(LodOptions(move_vertices=False)) is None
    assert lod_move_note(None) is None  # --no-lod


def test_a_second_process_loads_the_compiled_module_from_the_cache_folder(tmp_path):
    """The module is compiled once per cache, not once per worker process: the first process
    writes wasmtime's cache in the folder use_compile_cache names (the build cache's), a second
    one finds it there and simplifies to the same result; nothing lands in XDG_CACHE_HOME."""
    import os
    import subprocess
    import sys

    folder = tmp_path / "cache" / "wasmtime"
    code = ("import sys, numpy as np, trimesh\n"
            "from assetpipe.pipelines import meshopt_wasm\n"
            "meshopt_wasm.use_compile_cache(sys.argv[1])\n"
            "m = trimesh.creation.icosphere(4)\n"
            "out, moved, err = meshopt_wasm.simplify_with_update(m.vertices.astype(np.float32), "
            "m.faces.astype(np.uint32), len(m.faces) // 4)\n"
            "print(out.tobytes().hex()[:64], moved.tobytes().hex()[:64], err)\n")
    home = tmp_path / "home"
    home.mkdir()
    env = {**os.environ, "XDG_CACHE_HOME": str(home / "xdg"), "HOME": str(home)}
    run = [sys.executable, "-c", code, str(folder)]
    first = subprocess.run(run, env=env, capture_output=True, text=True, check=True)
    # the compiled module (beside it, a ``.stats`` file of uses, rewritten at every load)
    written = sorted(p for p in (folder / "modules").rglob("*") if p.is_file() and p.suffix != ".stats")
    assert written, "wasmtime wrote no compiled module to the cache folder"
    stamps = [p.stat().st_mtime_ns for p in written]
    second = subprocess.run(run, env=env, capture_output=True, text=True, check=True)
    assert second.stdout == first.stdout and first.stdout.strip()
    assert first.stderr == second.stderr == ""
    # the second process read the entry (it did not compile and write it again)
    assert [p.stat().st_mtime_ns for p in written] == stamps
    assert list(home.rglob("*")) == []
