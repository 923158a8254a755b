"""The CI-sized fuzzing run (issue #13): hypothesis-generated and mutated glTF/GLB, OBJ+MTL and
PNG inputs through the importers and the image decoder, and a slice of them through the real
``assetpipe build`` beside a good model. The long run is ``benchmarks/fuzz.py``.

The cases run in a subprocess that limits its own address space and each case's time
(``tests/fuzz_inputs.py``), so a memory blow-up or a hang is a reported outcome.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.timeout(240)
def test_fuzz_ci_run_has_no_internal_error_hang_or_memory_blow_up(tmp_path: Path) -> None:
    report = tmp_path / "fuzz.json"
    cases, builds = 300, 3
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(ROOT / "tests" / "fuzz_inputs.py"), "--cases", str(cases),
                           "--seed", "0", "--builds", str(builds), "--report", str(report)],
                          env=env, capture_output=True, text=True, timeout=230)
    assert report.exists(), proc.stdout + proc.stderr[-3000:]
    result = json.loads(report.read_text())
    counts = result["cases"]
    print(proc.stdout)
    # every case was run and ended in one of the expected outcomes
    assert sum(sum(counts[k].values()) for k in ("gltf", "obj", "png", "jpeg")) == cases
    assert counts["build"] == {"build-ok": builds}, result["failures"]
    assert not result["failures"], "\n".join(f"{f['kind']} {f['outcome']}: {f['detail']}" for f in result["failures"])
    assert proc.returncode == 0
    # the generators reach past the first check: some inputs of every kind build, and glTF/OBJ
    # produce warnings too (a generator that only made garbage would test one error path)
    for kind in ("gltf", "obj", "png", "jpeg"):
        assert counts[kind].get("built", 0) + counts[kind].get("warning", 0) > 0, counts
