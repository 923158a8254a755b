"""A long fuzzing run of the importers and the image decoder (issue #13).

    .venv/bin/python benchmarks/fuzz.py [--quick] [--cases 3000] [--seed 0] [--builds 30] [--report fuzz.json]

Runs ``tests/fuzz_inputs.py`` (hypothesis-generated and mutated glTF/GLB, OBJ+MTL and PNG
inputs, a third each) in a subprocess that limits its own address space and every case's
time, and prints the number of cases per outcome: ``built``, ``warning``, ``error`` (one clear
AssetError line naming the file) and the failures ``internal``, ``timeout``, ``memory``; for
``--builds`` of the model cases, the real ``assetpipe build`` with a good model beside the bad
one (``build-ok``: exit 0 or 1, the good model built, no internal error). ``--report`` keeps
every failing input (base64) to reproduce it. Exit status 1 when any case failed.

The CI-sized run (300 cases, 4 builds) is ``tests/test_fuzz.py``; a different ``--seed``
gives different cases, the same seed the same ones.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--builds", type=int, default=30)
    ap.add_argument("--report", type=Path, default=None)
    ap.add_argument("--quick", action="store_true", help="the CI size: 300 cases, 3 builds")
    args = ap.parse_args()
    if args.quick:
        args.cases, args.builds = 300, 3
    cmd = [sys.executable, str(ROOT / "tests" / "fuzz_inputs.py"), "--cases", str(args.cases),
           "--seed", str(args.seed), "--builds", str(args.builds)]
    if args.report:
        cmd += ["--report", str(args.report.resolve())]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    print(proc.stdout, end="")
    print(f"{time.perf_counter() - t0:.1f} s")
    if proc.returncode not in (0, 1):
        print(f"the fuzzing process itself died (exit {proc.returncode})")
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
