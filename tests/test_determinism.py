"""Deterministic outputs (#13): whatever ran before (a cold or warm cache, a cache warmed by
another set of inputs, ``-j 1`` or ``-j 2``, builds running at once into one output folder),
every output file is byte-identical to a clean build's."""

from __future__ import annotations

import json
import shutil
import subprocess

from robust_models import assert_same_outputs, cli_cmd, cli_env, make_inputs, output_bytes, run_cli


def _build(*args, env):
    r = run_cli("build", *args, env=env)
    assert r.returncode == 0, r.stderr + r.stdout
    return r


def test_outputs_do_not_depend_on_cache_state_jobs_or_concurrency(tmp_path):
    src = make_inputs(tmp_path / "src", n_obj=2, n_gltf=2)
    env = cli_env()
    _build(src, "-o", tmp_path / "ref", "--cache", tmp_path / "c-ref", "-j", "1", env=env)
    want = output_bytes(tmp_path / "ref")
    sidecar = json.loads(want["tex0.asset.json"])
    # the material lists its three textures in sorted role order, whichever step finished first
    assert list(sidecar["materials"][0]["textures"]) == ["baseColor", "metallicRoughness", "normal"]

    # a cache warmed by part of the inputs under other names: the import, mesh, texture and LOD
    # steps of tex0 and ball0 come from it (their keys are content), their encode steps (keyed
    # by the id too) and every step of the others run fresh
    part = tmp_path / "part"
    part.mkdir()
    for name, to in (("tex0.gltf", "renamed.gltf"), ("tex0.bin", "tex0.bin"), ("tex0-base.png", "tex0-base.png"),
                     ("tex0-normal.png", "tex0-normal.png"), ("tex0-mr.png", "tex0-mr.png"), ("ball0.obj", "b.obj")):
        shutil.copy(src / name, part / to)
    _build(part, "-o", tmp_path / "scratch", "--cache", tmp_path / "c", "-j", "2", env=env)
    _build(src, "-o", tmp_path / "warm-part", "--cache", tmp_path / "c", "-j", "2", env=env)
    assert_same_outputs(output_bytes(tmp_path / "warm-part"), want, "cache warmed by part of the inputs, -j 2")

    # everything from the cache, -j 1
    _build(src, "-o", tmp_path / "warm", "--cache", tmp_path / "c", "-j", "1", env=env)
    assert_same_outputs(output_bytes(tmp_path / "warm"), want, "warm cache, -j 1")

    # two builds at once into one output folder and a cold cache, the inputs named in other
    # orders, -j 1 and -j 2; then two builds of different inputs at once into another
    files = sorted(p for p in src.iterdir() if p.suffix in (".obj", ".gltf"))
    runs = [(["build", src, "-o", tmp_path / "both", "--cache", tmp_path / "c2", "-j", "2"]),
            (["build", *reversed(files), "-o", tmp_path / "both", "--cache", tmp_path / "c2", "-j", "1"]),
            (["build", *[f for f in files if f.suffix == ".obj"], "-o", tmp_path / "split", "--cache", tmp_path / "c3"]),
            (["build", *[f for f in files if f.suffix == ".gltf"], "-o", tmp_path / "split", "--cache", tmp_path / "c3",
              "-j", "2"])]
    procs = [subprocess.Popen(cli_cmd(*args), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for args in runs]
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err + out
    assert_same_outputs(output_bytes(tmp_path / "both"), want, "two concurrent builds into one folder")
    assert_same_outputs(output_bytes(tmp_path / "split"), want, "concurrent builds of different inputs")
    # neither concurrent build lost the other's sources: the whole folder is a no-op now
    state = json.loads((tmp_path / "split" / ".assetpipe" / "state.json").read_text())
    assert sorted(e["id"] for e in state["assets"].values()) == ["ball0", "ball1", "tex0", "tex1"]
    _build(src, "-o", tmp_path / "split", "--cache", tmp_path / "c3", "--json", tmp_path / "r.json", env=env)
    assert json.loads((tmp_path / "r.json").read_text())["counts"] == {"cached": 4}
