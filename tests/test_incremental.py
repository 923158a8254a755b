"""The incremental build: exactly the steps an edit invalidates rerun, nothing else; the cache
is never wrong (corrupt entries are rebuilt); outputs are restored, removed and written
atomically; -j does not change a byte; concurrent and killed builds end correctly."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from assetpipe import steps, versions
from assetpipe.build import run_build
from assetpipe.core.hashing import digest_file
from assetpipe.options import DEFAULT_BUILD_OPTIONS

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"


def write_sphere_obj(path: Path) -> None:
    """An icosphere (1280 triangles): enough for LOD levels."""
    m = trimesh.creation.icosphere(subdivisions=3)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in m.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in m.faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def project(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(EXAMPLES / "crate", src / "crate")
    shutil.copytree(EXAMPLES / "pyramid", src / "pyramid")
    (src / "sphere").mkdir()
    write_sphere_obj(src / "sphere" / "sphere.obj")
    return tmp_path


def build(project: Path, options=DEFAULT_BUILD_OPTIONS, jobs: int = 1, out: str = "out"):
    return run_build([project / "src"], project / out, options, jobs=jobs, cache_dir=project / "cache")


def ran(report) -> set[tuple[str, str]]:
    """(asset id, step kind) of every step that ran."""
    return {(r.id, s["step"].split(" ")[0]) for r in report.results for s in r.steps if s["ran"]}


def touch_later(path: Path) -> None:
    """Make sure an edit changes the mtime even on coarse-timestamp file systems."""
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000_000))


def outputs(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*")
            if p.is_file() and ".assetpipe" not in p.parts}


def test_first_build_runs_everything_and_a_rebuild_nothing(project):
    first = build(project)
    assert [r.status for r in first.results] == ["built"] * 3
    assert {k for _, k in ran(first)} == {"import", "mesh", "texture", "lod", "encode"}
    again = build(project)
    assert [r.status for r in again.results] == ["cached"] * 3
    assert ran(again) == set()
    assert all(r.reason == "up to date" for r in again.results)


def test_source_edit_reruns_that_model_only(project):
    build(project)
    gltf = project / "src/crate/crate.gltf"
    doc = json.loads(gltf.read_text())
    doc["nodes"][0]["translation"] = [0.0, 2.0, 0.0]
    gltf.write_text(json.dumps(doc))
    touch_later(gltf)
    r = build(project)
    assert ran(r) == {("crate", "import"), ("crate", "mesh"), ("crate", "lod"), ("crate", "encode")}
    assert {x.id: x.status for x in r.results} == {"crate": "built", "pyramid": "cached", "sphere": "cached"}


def test_bin_edit_is_seen_through_the_import_dependencies(project):
    build(project)
    b = project / "src/crate/crate.bin"
    data = bytearray(b.read_bytes())
    pos_start = 36 * 2  # after 36 uint16 indices: the first position's x
    data[pos_start:pos_start + 4] = np.float32(0.75).tobytes()
    b.write_bytes(bytes(data))
    touch_later(b)
    r = build(project)
    assert ran(r) == {("crate", "import"), ("crate", "mesh"), ("crate", "lod"), ("crate", "encode")}
    crate = next(x for x in r.results if x.id == "crate")
    assert any("crate.bin" in s.get("reason", "") for s in crate.steps if s["step"] == "import")


def test_texture_edit_reruns_only_that_texture_and_its_model_encode(project):
    build(project)
    png = project / "src/crate/crate.png"
    from PIL import Image

    img = Image.open(png).convert("RGB")
    img.putpixel((0, 0), (255, 0, 0))
    img.save(png)
    touch_later(png)
    r = build(project)
    assert ran(r) == {("crate", "texture"), ("crate", "encode")}


def test_mtl_edit_reruns_import_and_encode_not_geometry(project):
    build(project)
    mtl = project / "src/pyramid/pyramid.mtl"
    mtl.write_text(mtl.read_text().replace("Kd 1 1 1", "Kd 1 0.5 0.5"))
    touch_later(mtl)
    r = build(project)
    assert ran(r) == {("pyramid", "import"), ("pyramid", "encode")}
    mats = json.loads((project / "out/pyramid-mat.json").read_text())
    assert mats[0]["color"] == [1.0, 0.5, 0.5, 1.0]


def test_lod_option_change_reruns_lod_not_import_or_textures(project):
    build(project)
    opts = dataclasses.replace(DEFAULT_BUILD_OPTIONS, lod=dataclasses.replace(DEFAULT_BUILD_OPTIONS.lod,
                                                                              ratios=(1.0, 0.3)))
    r = build(project, opts)
    kinds = ran(r)
    assert {k for _, k in kinds} == {"lod", "encode"}
    # the tiny models get no coarser level either way: their LOD output is the same, so
    # their encode step is not rerun; the sphere's is
    assert ("sphere", "encode") in kinds and ("crate", "encode") not in kinds
    side = json.loads((project / "out/sphere.asset.json").read_text())
    assert [l["triangles"] for l in side["meshes"][0]["lods"]] == [1280, 384]


def test_texture_option_change_reruns_textures_only(project):
    build(project)
    opts = dataclasses.replace(DEFAULT_BUILD_OPTIONS, texture=dataclasses.replace(DEFAULT_BUILD_OPTIONS.texture,
                                                                                  max_size=64))
    r = build(project, opts)
    assert {k for _, k in ran(r)} == {"texture", "encode"}
    assert {i for i, _ in ran(r)} == {"crate", "pyramid"}


def test_step_version_change_reruns_that_step(project, monkeypatch):
    build(project)
    monkeypatch.setitem(versions.STEP_VERSIONS, "texture", versions.STEP_VERSIONS["texture"] + 1)
    r = build(project)
    # same texture output, so nothing after the texture step reruns
    assert ran(r) == {("crate", "texture"), ("pyramid", "texture")}
    crate = next(x for x in r.results if x.id == "crate")
    assert any("step version changed" in s.get("reason", "") for s in crate.steps if s["ran"])


def test_a_shared_texture_is_processed_once(project, monkeypatch):
    shutil.copytree(project / "src/crate", project / "src/crate2")
    (project / "src/crate2/crate.gltf").rename(project / "src/crate2/other.gltf")
    calls = []
    real = steps.task_texture
    monkeypatch.setattr(steps, "task_texture", lambda *a: calls.append(a) or real(*a))
    r = build(project)
    assert all(x.status == "built" for x in r.results)
    assert sum(1 for c in calls if c[1]["name"] == "crate.png") == 1
    a = json.loads((project / "out/crate-mat.json").read_text())[0]["texturePath"]
    b = json.loads((project / "out/other-mat.json").read_text())[0]["texturePath"]
    assert a == b


def test_outputs_are_byte_identical_for_j1_and_j2(project):
    r1 = run_build([project / "src"], project / "o1", DEFAULT_BUILD_OPTIONS, jobs=1, cache_dir=project / "c1")
    r2 = run_build([project / "src"], project / "o2", DEFAULT_BUILD_OPTIONS, jobs=2, cache_dir=project / "c2")
    assert not r1.failed and not r2.failed
    o1, o2 = outputs(project / "o1"), outputs(project / "o2")
    assert o1.keys() == o2.keys() and o1 == o2


def test_a_corrupt_blob_is_dropped_and_rebuilt(project):
    build(project)
    reference = outputs(project / "out")
    objects = sorted((project / "cache/objects").rglob("*"))
    blobs = [p for p in objects if p.is_file()]
    for p in blobs:  # corrupt every blob: flip a byte / truncate
        data = p.read_bytes()
        p.write_bytes(data[:-1] if len(data) > 1 else b"x")
    shutil.rmtree(project / "out")
    r = build(project)
    assert not r.failed
    assert r.cache_dropped, "corrupt entries must be reported"
    assert outputs(project / "out") == reference


def test_hand_edited_and_deleted_outputs_are_restored(project):
    build(project)
    reference = outputs(project / "out")
    (project / "out/crate.json").write_text("{}")
    (project / "out/pyramid.vtx").unlink()
    r = build(project)
    assert outputs(project / "out") == reference
    crate = next(x for x in r.results if x.id == "crate")
    assert "crate.json" in crate.reason and crate.status == "cached"


def test_outputs_of_removed_and_renamed_sources_are_removed(project):
    build(project)
    shutil.rmtree(project / "src/pyramid")
    (project / "src/sphere/sphere.obj").rename(project / "src/sphere/ball.obj")
    r = build(project)
    names = set(outputs(project / "out"))
    assert not any(n.startswith("pyramid") for n in names)
    assert not any(n.startswith("sphere") for n in names)
    assert {"ball.json", "crate.json"} <= names
    assert "pyramid.json" in r.removed and "sphere.json" in r.removed
    # the pyramid's texture file went with it; the crate's stays
    tex = {n for n in names if n.startswith("textures/")}
    crate_mat = json.loads((project / "out/crate-mat.json").read_text())[0]["texturePath"]
    assert crate_mat in tex and len([t for t in tex if t.endswith(".ktx2")]) == 1


def test_noop_does_not_import_heavy_modules(project):
    build(project)
    code = ("import sys, assetpipe.build as b; from pathlib import Path;"
            "from assetpipe.options import DEFAULT_BUILD_OPTIONS as O;"
            "heavy0 = {m for m in ('numpy', 'PIL', 'pygltflib', 'cv2', 'vulkan', 'assetpipe.renderer') if m in sys.modules};"
            f"r = b.run_build([Path({str(project / 'src')!r})], Path({str(project / 'out')!r}), O,"
            f" cache_dir=Path({str(project / 'cache')!r}));"
            "assert all(x.status == 'cached' for x in r.results), [x.reason for x in r.results];"
            "heavy = {m for m in ('numpy', 'pygltflib', 'PIL', 'cv2', 'vulkan', 'assetpipe.renderer', 'assetpipe.pipelines.import_gltf', 'trimesh',"
            " 'assetpipe.cache.remote') if m in sys.modules};"
            "print(sorted(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_cli_noop_imports_only_what_it_uses(project):
    """The CLI's no-op build imports neither the other commands' modules (renderer, cache CLI:
    loaded when named) nor tempfile, shutil and traceback (5-8 ms of a 100 ms no-op: imported
    where a file is written through them or a step fails). It still writes its lookups
    (``cache stats``), under a name of its own."""
    build(project)
    # every file older than the stat cache's racy window, and one no-op to remember them: the
    # checked no-op then hashes nothing and saves nothing
    old = time.time() - 3600
    for f in [*(project / "src").rglob("*"), *(project / "out").rglob("*")]:
        os.utime(f, (old, old))
    subprocess.run(_cli(project), capture_output=True, check=True, cwd=REPO)
    argv = ["assetpipe", "build", str(project / "src"), "-o", str(project / "out"), "--cache",
            str(project / "cache"), "-q"]
    # main() as the script's entry (cli.run) calls it, but returning here: run() ends the
    # process with os._exit, before anything could be printed
    code = "\n".join([
        "import sys",
        f"sys.argv = {argv!r}",
        "from assetpipe.cli import main",
        "try:",
        "    main()",
        "except SystemExit:",
        "    pass",
        "print(sorted(m for m in ('tempfile', 'shutil', 'traceback', 'assetpipe.renderer',",
        "                         'assetpipe.cache_cli', 'numpy') if m in sys.modules))"])
    before = (project / "cache" / "last-build.json").stat().st_mtime_ns
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
    assert " cached in " in out.stdout, out.stdout
    last = project / "cache" / "last-build.json"
    assert last.stat().st_mtime_ns > before and "lookups" in json.loads(last.read_text())
    assert not list((project / "cache").glob(".tmp-*")), "a temporary file was left"


def _cli(project: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "assetpipe.cli", "build", str(project / "src"), "-o", str(project / "out"),
            "--cache", str(project / "cache"), "-q", *extra]


def test_concurrent_builds_both_succeed_with_identical_outputs(project):
    reference_dir = project / "ref"
    run_build([project / "src"], reference_dir, DEFAULT_BUILD_OPTIONS, cache_dir=project / "refcache")
    procs = [subprocess.Popen(_cli(project), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=REPO)
             for _ in range(2)]
    codes = [p.wait(timeout=300) for p in procs]
    assert codes == [0, 0], [p.stdout.read().decode() for p in procs]
    assert outputs(project / "out") == outputs(reference_dir)


@pytest.mark.parametrize("delay", [0.3, 0.8, 1.5])
def test_a_killed_build_leaves_no_partial_output_and_the_next_one_completes(project, delay):
    reference_dir = project / "ref"
    run_build([project / "src"], reference_dir, DEFAULT_BUILD_OPTIONS, cache_dir=project / "refcache")
    p = subprocess.Popen(_cli(project), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
    time.sleep(delay)
    p.send_signal(signal.SIGKILL)
    p.wait()
    out = project / "out"
    if out.exists():
        # every visible output is a complete file: its bytes are a blob of the store
        for rel, data in outputs(out).items():
            assert (project / "cache/objects").exists()
            from assetpipe.core.hashing import digest_bytes
            d = digest_bytes(data).split(":")[1]
            assert (project / "cache/objects" / d[:2] / d[2:]).is_file(), rel
    r = subprocess.run(_cli(project), capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stdout + r.stderr
    assert outputs(out) == outputs(reference_dir)
