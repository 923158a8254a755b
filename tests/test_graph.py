"""The step graph's scheduling: the LOD tasks are handed to the executor largest first (a long
task started last would hold up the phase on one worker); a rebuild from scratch gives the same
bytes."""

from __future__ import annotations

from pathlib import Path

from assetpipe import graph, steps
from assetpipe.cache.serialize import unpack
from assetpipe.cache.store import Store
from robust_models import output_bytes, uv_sphere, write_obj


class _Recording(graph.Executor):
    """The real executor, remembering the order in which it was handed the tasks."""

    calls: list[tuple] = []

    def map(self, calls):
        type(self).calls.extend(calls)
        return super().map(calls)


def test_lod_tasks_start_largest_first_and_outputs_do_not_depend_on_it(tmp_path, monkeypatch):
    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions

    src = tmp_path / "src"
    src.mkdir()
    # names that sort against size: the asset order alone would start the largest in the middle
    for name, (lon, lat) in {"a_small": (8, 4), "b_large": (96, 48), "c_medium": (32, 16)}.items():
        pos, tris, _ = uv_sphere(lon, lat)
        write_obj(src / f"{name}.obj", pos, tris)
    _Recording.calls = []
    monkeypatch.setattr(graph, "Executor", _Recording)
    cache = tmp_path / "cache"
    run_build([src], tmp_path / "out", BuildOptions(), jobs=1, cache_dir=cache)
    blobs = [c[2] for c in _Recording.calls if c[0] is steps.task_lod]
    store = Store(cache)

    def triangles(blob: str) -> int:
        _, arrays = unpack(store.get_blob(blob))
        return sum(v.shape[0] for k, v in arrays.items() if k.endswith(".indices"))

    sizes = [triangles(b) for b in blobs]
    assert len(sizes) == 3 and sizes == sorted(sizes, reverse=True), sizes
    # the same models built again into a fresh folder and cache, one job: byte-identical outputs
    monkeypatch.undo()
    run_build([src], tmp_path / "out2", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache2")
    assert output_bytes(tmp_path / "out") == output_bytes(tmp_path / "out2")


_WARM_SCRIPT = """
import sys
from assetpipe.graph import Executor

def loaded():
    mod = sys.modules.get("assetpipe.pipelines.closest_point")
    return mod is not None and len(mod._query.signatures) > 0

if __name__ == "__main__":
    ex = Executor(2)
    try:
        cold = [r[:2] for r in ex.map([(loaded,), (loaded,)])]
        ex.warm()
        ex.fresh_pool()
        warm = [r[:2] for r in ex.map([(loaded,), (loaded,)])]
    finally:
        ex.close()
    print(cold == [("ok", False)] * 2, warm == [("ok", True)] * 2)
"""


def test_workers_forked_after_warming_inherit_the_lod_kernels(tmp_path):
    """A fresh build process (not this test process, which has loaded kernels already): its
    first workers load no kernels; after warm() and fresh_pool() the new workers start with
    the ones the parent loaded (0.7 s a process saved)."""
    import subprocess
    import sys

    script = tmp_path / "warm.py"
    script.write_text(_WARM_SCRIPT)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True"]
    from assetpipe.graph import Executor

    inline = Executor(1)  # no pool: nothing to warm, nothing to fork
    inline.warm()
    inline.fresh_pool()
    assert inline.pool is None and inline._warming is None
