"""Run every benchmark in benchmarks/, one after another, each in its own subprocess.

    .venv/bin/python benchmarks/run_all.py [--quick] [--only import,incremental] [--skip validate]

Order: import.py, incremental.py, then the other ``benchmarks/*.py`` scripts by name (mips.py,
lod.py, validate.py, ...; this runner, files starting with ``_`` and modules without a
``__main__`` block, such as the generated models of cad_models.py, are not benchmarks).
``--quick`` is passed to the scripts that accept it (those whose source defines a ``--quick``
option); the others run with their defaults. Each script's output streams through under a
header; a summary of exit codes follows. Benchmarks run one at a time, never in parallel, so
they do not disturb each other's timings. Exit code 1 if any benchmark failed.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
FIRST = ("import.py", "incremental.py")


def _is_script(p: Path) -> bool:
    """A benchmark runs as a script; a module of generated models the others import
    (cad_models.py, unseen_models.py) has no ``__main__`` block and is not run."""
    return '__name__ == "__main__"' in p.read_text(encoding="utf-8", errors="replace")


def benchmarks() -> list[Path]:
    scripts = [p for p in HERE.glob("*.py")
               if p.name != Path(__file__).name and not p.name.startswith("_") and _is_script(p)]
    return sorted(scripts, key=lambda p: (FIRST.index(p.name) if p.name in FIRST else len(FIRST), p.name))


def supports_quick(script: Path) -> bool:
    return '"--quick"' in script.read_text(encoding="utf-8", errors="replace")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="pass --quick to the benchmarks that support it")
    ap.add_argument("--only", help="comma-separated benchmark names (without .py)")
    ap.add_argument("--skip", default="", help="comma-separated benchmark names to leave out")
    ap.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    args = ap.parse_args()
    only = set(args.only.split(",")) if args.only else None
    skip = set(filter(None, args.skip.split(",")))
    todo = [p for p in benchmarks() if (only is None or p.stem in only) and p.stem not in skip]
    if args.list:
        for p in todo:
            print(f"{p.name:20s} {'--quick' if supports_quick(p) else ''}")
        return 0
    if not todo:
        print("no benchmark selected")
        return 1

    results = []
    for i, script in enumerate(todo, 1):
        cmd = [sys.executable, str(script)] + (["--quick"] if args.quick and supports_quick(script) else [])
        title = f" [{i}/{len(todo)}] {script.name} {' '.join(cmd[2:])}".rstrip() + " "
        print(f"\n{title:=^100}", flush=True)
        t0 = time.perf_counter()
        try:
            rc = subprocess.run(cmd, cwd=HERE.parent).returncode
        except KeyboardInterrupt:
            print(f"\n{script.name}: interrupted")
            rc = 130
        results.append((script.name, rc, time.perf_counter() - t0))
        if rc == 130:
            break

    print(f"\n{' summary ':=^100}")
    for name, rc, secs in results:
        print(f"{name:20s} {'ok' if rc == 0 else f'FAILED (exit {rc})':18s} {secs:8.1f} s")
    return 0 if all(rc == 0 for _, rc, _ in results) else 1


if __name__ == "__main__":
    sys.exit(main())
