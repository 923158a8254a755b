"""Scene build against building the whole folder it draws from (project issue 7).

A scene placing a few corpus models (at limited view distances and screen sizes) is built
into a fresh cache, and so is the whole ``$ASSETPIPE_CORPUS/models`` folder (default
``../shared/corpus/models``); both through the
real CLI as subprocesses, interleaved, median of N cold runs each. Printed: wall times, their
ratio, and what the scene build skipped (models, LOD levels, mip levels, attributes).

    .venv/bin/python benchmarks/scene.py [--repeats 3] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS") or REPO.parent / "shared" / "corpus") / "models"
CLI = [sys.executable, "-m", "assetpipe.cli", "build"]


def scene_doc() -> dict:
    m = CORPUS
    return {"scene": {"ambient_light": [1, 1, 1, 0.2], "texture_budget": 512, "objects": [
        {"model": {"name": str(m / "Duck/glTF/Duck.gltf")}, "view_distance": [2, 40],
         "instances": [[{"translation": [0, 0, -5]}], [{"translation": [3, 0, -8]}, {"rotationY": 45}]]},
        {"model": {"name": str(m / "Avocado/glTF/Avocado.gltf")}, "max_screen_px": 128,
         "instances": [[{"translation": [-2, 0, -4]}, {"scaling": [20, 20, 20]}]]},
        {"model": {"name": str(m / "stanford-bunny/stanford-bunny.obj"), "lod": {"ratios": [1, 0.25, 0.0625]}},
         "view_distance": [5, 200], "instances": [[{"translation": [0, 0, -20]}]]},
    ]}}


def run(args: list[str]) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        r = subprocess.run(CLI + args + ["-o", f"{tmp}/out", "--cache", f"{tmp}/cache", "-q",
                                         "--json", f"{tmp}/report.json"], capture_output=True, text=True, cwd=REPO)
        dt = time.perf_counter() - t0
        if r.returncode != 0:
            raise SystemExit(f"build failed: {r.stdout}{r.stderr}")
        return dt, json.loads(Path(f"{tmp}/report.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="one run each")
    opts = ap.parse_args()
    repeats = 1 if opts.quick else opts.repeats
    work = Path(tempfile.mkdtemp(prefix="assetpipe-bench-scene-"))
    try:
        scene = work / "level.json"
        scene.write_text(json.dumps(scene_doc()))
        scene_times, folder_times = [], []
        scene_report = folder_report = None
        for _ in range(repeats):  # interleaved: the machine's load hits both alike
            t, scene_report = run([str(scene), str(CORPUS)])
            scene_times.append(t)
            t, folder_report = run([str(CORPUS)])
            folder_times.append(t)
        s, f = statistics.median(scene_times), statistics.median(folder_times)
        counts = scene_report["counts"]
        print(f"scene build (3 objects, corpus folder as candidates): median {s:.2f} s over {repeats} cold run(s)")
        print(f"whole folder build ({folder_report['counts']}): median {f:.2f} s")
        print(f"scene / folder: {s / f:.3f}x  ({counts})")
        print("what the scene build skipped:")
        for a in scene_report["assets"]:
            if a["status"] == "skipped" or a["source"] == str(scene):  # the scene repeats its models'
                continue
            for line in a.get("skipped", []):
                print(f"  {line}")
        n_unref = sum(1 for a in scene_report["assets"] if a["status"] == "skipped")
        print(f"  {n_unref} model files: not built: no scene references them")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
