"""Builds on a real Dask cluster (distributed.LocalCluster: 2 worker processes on 127.0.0.1):
byte-identical to a local build, a second machine served by the shared cache, a worker killed
mid-step, an unreachable scheduler."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from farm_fixtures import free_port, make_cluster, make_model, tree

from assetpipe.build import run_build
from assetpipe.cache.remote import TieredStore
from assetpipe.cache.store import Store
from assetpipe.executor import DaskExecutor, SchedulerError, blob_digests, run_on_worker
from assetpipe.options import DEFAULT_BUILD_OPTIONS


@pytest.fixture(scope="module")
def cluster():
    c = make_cluster()
    yield c
    c.close()


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("models")
    make_model(src, "a", 12, seed=1, texture=32)
    make_model(src / "sub", "b", 20, seed=2, texture=16)
    make_model(src, "big", 50, seed=3, texture=64)  # ~5k triangles: its LOD step is the slowest step
    return src


@pytest.fixture(scope="module")
def local_build(models, tmp_path_factory):
    """The reference: the same inputs built locally (-j 1), its output tree and steps."""
    tmp = tmp_path_factory.mktemp("local")
    report = run_build([models], tmp / "out", DEFAULT_BUILD_OPTIONS, cache_dir=Store(tmp / "cache"))
    assert not report.failed
    return tree(tmp / "out"), sum(len(r.steps) for r in report.results)


def _farm_build(models, tmp: Path, name: str, scheduler, cache=None):
    store = TieredStore(Store(tmp / f"{name}-local"), cache) if cache else Store(tmp / f"{name}-local")
    ex = DaskExecutor(scheduler)
    try:
        report = run_build([models], tmp / f"{name}-out", DEFAULT_BUILD_OPTIONS, cache_dir=store, scheduler=ex)
    finally:
        ex.close()
    assert not report.failed, [r.error for r in report.results]
    return report, ex, store


def test_farm_build_equals_local_build_and_a_second_machine_hits_the_shared_cache(cluster, models, local_build,
                                                                                  s3_server, tmp_path):
    ref, n_steps = local_build
    shared = s3_server.url(f"farm-{tmp_path.name}")  # the S3 server of tests/conftest.py
    report, ex, store = _farm_build(models, tmp_path, "m1", cluster.scheduler_address, shared)
    assert tree(tmp_path / "m1-out") == ref
    assert ex.moved["tasks"] == n_steps and all(s["ran"] for r in report.results for s in r.steps)
    # the client wrote every step's blobs (workers only saw their inputs, sent by content)
    assert ex.moved["from_workers"] > 0 and ex.moved["to_workers"] > 0
    assert set(ex.per_step) == {"task_import", "task_mesh", "task_texture", "task_lod", "task_encode"}
    assert ex.per_step["task_import"]["to_workers"] == 0  # imports read sources by path, nothing else
    # each encode step is sent exactly the blob its LOD step returned (and each LOD its mesh)
    assert ex.per_step["task_encode"]["to_workers"] == ex.per_step["task_lod"]["from_workers"]
    assert ex.per_step["task_lod"]["to_workers"] == ex.per_step["task_mesh"]["from_workers"]
    # machine 2: fresh output folder, fresh local tier, the same shared cache: nothing runs
    report2, ex2, _ = _farm_build(models, tmp_path, "m2", cluster.scheduler_address, shared)
    assert ex2.moved["tasks"] == 0 and ex2.client is None  # the scheduler was never contacted
    assert not any(s["ran"] for r in report2.results for s in r.steps)
    assert tree(tmp_path / "m2-out") == ref


def test_killed_worker_mid_step(cluster, models, local_build, tmp_path):
    """SIGKILL the worker running an LOD step; Dask reschedules it, the output is unchanged."""
    from distributed import Client

    killed: dict = {}
    stop = threading.Event()

    def killer():
        with Client(cluster.scheduler_address, set_as_default=False, timeout=30) as c:
            pids = c.run(os.getpid)
            while not stop.is_set():
                for addr, keys in c.processing().items():
                    lod = [k for k in keys if str(k).startswith("task_lod")]
                    if lod and addr in pids:
                        os.kill(pids[addr], signal.SIGKILL)
                        killed.update(addr=addr, keys=lod)
                        return
                time.sleep(0.005)

    t = threading.Thread(target=killer, daemon=True)
    t.start()
    try:
        _farm_build(models, tmp_path, "k", cluster.scheduler_address)
    finally:
        stop.set()
        t.join(30)
    assert killed, "no LOD step was seen running"
    assert tree(tmp_path / "k-out") == local_build[0]
    # the killed step was handed to a worker again
    for key in killed["keys"]:
        starts = [s for s in cluster.scheduler.story(key) if len(s) > 2 and s[2] == "processing"]
        assert len(starts) >= 2, cluster.scheduler.story(key)


def test_steps_on_workers_run_with_a_local_process_allocator(cluster):
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536 (every array above 128 KiB
    a fresh mmap: the LOD step took 1.6x its CPU time); a step run by the executor reuses freed
    memory as in a local build process (tests/test_executor.py measures the premise)."""
    from distributed import Client

    with Client(cluster.scheduler_address, set_as_default=False, timeout=30) as c:
        assert set(c.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_")).values()) == {"65536"}

    def alloc_faults(store_root, rounds):  # a task: 1 MiB arrays written and freed, page faults counted
        import resource

        import numpy as np

        np.ones(1 << 17).sum()
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for _ in range(rounds):
            np.ones(1 << 17).sum()
        return {"blobs": {}, "meta": {"faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0}}

    ex = DaskExecutor(cluster.scheduler_address)
    try:
        results = ex.map([(alloc_faults, "", 100)] * 4)
    finally:
        ex.close()
    pages = 2**20 // 4096  # with a fixed 128 KiB threshold: at least 100 x 256 faults per task
    assert [s for s, _, _ in results] == ["ok"] * 4, results
    assert all(v["meta"]["faults"] <= 4 * pages for _, v, _ in results), results


def test_unreachable_scheduler_is_one_clear_error(models, tmp_path):
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    t0 = time.monotonic()
    with pytest.raises(SchedulerError, match=rf"cannot reach the Dask scheduler at {address} within 2 s"):
        run_build([models], tmp_path / "out", DEFAULT_BUILD_OPTIONS, cache_dir=Store(tmp_path / "c"),
                  scheduler=DaskExecutor(address, timeout=2))
    assert time.monotonic() - t0 < 30


def test_worker_with_other_versions_refuses(tmp_path):
    """A worker whose libraries differ from the client's would store wrong bytes under the
    client's key: it refuses the step."""
    from assetpipe import steps

    status, value, _, blobs = run_on_worker(steps.task_import, [str(tmp_path / "x.gltf")], {}, "xxh3:" + "0" * 32)
    assert status == "internal" and "different assetpipe or library versions" in value and blobs == {}


def test_blob_digests_finds_nested_digests():
    d1, d2 = "xxh3:" + "1" * 32, "xxh3:" + "2" * 32
    assert blob_digests(["root", d1, [{"a": d2, "b": "xxh3"}], 3]) == [d1, d2]


# -- ETC2 on the farm: the key names the etcpak build, the worker encodes with that build ---------

def _etc2_options():
    import dataclasses

    return dataclasses.replace(DEFAULT_BUILD_OPTIONS,
                               texture=dataclasses.replace(DEFAULT_BUILD_OPTIONS.texture, compression="etc2"))


@pytest.fixture(scope="module")
def etc2_models(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("etc2-models")
    make_model(src, "e", 8, seed=5, texture=64)  # noise: every etcpak build encodes it differently
    return src


def _local(models, tmp: Path, name: str):
    report = run_build([models], tmp / name, _etc2_options(), cache_dir=Store(tmp / f"{name}-cache"))
    assert not report.failed, [r.error for r in report.results]
    return tree(tmp / name)


def _etc2_farm(models, out: Path, cache: Path, address: str) -> DaskExecutor:
    """An ETC2 build of ``models`` on the cluster at ``address`` into ``out``; its executor."""
    ex = DaskExecutor(address)
    try:
        report = run_build([models], out, _etc2_options(), cache_dir=Store(cache), scheduler=ex)
    finally:
        ex.close()
    assert not report.failed, [r.error for r in report.results]
    return ex


def test_etc2_on_workers_is_encoded_with_the_build_the_key_names(cluster, etc2_models, tmp_path, monkeypatch):
    """The client keys ETC2 steps by its etcpak build (here capped to the portable one by
    ASSETPIPE_ETCPAK_BUILD); the workers' CPUs run a better build, yet they encode with the one
    the key names: the farm's KTX2 files are the client's local build's, byte for byte."""
    from assetpipe.pipelines.texture_compress import ETCPAK_BUILD_ENV, etcpak_builds

    assert len(etcpak_builds()) >= 2, "needs a CPU with an etcpak SIMD build (every x86-64 with SSE4.1)"
    own = _local(etc2_models, tmp_path, "local-best")
    monkeypatch.setenv(ETCPAK_BUILD_ENV, "none")
    ref = _local(etc2_models, tmp_path, "local-none")
    ktx = {p for p in ref if p.endswith(".ktx2")}  # named by content
    assert ktx and ktx != {p for p in own if p.endswith(".ktx2")}, "the two builds' blocks differ on noise"
    ex = _etc2_farm(etc2_models, tmp_path / "farm", tmp_path / "farm-cache", cluster.scheduler_address)
    assert ex.per_step["task_texture"]["tasks"] == 1
    assert ex.worker_builds and all(v[0] != "none" for v in ex.worker_builds.values())  # better CPUs
    assert tree(tmp_path / "farm") == ref


@pytest.fixture()
def mixed_cluster():
    """A real cluster of two workers on different etcpak builds: one LocalCluster worker (this
    CPU's best build) and a `dask worker` process started with ASSETPIPE_ETCPAK_BUILD=none (a
    CPU without SIMD). Yields (cluster, address of the portable-only worker)."""
    import subprocess
    import sys

    from distributed import Client

    from assetpipe.pipelines.texture_compress import ETCPAK_BUILD_ENV

    c = make_cluster(workers=1)
    dask = Path(sys.executable).with_name("dask")
    proc = subprocess.Popen([str(dask), "worker", c.scheduler_address, "--nthreads", "1", "--host", "127.0.0.1",
                             "--no-dashboard", "--name", "portable-only"],
                            env={**os.environ, ETCPAK_BUILD_ENV: "none"},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        with Client(c.scheduler_address, set_as_default=False, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
            caps = client.run(lambda: os.environ.get(ETCPAK_BUILD_ENV))
        (portable,) = [addr for addr, cap in caps.items() if cap == "none"]
        yield c, portable
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
        c.close()


def test_etc2_refused_when_a_worker_cannot_run_the_keys_build(mixed_cluster, etc2_models, tmp_path, monkeypatch):
    """A worker that cannot run the etcpak build the ETC2 keys name would store other blocks under
    those keys: the build stops with one line naming the worker and the build to key by; that
    worker, sent such a step anyway (one that joined after the check), refuses it; keyed by a
    build every worker runs, the farm build succeeds and equals the local one."""
    from distributed import Client

    from assetpipe import steps
    from assetpipe.executor import WorkerBuildError, environment_fingerprint
    from assetpipe.pipelines.texture_compress import ETCPAK_BUILD_ENV, etcpak_builds

    cluster, portable = mixed_cluster
    best = etcpak_builds()[0]
    assert best != "none", "needs a CPU with an etcpak SIMD build (every x86-64 with SSE4.1)"
    ex = DaskExecutor(cluster.scheduler_address)
    try:
        with pytest.raises(WorkerBuildError, match=rf"worker {portable} cannot run etcpak build {best}, .* set "
                                                   rf"{ETCPAK_BUILD_ENV}=none here"):
            run_build([etc2_models], tmp_path / "out", _etc2_options(), cache_dir=Store(tmp_path / "c"), scheduler=ex)
        assert "task_texture" not in ex.per_step  # no ETC2 step was sent anywhere
        assert ex.worker_builds[portable] == ["none"]
        # the worker's own check: sent a step keyed by `best`, it refuses; keyed by its build, it runs
        image = {"name": "e.png", "mime": "image/png", "digest": None, "path": "e.png"}
        args = [image, str(etc2_models), "baseColor", "OPAQUE", 0.5, steps.options_to_json(_etc2_options().texture)]
        with Client(cluster.scheduler_address, set_as_default=False, timeout=30) as client:
            for build, want in ((best, "refused"), ("none", "ok")):
                status, value, _, _ = client.submit(run_on_worker, steps.task_texture, args, {},
                                                    environment_fingerprint(), {"etcpak-build": build},
                                                    workers=[portable], pure=False).result()
                assert status == want, value
                if want == "refused":
                    assert f"cannot run etcpak build {best}" in value and f"{ETCPAK_BUILD_ENV}=none" in value
    finally:
        ex.close()
    # the way out the message names: key by the portable build on the client
    monkeypatch.setenv(ETCPAK_BUILD_ENV, "none")
    ref = _local(etc2_models, tmp_path, "local-none")
    _etc2_farm(etc2_models, tmp_path / "farm", tmp_path / "fc", cluster.scheduler_address)
    assert tree(tmp_path / "farm") == ref


def test_an_image_with_several_uses_builds_on_the_farm_as_locally(cluster, tmp_path):
    # one texture step per image a model uses (steps.task_texture_uses): an ORM file named by
    # two roles, and an embedded label sheet sampled opaque and alpha-tested (its bytes travel
    # with the task, as a single use's do); the farm's outputs are the local build's
    import io

    import numpy as np
    from PIL import Image

    from gltf_builder import GltfBuilder

    src = tmp_path / "src"
    src.mkdir()
    rng = np.random.default_rng(11)

    def png(arr) -> bytes:
        buf = io.BytesIO()
        Image.fromarray(arr).save(buf, "PNG")
        return buf.getvalue()

    (src / "orm.png").write_bytes(png(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)))
    labels = rng.integers(0, 256, (16, 16, 4), dtype=np.uint8)
    for name, embed in (("orm", False), ("labels", True)):
        b = GltfBuilder()
        if embed:
            t = b.add_texture(data=png(labels))
            mats = [b.add_material(name="o", pbrMetallicRoughness={"baseColorTexture": {"index": t}}),
                    b.add_material(name="m", alphaMode="MASK", alphaCutoff=0.6,
                                   pbrMetallicRoughness={"baseColorTexture": {"index": t}})]
        else:
            t = b.add_texture(uri="orm.png")
            mats = [b.add_material(name="orm", occlusionTexture={"index": t},
                                   pbrMetallicRoughness={"metallicRoughnessTexture": {"index": t}})]
        for k, m in enumerate(mats):
            tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32) + [2.0 * k, 0, 0]
            b.add_node(mesh=b.add_triangles(tri, [0, 1, 2], material=m, TEXCOORD_0=[[0, 0], [1, 0], [0, 1]]))
        if embed:
            b.write_glb(src / f"{name}.glb")
        else:
            b.write_gltf(src / f"{name}.gltf")
    local = run_build([src], tmp_path / "local-out", DEFAULT_BUILD_OPTIONS, cache_dir=Store(tmp_path / "local"))
    assert not local.failed
    report, ex, _ = _farm_build(src, tmp_path, "farm", cluster.scheduler_address)
    assert ex.per_step["task_texture_uses"]["tasks"] == 2
    # what was sent with them: the embedded image's bytes alone (the ORM file is read by path)
    assert ex.per_step["task_texture_uses"]["to_workers"] == len(png(labels))
    assert tree(tmp_path / "farm-out") == tree(tmp_path / "local-out")


def test_etc2_image_with_several_uses_is_encoded_on_workers_with_the_build_the_key_names(cluster, tmp_path,
                                                                                        monkeypatch):
    # an ORM image named by two roles goes to a worker as one step (steps.task_texture_uses): it
    # must carry the etcpak build its key names as a single use's step does, or the worker's
    # better build writes other blocks under the client's key
    import io

    import numpy as np
    from PIL import Image

    from assetpipe.pipelines.texture_compress import ETCPAK_BUILD_ENV, etcpak_builds
    from gltf_builder import GltfBuilder

    assert len(etcpak_builds()) >= 2, "needs a CPU with an etcpak SIMD build (every x86-64 with SSE4.1)"
    src = tmp_path / "src"
    src.mkdir()
    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(13).integers(0, 256, (64, 64, 3), dtype=np.uint8)).save(buf, "PNG")
    (src / "orm.png").write_bytes(buf.getvalue())
    b = GltfBuilder()
    t = b.add_texture(uri="orm.png")
    m = b.add_material(name="orm", occlusionTexture={"index": t},
                       pbrMetallicRoughness={"metallicRoughnessTexture": {"index": t}})
    b.add_node(mesh=b.add_triangles([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [0, 1, 2], material=m,
                                    TEXCOORD_0=[[0, 0], [1, 0], [0, 1]]))
    b.write_gltf(src / "orm.gltf")
    own = _local(src, tmp_path, "local-best")
    monkeypatch.setenv(ETCPAK_BUILD_ENV, "none")
    ref = _local(src, tmp_path, "local-none")
    assert {p for p in ref if p.endswith(".ktx2")} != {p for p in own if p.endswith(".ktx2")}
    ex = _etc2_farm(src, tmp_path / "farm", tmp_path / "farm-cache", cluster.scheduler_address)
    assert ex.per_step["task_texture_uses"]["tasks"] == 1
    assert tree(tmp_path / "farm") == ref
