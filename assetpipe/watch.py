"""``assetpipe watch``: rebuild what changed when a source is saved.

The folders of the inputs (and of every source a build read: scene models, .bin, .mtl and
images elsewhere) are watched with watchfiles (Rust ``notify``: inotify here). A burst of writes
(an exporter writing .gltf, .bin and textures, an editor's save through a temporary file) is
coalesced into one rebuild: watchfiles waits until no change arrived for ``debounce_ms``. Each
rebuild is an ordinary incremental build, so only the assets whose inputs changed rerun. A bad
save fails that asset with its one-line error; the last good outputs stay in place (a build
never touches the outputs of an asset that fails), and watching goes on. With ``preview``, the
contact sheet of every rebuilt model is rendered again (``OUT/ID-preview.png``), in a
subprocess, so a driver fault cannot end the watch.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from assetpipe.build_types import BuildReport
from assetpipe.core.errors import AssetpipeError

DEFAULT_DEBOUNCE_MS = 300


@dataclass
class WatchEvent:
    """One rebuild: what triggered it (changed paths; empty for the first build) and its report."""

    changed: list[str]
    report: BuildReport
    previews: list[str]
    error: str | None = None  # the build could not run at all (the cache or output folder unusable)


def _watched_folders(inputs: list[Path], report: BuildReport | None) -> set[Path]:
    folders = set()
    for p in inputs:
        p = Path(os.path.abspath(p))
        folders.add(p if p.is_dir() else p.parent)
    for r in (report.results if report else []):
        src = Path(os.path.abspath(r.source))
        if src.parent.is_dir():
            folders.add(src.parent)
    # a folder inside another watched one is watched already (recursively)
    return {f for f in folders if not any(o != f and o in f.parents for o in folders)}


def _preview(model_json: Path) -> str:
    out = model_json.with_name(model_json.name[: -len(".json")] + "-preview.png")
    r = subprocess.run([sys.executable, "-m", "assetpipe.cli", "preview", str(model_json), "-o", str(out)],
                       capture_output=True, text=True)
    return str(out) if r.returncode == 0 else f"preview of {model_json.name} failed: {(r.stderr or r.stdout).strip()}"


def watch(inputs: list[Path], out_dir: Path, options, *, jobs: int = 1, cache_dir: Path | None = None,
          preview: bool = False, debounce_ms: int = DEFAULT_DEBOUNCE_MS,
          on_build: Callable[[WatchEvent], None] | None = None,
          on_ready: Callable[[list[Path]], None] | None = None,
          stop_event: threading.Event | None = None) -> None:
    """Build, then rebuild on every (coalesced) change until ``stop_event`` is set or Ctrl-C.

    ``on_build(event)`` after every rebuild; ``on_ready(folders)`` once the watcher runs (saves
    made before that are caught up then: the first build's outputs are checked again)."""
    import watchfiles

    from assetpipe.build import run_build

    inputs = [Path(p) for p in inputs]
    out_abs = Path(os.path.abspath(out_dir))
    stop = stop_event or threading.Event()

    def keep(change, path: str) -> bool:  # not our own outputs, nor editors' swap and backup files
        p = Path(path)
        if p == out_abs or out_abs in p.parents:
            return False
        return watchfiles.DefaultFilter()(change, path)

    def rebuild(changed: list[str]) -> BuildReport:
        try:
            report = run_build(inputs, out_dir, options, jobs=jobs, cache_dir=cache_dir)
        except (AssetpipeError, OSError) as exc:  # the build as a whole (cache, output folder): say so, go on
            report = BuildReport(results=[], seconds=0.0)
            if on_build:
                on_build(WatchEvent(changed=changed, report=report, previews=[], error=str(exc)))
            return report
        previews = []
        if preview:
            for r in report.results:
                if r.status == "built" and r.outputs:
                    previews.append(_preview(Path(r.outputs[0])))
        if on_build:
            on_build(WatchEvent(changed=changed, report=report, previews=previews))
        return report

    report = rebuild([])
    while not stop.is_set():
        folders = _watched_folders(inputs, report)
        restart, ready = False, False
        # a change, then debounce_ms of quiet: one rebuild (a burst never waits longer than 10x that)
        for changes in watchfiles.watch(*folders, watch_filter=keep, debounce=max(10 * debounce_ms, 2000),
                                        step=debounce_ms, stop_event=stop, rust_timeout=500, yield_on_timeout=True):
            if stop.is_set():
                return
            if not ready:  # the watcher runs now: catch up with saves made before it started
                ready = True
                try:
                    catch_up = run_build(inputs, out_dir, options, jobs=jobs, cache_dir=cache_dir).counts()
                except (AssetpipeError, OSError):
                    catch_up = {}  # reported by the build before; the next save tries again
                if catch_up.keys() - {"cached", "skipped"}:
                    report = rebuild(["(saved before the watch started)"])
                if on_ready:
                    on_ready(sorted(folders))
            if not changes:
                continue
            report = rebuild(sorted({p for _, p in changes}))
            if _watched_folders(inputs, report) != folders:  # a source moved elsewhere: watch its folder
                restart = True
                break
        if not restart:
            return
