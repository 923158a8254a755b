"""The step graph's scheduling: the LOD tasks are handed to the executor largest first (a long
task started last would hold up the phase on one worker); a rebuild from scratch gives the same
bytes."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

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

    def submit(self, call):
        type(self).calls.append(call)
        return super().submit(call)


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
    # the mesh steps too, by their geometry's size
    geometry = [store.blob_path(c[2]).stat().st_size for c in _Recording.calls if c[0] is steps.task_mesh]
    assert len(geometry) == 3 and geometry == sorted(geometry, reverse=True), geometry
    # the same models built again into a fresh folder and cache, one job: byte-identical outputs
    monkeypatch.undo()
    run_build([src], tmp_path / "out2", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache2")
    assert output_bytes(tmp_path / "out") == output_bytes(tmp_path / "out2")


_WARM_SCRIPT = """
import sys
from assetpipe.graph import Executor

def loaded():
    lod = sys.modules.get("assetpipe.pipelines.closest_point")
    tex = sys.modules.get("assetpipe.pipelines.texture_mips")
    return (lod is not None and len(lod._query.signatures) > 0
            and tex is not None and len(tex._encode_rows.signatures) > 0)

def big_chain():
    # OpenCV's pthreads pool was loaded by the parent's warm-up: a forked worker still filters
    # a large image (its resize runs in parallel) instead of waiting for threads it lacks
    import numpy as np
    from assetpipe.pipelines.texture_mips import build_mip_chain
    rgba = (np.random.default_rng(0).random((2048, 2048, 4)) * 255).astype(np.uint8)
    return len(build_mip_chain(rgba, "baseColor", "BLEND").levels)

if __name__ == "__main__":
    ex = Executor(2)
    try:
        cold = [r[:2] for r in ex.map([(loaded,), (loaded,)])]
        ex.warm()
        ex.fresh_pool()
        warm = [r[:2] for r in ex.map([(loaded,), (loaded,)])]
        chains = [r[:2] for r in ex.map([(big_chain,), (big_chain,)])]
    finally:
        ex.close()
    print(cold == [("ok", False)] * 2, warm == [("ok", True)] * 2, chains == [("ok", 12)] * 2)
"""


def test_workers_forked_after_warming_inherit_the_lod_kernels(tmp_path):
    """A fresh build process (not this test process, which has loaded kernels already): its
    first workers load no kernels; after warm() and fresh_pool() the new workers start with
    the LOD and texture kernels the parent loaded (0.7 s a process saved), and OpenCV, which
    the warm-up loaded in the parent, still works in them."""
    import subprocess
    import sys

    script = tmp_path / "warm.py"
    script.write_text(_WARM_SCRIPT)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "True"]
    from assetpipe.graph import Executor

    inline = Executor(1)  # no pool: nothing to warm, nothing to fork
    inline.warm()
    inline.fresh_pool()
    assert inline.pool is None and inline._warming is None


class _Phased(_Recording):
    """The real executor without ``submit``: the graph then runs lod + textures, then encode,
    as it does with an executor of whole phases (the farm's)."""

    @property
    def submit(self):
        raise AttributeError("submit")


def _textured_models(src: Path) -> None:
    """Three spheres of different sizes; two share one texture, one has its own."""
    from PIL import Image

    src.mkdir()
    rng = np.random.default_rng(3)
    for name in ("shared.png", "own.png"):
        Image.fromarray(rng.integers(0, 255, (32, 32, 3), dtype=np.uint8)).save(src / name)
    for name, (lon, lat), image in (("a_small", (8, 4), "shared.png"), ("b_large", (64, 32), "own.png"),
                                    ("c_medium", (24, 12), "shared.png")):
        pos, tris, uv = uv_sphere(lon, lat)
        obj = write_obj(src / f"{name}.obj", pos, tris, uv=uv)
        obj.write_text(f"mtllib {name}.mtl\nusemtl m\n" + obj.read_text())
        (src / f"{name}.mtl").write_text(f"newmtl m\nKd 1 1 1\nmap_Kd {image}\n")


def test_a_model_is_encoded_and_written_as_soon_as_its_own_steps_are_done(tmp_path, monkeypatch):
    """Locally the encode step of a model whose chain and textures are in runs before the
    chains of other models still waiting, and its result is reported then; the outputs are
    byte-identical to a build that runs every encode after every chain (the phased path)."""
    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions

    src = tmp_path / "src"
    _textured_models(src)
    _Recording.calls = []
    monkeypatch.setattr(graph, "Executor", _Recording)
    reported: list[tuple[str, int]] = []

    def on_result(r, done, total):
        reported.append((Path(r.source).stem, len(_Recording.calls)))

    run_build([src], tmp_path / "out", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache", on_result=on_result)
    names = [c[0].__name__ for c in _Recording.calls]
    last_lod = max(i for i, n in enumerate(names) if n == "task_lod")
    first_encode = names.index("task_encode")
    assert first_encode < last_lod, names  # one model done before another's chain started
    # the largest model (its chain handed out first) is reported before the last chain ran
    assert dict(reported)["b_large"] <= last_lod, (reported, names)
    assert sorted(n for n, _ in reported) == ["a_small", "b_large", "c_medium"]

    monkeypatch.setattr(graph, "Executor", _Phased)
    _Recording.calls = []
    run_build([src], tmp_path / "out2", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache2")
    names = [c[0].__name__ for c in _Recording.calls]
    assert names.index("task_encode") > max(i for i, n in enumerate(names) if n == "task_lod")
    assert output_bytes(tmp_path / "out") == output_bytes(tmp_path / "out2")


class _InlineTwo(_Recording):
    """Runs each task where it is handed out (as one job does), but tells the graph it has two
    workers: the graph then streams as it does with a pool, and each task it hands out has
    finished by the time it looks (a pool whose workers are always done first)."""

    def __init__(self, jobs):
        super().__init__(1)
        self.jobs = 2


def test_with_workers_a_models_outputs_wait_for_the_tasks_it_freed(tmp_path, monkeypatch):
    """With a pool, writing a finished model's outputs (this process's work, a copy of each of
    its textures) comes after handing out the tasks there are and taking the ones that finished:
    with workers that are always done first, every model is written once no task is left. The
    outputs are byte-identical to a build with one job, which writes each model at once."""
    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions

    src = tmp_path / "src"
    _textured_models(src)
    _Recording.calls = []
    monkeypatch.setattr(graph, "Executor", _InlineTwo)
    monkeypatch.setattr(graph, "STREAM_QUEUED_SECONDS", 0.0)  # three tasks out at a time
    reported: list[tuple[str, int]] = []

    def on_result(r, done, total):
        reported.append((Path(r.source).stem, len(_Recording.calls)))

    run_build([src], tmp_path / "out", BuildOptions(), jobs=2, cache_dir=tmp_path / "cache", on_result=on_result)
    calls = len(_Recording.calls)
    assert sorted(n for n, _ in reported) == ["a_small", "b_large", "c_medium"]
    assert all(n == calls for _, n in reported), (reported, calls)
    monkeypatch.undo()
    run_build([src], tmp_path / "out1", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache1")
    assert output_bytes(tmp_path / "out") == output_bytes(tmp_path / "out1")


# -- a worker killed by one model's step (a native crash) fails that model alone ------------

_CRASH_ON = Path("/nonexistent")  # set by the test: a file holding the blob whose step kills its worker
_PARENT = [0]
_SIGNAL = [9]  # set by the test: the signal the worker dies by
_REAL = {"lod": steps.task_lod, "mesh": steps.task_mesh}


def _crash_if_chosen(blob: str) -> None:
    """The worker dies by ``_SIGNAL`` (SIGKILL: as the system's out-of-memory killer kills it;
    SIGSEGV: as a native library's fault does) when given the chosen blob (never the test
    process itself)."""
    if _CRASH_ON.is_file() and blob == _CRASH_ON.read_text() and os.getpid() != _PARENT[0]:
        os.kill(os.getpid(), _SIGNAL[0])


def _crashing_task_lod(store_root, blob, *args):
    _crash_if_chosen(blob)
    return _REAL["lod"](store_root, blob, *args)


def _crashing_task_mesh(store_root, blob, *args):
    _crash_if_chosen(blob)
    return _REAL["mesh"](store_root, blob, *args)


# pickled by name as the real steps, which the test points here in this process and so in the
# workers it forks
_crashing_task_lod.__module__, _crashing_task_lod.__qualname__ = "assetpipe.steps", "task_lod"
_crashing_task_mesh.__module__, _crashing_task_mesh.__qualname__ = "assetpipe.steps", "task_mesh"


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGSEGV"])
@pytest.mark.parametrize("step", ["mesh", "lod"])
def test_a_worker_killed_by_one_models_step_fails_that_model_alone(tmp_path, monkeypatch, step, sig):
    """Four models' mesh (a phase) or LOD steps (the streamed phase) are in the pool when one
    model's step kills its worker: the others' steps, lost with the pool, are run again alone
    and build; the model whose step kills a worker even alone fails with one line saying so.
    (Before, every step still in the pool failed with it.) The line says how the worker died:
    SIGKILL (the out-of-memory killer's signal) is out of memory, not a bug to report; another
    signal is a native library's fault, an internal error."""
    import json
    import signal

    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions

    src = tmp_path / "src"
    src.mkdir()
    for name, (lon, lat) in {"a": (16, 8), "bad": (24, 12), "c": (20, 10), "d": (12, 6)}.items():
        pos, tris, _ = uv_sphere(lon, lat)
        write_obj(src / f"{name}.obj", pos, tris)
    # the bad model's mesh blob, from a build of it alone (blobs are content-addressed)
    run_build([src / "bad.obj"], tmp_path / "probe", BuildOptions(), jobs=1, cache_dir=tmp_path / "probe-cache")
    explain = json.loads((tmp_path / "probe" / ".assetpipe" / "explain.json").read_text())
    (entry,) = explain["steps"].values()
    marker = tmp_path / "crash-on"
    marker.write_text(entry[step]["inputs"]["mesh" if step == "lod" else "geometry"])
    monkeypatch.setattr(steps, f"task_{step}", {"lod": _crashing_task_lod, "mesh": _crashing_task_mesh}[step])
    monkeypatch.setattr(sys.modules[__name__], "_CRASH_ON", marker)
    monkeypatch.setattr(sys.modules[__name__], "_PARENT", [os.getpid()])
    monkeypatch.setattr(sys.modules[__name__], "_SIGNAL", [getattr(signal, sig)])
    report = run_build([src], tmp_path / "out", BuildOptions(), jobs=2, cache_dir=tmp_path / "cache")
    status = {Path(r.source).stem: (r.status, r.error) for r in report.results}
    assert status["bad"][0] == "failed", status
    assert f"step {step}" in status["bad"][1], status
    if sig == "SIGKILL":
        assert f"out of memory in step {step} (its worker process was killed (SIGKILL)" in status["bad"][1], status
        assert "internal error" not in status["bad"][1] and "please report" not in status["bad"][1], status
    else:
        assert "worker process crashed running this step alone (SIGSEGV: a native library's fault)" in \
            status["bad"][1], status
        assert "internal error" in status["bad"][1], status
    assert all(status[n][0] == "built" for n in ("a", "c", "d")), status


def test_one_texture_step_per_image_and_each_alpha_mode_keeps_its_own_texture(tmp_path, monkeypatch):
    # one image sampled as baseColor by an opaque material and by two alpha-tested ones with
    # other cutoffs, another as occlusion and metallicRoughness (an ORM image): one texture
    # step per image (read and decoded once), and every material its own use's texture. Before,
    # the three baseColor uses shared one record label, so every one of them was given the
    # last one's texture: the alpha-tested materials lost their coverage-preserving mips.
    import io
    import json

    from PIL import Image

    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions
    from gltf_builder import GltfBuilder

    rng = np.random.default_rng(3)
    labels = rng.integers(0, 256, (32, 32, 4), dtype=np.uint8)
    labels[::2, :, 3] = 255
    orm = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    src = tmp_path / "src"
    src.mkdir()
    for name, arr in (("labels.png", labels), ("orm.png", orm)):
        buf = io.BytesIO()
        Image.fromarray(arr).save(buf, "PNG")
        (src / name).write_bytes(buf.getvalue())
    b = GltfBuilder()
    t_labels, t_orm = b.add_texture(uri="labels.png"), b.add_texture(uri="orm.png")
    mats = [b.add_material(name="opaque", pbrMetallicRoughness={"baseColorTexture": {"index": t_labels}}),
            b.add_material(name="cut25", alphaMode="MASK", alphaCutoff=0.25,
                           pbrMetallicRoughness={"baseColorTexture": {"index": t_labels}}),
            b.add_material(name="cut75", alphaMode="MASK", alphaCutoff=0.75,
                           pbrMetallicRoughness={"baseColorTexture": {"index": t_labels}}),
            b.add_material(name="orm", occlusionTexture={"index": t_orm},
                           pbrMetallicRoughness={"metallicRoughnessTexture": {"index": t_orm}})]
    for k, m in enumerate(mats):
        quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32) + [2.0 * k, 0, 0]
        b.add_node(mesh=b.add_triangles(quad, [0, 1, 2, 0, 2, 3], material=m,
                                        TEXCOORD_0=[[0, 0], [1, 0], [1, 1], [0, 1]]))
    b.write_gltf(src / "mats.gltf")
    _Recording.calls = []
    monkeypatch.setattr(graph, "Executor", _Recording)
    run_build([src], tmp_path / "out", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache")
    textures = [c for c in _Recording.calls if c[0] in (steps.task_texture, steps.task_texture_uses)]
    assert sorted(c[0].__name__ for c in textures) == ["task_texture_uses"] * 2
    sidecar = json.loads((tmp_path / "out" / "mats.asset.json").read_text())
    got = {m["name"]: m["textures"] for m in sidecar["materials"]}
    base = {n: got[n]["baseColor"] for n in ("opaque", "cut25", "cut75")}
    assert len({t["ktx2"] for t in base.values()}) == 3  # each alpha mode and cutoff its own chain
    assert base["opaque"]["coverage"] is None
    for name, cutoff in (("cut25", 0.25), ("cut75", 0.75)):
        cov = base[name]["coverage"]
        # the mask's coverage kept at every level: level 0's share of texels at or above the cutoff
        a0 = labels[..., 3] / 255.0
        assert len(cov) == base[name]["levels"] and abs(cov[0] - float((a0 >= cutoff).mean())) < 1e-9
    assert got["orm"]["occlusion"]["ktx2"] == got["orm"]["metallicRoughness"]["ktx2"]
    # built again into a fresh folder and cache with the executor the build uses: the same bytes
    monkeypatch.undo()
    run_build([src], tmp_path / "out2", BuildOptions(), jobs=2, cache_dir=tmp_path / "cache2")
    assert output_bytes(tmp_path / "out") == output_bytes(tmp_path / "out2")


def test_a_broken_image_with_several_uses_is_one_warning_and_the_model_builds(tmp_path):
    # an ORM image that cannot be decoded, named by occlusion and metallicRoughness: its one
    # texture step fails with one line naming the image and both uses; the model builds with
    # its other texture, and its materials simply lack the broken one
    import io
    import json

    from PIL import Image

    from assetpipe.build import run_build
    from assetpipe.options import BuildOptions
    from gltf_builder import GltfBuilder

    src = tmp_path / "src"
    src.mkdir()
    buf = io.BytesIO()
    Image.fromarray(np.full((8, 8, 3), 128, np.uint8)).save(buf, "PNG")
    (src / "base.png").write_bytes(buf.getvalue())
    (src / "orm.png").write_bytes(buf.getvalue()[:60])  # the header, then nothing
    b = GltfBuilder()
    t_base, t_orm = b.add_texture(uri="base.png"), b.add_texture(uri="orm.png")
    m = b.add_material(name="m", occlusionTexture={"index": t_orm},
                       pbrMetallicRoughness={"baseColorTexture": {"index": t_base},
                                             "metallicRoughnessTexture": {"index": t_orm}})
    b.add_node(mesh=b.add_triangles([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [0, 1, 2], material=m,
                                    TEXCOORD_0=[[0, 0], [1, 0], [0, 1]]))
    b.write_gltf(src / "orm.gltf")
    report = run_build([src], tmp_path / "out", BuildOptions(), jobs=1, cache_dir=tmp_path / "cache")
    (res,) = report.results
    assert res.status == "built", res.error
    said = [w for w in res.warnings if "orm.png" in w]
    assert len(said) == 1 and "(metallicRoughness, occlusion) skipped" in said[0] and "truncated PNG" in said[0], said
    side = json.loads((tmp_path / "out" / "orm.asset.json").read_text())
    assert set(side["materials"][0]["textures"]) == {"baseColor"}
