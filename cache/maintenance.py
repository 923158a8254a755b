"""Cache statistics and collection (``assetpipe cache stats`` / ``gc``, and the automatic limit).

What a collection may delete: step records (``actions/``) and blobs (``objects/``), least
recently used first (a record's mtime is its last use: the store touches it on every hit; a
blob lives as long as a kept record names it). What it never deletes:

* the blobs of the current outputs of every output folder built with this cache (``outputs/``
  registers them; each folder's ``.assetpipe/state.json`` names its outputs' blobs), and the
  records of the steps that made them (``explain.json`` holds their key inputs): so the current
  outputs still build as a no-op, and an output deleted or edited by hand is restored from the
  cache without rerunning a step;
* anything used since the oldest running build started (``builds/`` holds one locked file per
  running build), or within the last ``GRACE_S`` seconds: a build running meanwhile never loses
  a record it found or a blob it has just written. Each victim's mtime is checked again right
  before it is deleted.

The automatic limit: after a build that wrote to the cache, when the cache holds more than
``$ASSETPIPE_CACHE_MAX_SIZE`` (default :data:`DEFAULT_MAX_SIZE`, 10 GiB; ``0`` turns it off), a
collection brings it down to 80% of the limit.
"""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

from assetpipe.core.hashing import digest_json
from assetpipe.core.state_file import read_json_dict

DEFAULT_MAX_SIZE = 10 * 1024 ** 3
MAX_SIZE_ENV = "ASSETPIPE_CACHE_MAX_SIZE"
AUTO_TARGET = 0.8  # an automatic collection goes down to this fraction of the limit
GRACE_S = 600.0  # entries used this recently are kept even with no registered build running
_UNITS = {"": 1, "b": 1, "k": 1024, "m": 1024 ** 2, "g": 1024 ** 3, "t": 1024 ** 4}
_AGE_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}


def parse_size(text: str) -> int:
    """'500M', '2G', '1.5g', '1024' (bytes), '10GiB' -> bytes."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmgt]?)(?:i?b)?\s*", str(text).lower())
    if not m:
        raise ValueError(f"not a size: {text!r} (e.g. 500M, 2G)")
    return int(float(m.group(1)) * _UNITS[m.group(2)])


def parse_age(text: str) -> float:
    """'30d', '12h', '90m', '45s', '2w' -> seconds."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smhdw])\s*", str(text).lower())
    if not m:
        raise ValueError(f"not an age: {text!r} (e.g. 30d, 12h, 90m)")
    return float(m.group(1)) * _AGE_UNITS[m.group(2)]


def human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(n) < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def max_size_setting() -> int:
    """The automatic limit in bytes (0: none), from ``$ASSETPIPE_CACHE_MAX_SIZE``."""
    text = os.environ.get(MAX_SIZE_ENV)
    if not text:
        return DEFAULT_MAX_SIZE
    try:
        return parse_size(text)
    except ValueError:
        return DEFAULT_MAX_SIZE


@dataclass
class _Entry:
    path: Path
    size: int  # bytes on disk this entry frees when deleted (0 for a blob an output still links)
    mtime: float
    blobs: tuple = ()


@dataclass
class CacheStats:
    root: Path
    size: int = 0  # bytes of records and blobs (a blob hard-linked by an output counted once)
    shared: int = 0  # of which bytes shared with output folders through hard links
    records: int = 0
    blobs: int = 0
    output_folders: int = 0
    last_build: dict = field(default_factory=dict)

    def lines(self) -> list[str]:
        lb = self.last_build
        if lb.get("lookups"):
            rate = f"{lb['hits']} of {lb['lookups']} step lookups hit ({100.0 * lb['hits'] / lb['lookups']:.1f}%)"
        elif lb:
            rate = "no step looked up (every output was up to date)"
        else:
            rate = "no build recorded yet"
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(lb["time"])) if lb.get("time") else "-"
        limit = max_size_setting()
        return [f"cache: {self.root}",
                f"size: {human(self.size)} ({self.size} bytes) in {self.records} step records and {self.blobs} blobs; "
                f"{human(self.shared)} of it shared with outputs by hard links",
                f"limit: {human(limit) if limit else 'none'} (${MAX_SIZE_ENV})",
                f"output folders: {self.output_folders}",
                f"last build: {when}{' -> ' + lb['out'] if lb.get('out') else ''}: {rate}"]

    def to_json(self) -> dict:
        return {"root": str(self.root), "size": self.size, "shared": self.shared, "records": self.records,
                "blobs": self.blobs, "outputFolders": self.output_folders, "lastBuild": self.last_build,
                "maxSize": max_size_setting()}


def _walk(root: Path, kind: str):
    base = root / kind
    try:
        shards = list(os.scandir(base))
    except OSError:
        return
    for shard in shards:
        if not shard.is_dir(follow_symlinks=False):
            continue
        try:
            for e in os.scandir(shard.path):
                if e.is_file(follow_symlinks=False):
                    yield shard.name + e.name, e
        except OSError:
            continue


def _blob_size(st: os.stat_result) -> int:
    return st.st_size


def stats(root: Path) -> CacheStats:
    root = Path(root)
    s = CacheStats(root=root, last_build=read_json_dict(root / "last-build.json"))
    for _, e in _walk(root, "actions"):
        try:
            s.size += e.stat().st_size
            s.records += 1
        except OSError:
            pass
    for _, e in _walk(root, "objects"):
        try:
            st = e.stat()
        except OSError:
            continue
        s.blobs += 1
        s.size += st.st_size
        if st.st_nlink > 1:
            s.shared += st.st_size
    s.output_folders = len(_output_folders(root))
    return s


def _output_folders(root: Path) -> list[tuple[Path, Path]]:
    """(registration file, output folder) of every output folder that still exists."""
    out = []
    d = root / "outputs"
    try:
        regs = list(d.iterdir())
    except OSError:
        return out
    for reg in regs:
        try:
            folder = Path(reg.read_text())
        except (OSError, ValueError):
            continue
        out.append((reg, folder))
    return out


def _protected(root: Path) -> tuple[set[str], set[str]]:
    """(blob hex names, record hex names) the current outputs need; forgets vanished folders."""
    blobs, records = set(), set()
    for reg, folder in _output_folders(root):
        state = read_json_dict(folder / ".assetpipe" / "state.json")
        if not state:
            if not folder.exists():
                try:
                    reg.unlink()
                except OSError:
                    pass
            continue
        assets = state.get("assets") if isinstance(state.get("assets"), dict) else {}
        for entry in assets.values():
            outputs = entry.get("outputs") if isinstance(entry, dict) else None
            for row in (outputs.values() if isinstance(outputs, dict) else ()):
                if isinstance(row, list) and row and isinstance(row[0], str):
                    blobs.add(row[0].split(":", 1)[-1])
        explain = read_json_dict(folder / ".assetpipe" / "explain.json").get("steps")
        for steps in (explain.values() if isinstance(explain, dict) else ()):
            for kin in (steps.values() if isinstance(steps, dict) else ()):
                if isinstance(kin, dict):
                    if kin.get("step") == "import" and isinstance(kin.get("inputs"), dict):
                        # its explanation adds the files the import discovered; its key has only the
                        # source's digest and name (assetpipe/graph.py, the import phase)
                        kin = {**kin, "inputs": {k: kin["inputs"][k] for k in ("source", "name")
                                                 if k in kin["inputs"]}}
                    records.add(digest_json(kin).split(":", 1)[-1])
    return blobs, records


def _running_builds_since(root: Path) -> float | None:
    """The start time of the oldest running build (None: none); removes stale registrations."""
    import fcntl

    oldest = None
    d = root / "builds"
    try:
        regs = list(d.iterdir())
    except OSError:
        return None
    for p in regs:
        try:
            fd = os.open(p, os.O_RDONLY)
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # locked: that build is running
                start = os.fstat(fd).st_mtime
                oldest = start if oldest is None else min(oldest, start)
            else:  # nobody holds it: a build that died without unregistering
                try:
                    os.unlink(p)
                except OSError:
                    pass
        finally:
            os.close(fd)
    return oldest


@dataclass
class CollectResult:
    removed_records: int = 0
    removed_blobs: int = 0
    freed: int = 0
    size_before: int = 0
    size_after: int = 0
    kept_in_use: int = 0  # entries kept because current outputs or running builds need them

    def line(self) -> str:
        return (f"removed {self.removed_records} step records and {self.removed_blobs} blobs, freed "
                f"{human(self.freed)}: {human(self.size_before)} -> {human(self.size_after)} "
                f"({self.kept_in_use} entries kept for current outputs or running builds)")


def collect(root: Path, max_size: int | None = None, older_than_s: float | None = None,
            dry_run: bool = False, now: float | None = None) -> CollectResult:
    """Delete least recently used records and blobs until the cache holds at most ``max_size``
    bytes, and (with ``older_than_s``) everything unused for longer; never what the current
    outputs or a running build need (module docstring)."""
    root = Path(root)
    now = time.time() if now is None else now
    running = _running_builds_since(root)
    keep_after = now - GRACE_S if running is None else min(now - GRACE_S, running - 1.0)
    keep_blobs, keep_records = _protected(root)

    records: dict[str, _Entry] = {}
    for name, e in _walk(root, "actions"):
        try:
            st = e.stat()
            wrapper = json.loads(Path(e.path).read_bytes())
            blobs = tuple(d.split(":", 1)[-1] for d in wrapper["record"].get("blobs", {}).values())
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            blobs, st = (), None
        if st is None:
            try:
                st = e.stat()
            except OSError:
                continue
        records[name] = _Entry(Path(e.path), st.st_size, st.st_mtime, blobs)
    blobs: dict[str, _Entry] = {}
    for name, e in _walk(root, "objects"):
        try:
            st = e.stat()
        except OSError:
            continue
        blobs[name] = _Entry(Path(e.path), st.st_size, st.st_mtime)
    result = CollectResult()
    result.size_before = sum(r.size for r in records.values()) + sum(b.size for b in blobs.values())
    size = result.size_before

    users: dict[str, int] = {}  # blob -> how many live records name it
    for r in records.values():
        for b in set(r.blobs):
            users[b] = users.get(b, 0) + 1

    def in_use(entry: _Entry, name: str, kind: str) -> bool:
        if entry.mtime >= keep_after:
            return True
        return name in (keep_records if kind == "record" else keep_blobs)

    def still_old(entry: _Entry) -> bool:  # checked again right before deleting
        try:
            return os.stat(entry.path).st_mtime < keep_after
        except OSError:
            return False

    def delete(entry: _Entry) -> bool:
        if dry_run:
            return True
        try:
            os.unlink(entry.path)
            return True
        except OSError:
            return False

    # candidates, least recently used first: a record (with the blobs only it names), or an orphan blob
    candidates: list[tuple[float, str, str]] = [(r.mtime, "record", n) for n, r in records.items()]
    candidates += [(b.mtime, "blob", n) for n, b in blobs.items() if users.get(n, 0) == 0]
    candidates.sort()
    kept = 0
    for mtime, kind, name in candidates:
        over_size = max_size is not None and size > max_size
        too_old = older_than_s is not None and mtime < now - older_than_s
        if not (over_size or too_old):
            if max_size is not None and older_than_s is None:
                break  # sorted by age: nothing further is needed
            continue
        entry = records[name] if kind == "record" else blobs[name]
        if in_use(entry, name, kind):
            kept += 1
            continue
        if not still_old(entry) or not delete(entry):
            continue
        size -= entry.size
        if kind == "blob":
            result.removed_blobs += 1
            result.freed += entry.size
            continue
        result.removed_records += 1
        result.freed += entry.size
        for b in set(entry.blobs):
            users[b] -= 1
            blob = blobs.get(b)
            if users[b] == 0 and blob is not None and not in_use(blob, b, "blob") and still_old(blob) and delete(blob):
                size -= blob.size
                result.removed_blobs += 1
                result.freed += blob.size
    result.size_after = size
    result.kept_in_use = kept
    return result


def auto_collect(root: Path) -> CollectResult | None:
    """After a build that wrote to the cache: collect down to 80% of the limit when above it."""
    limit = max_size_setting()
    if not limit:
        return None
    s = stats(root)
    if s.size <= limit:
        return None
    return collect(root, max_size=int(limit * AUTO_TARGET))
