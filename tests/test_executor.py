"""assetpipe.executor without a cluster: a worker's allocator settings (step_malloc).

Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``; glibc then keeps its mmap
threshold fixed at 128 KiB, so every larger array is a fresh mmap whose pages fault in one by
one. These tests run a fresh interpreter with that environment (as a Dask worker has it) and
count the minor page faults of allocating, filling and freeing a 1 MiB array 100 times (1 MiB:
above the 128 KiB threshold, below the 4 MiB from which numpy asks for huge pages).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROUNDS = 100
PAGES = 2**20 // 4096  # pages of one 1 MiB array (4 KiB pages): what a fresh mapping faults in

PROBE = f"""
import json, resource, numpy as np
from assetpipe import executor

def faults():
    np.ones(1 << 17).sum()  # warm: numpy and the first mapping
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range({ROUNDS}):
        np.ones(1 << 17).sum()  # 1 MiB, written, freed
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

before = faults()
did = executor.step_malloc()
print(json.dumps({{"before": before, "after": faults(), "did": did, "again": executor.step_malloc()}}))
"""


def _probe(env_extra: dict) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env.update(env_extra, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's MALLOC_*_ variables: Linux only")
def test_step_malloc_undoes_dasks_fixed_trim_threshold():
    r = _probe({"MALLOC_TRIM_THRESHOLD_": "65536"})
    # the premise: with Dask's setting, each round maps the array afresh and faults in all its pages
    assert r["before"] >= ROUNDS * PAGES, r
    # after: the heap keeps the freed array and the next round reuses it; allow a few arrays'
    # worth of faults (numpy's and the interpreter's own allocations in between)
    assert r["after"] <= 4 * PAGES, r
    assert "MALLOC_TRIM_THRESHOLD_ in the environment" in r["did"] and "mmap threshold 32 MiB" in r["did"]
    assert r["again"] == r["did"]  # once per process


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's MALLOC_*_ variables: Linux only")
def test_step_malloc_leaves_glibc_defaults_alone():
    r = _probe({})
    assert r["did"] == "glibc defaults (adaptive)"
    # glibc's adaptive threshold already rose past 1 MiB at the warm-up's free: no fresh mappings
    assert r["before"] <= 4 * PAGES and r["after"] <= 4 * PAGES, r
