"""Kill and crash safety (#13): a real ``-j 2`` build killed with SIGKILL at random points,
several times. No worker outlives it; the next build finishes with outputs byte-identical to a
clean build; the cache verifies."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import time
from pathlib import Path

import pytest

from robust_models import (assert_same_outputs, cli_cmd, cli_env, make_inputs, output_bytes, run_cli,
                           verify_cache)

KILLS = 4


def _children(pid: int) -> set[int]:
    """Every live descendant of ``pid`` (from /proc)."""
    parent: dict[int, int] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            stat = Path(f"/proc/{d}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z":
            parent[int(d)] = int(fields[1])
    out, frontier = set(), {pid}
    while frontier:
        frontier = {c for c, p in parent.items() if p in frontier} - out
        out |= frontier
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2:].split()[0] != "Z"  # a zombie has exited


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux) to list the workers")
def test_sigkilled_builds_leave_no_worker_and_the_next_build_is_byte_identical(tmp_path):
    src = make_inputs(tmp_path / "src", n_obj=2, n_gltf=2)
    env = cli_env()
    t0 = time.perf_counter()
    clean = run_cli("build", src, "-o", tmp_path / "clean", "--cache", tmp_path / "clean-cache", "-j", "2", env=env)
    clean_s = time.perf_counter() - t0
    assert clean.returncode == 0, clean.stderr
    want = output_bytes(tmp_path / "clean")

    out, cache = tmp_path / "out", tmp_path / "cache"
    rng = random.Random(13)  # fixed: a failure reproduces
    killed_with_workers = 0
    for k in range(KILLS):
        proc = subprocess.Popen(cli_cmd("build", src, "-o", out, "--cache", cache, "-j", "2"), env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # a point in the first 90% of a clean build's time: import, mesh, textures, lod, encode, writing
        deadline = time.monotonic() + rng.uniform(0.15, 0.9) * clean_s
        workers: set[int] = set()
        while time.monotonic() < deadline and proc.poll() is None:
            workers |= _children(proc.pid)
            time.sleep(0.02)
        workers |= _children(proc.pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        killed_with_workers += bool(workers)
        # workers die with the build: PR_SET_PDEATHSIG at once, the parent watch within 1 s
        limit = time.monotonic() + 5.0
        while time.monotonic() < limit and any(_alive(w) for w in workers):
            time.sleep(0.05)
        survivors = [w for w in workers if _alive(w)]
        for w in survivors:  # do not leave them behind even when the check fails
            os.kill(w, signal.SIGKILL)
        assert not survivors, f"kill {k}: workers {survivors} outlived the killed build"
    assert killed_with_workers >= 2, "the kills never caught the build with its workers running"

    final = run_cli("build", src, "-o", out, "--cache", cache, "-j", "2", env=env)
    assert final.returncode == 0, final.stderr
    assert_same_outputs(output_bytes(out), want, "after 4 SIGKILLs")
    blobs, records = verify_cache(cache)
    assert blobs > 0 and records > 0
    # and a no-op build after it agrees that everything is in place
    again = run_cli("build", src, "-o", out, "--cache", cache, "--json", tmp_path / "r.json", env=env)
    assert again.returncode == 0, again.stderr
    import json

    counts = json.loads((tmp_path / "r.json").read_text())["counts"]
    assert counts == {"cached": 4}, counts
