"""The stat cache: a file whose (size, mtime_ns, inode) did not change is not read again.

Entries map an absolute path to ``[size, mtime_ns, inode, digest]``. A file modified within
``RACY_NS`` of the moment it was hashed is not remembered (git's "racily clean" rule: a
second write in the same timestamp tick would otherwise go unnoticed). Saved atomically; a
lost or corrupt stat cache only costs re-reading files.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from assetpipe.core.hashing import digest_file

RACY_NS = 2_000_000_000
VERSION = 1


class StatCache:
    def __init__(self, path: Path | None):
        self.path = Path(path) if path else None
        self.entries: dict[str, list] = {}
        self.dirty = False
        self.hashed = 0  # files actually read during this run
        if self.path is not None:
            try:
                data = json.loads(self.path.read_bytes())
                if isinstance(data, dict) and data.get("version") == VERSION and isinstance(data["entries"], dict):
                    self.entries = {k: e for k, e in data["entries"].items() if isinstance(e, list) and len(e) == 4}
            except (OSError, ValueError, KeyError):
                self.entries = {}

    def digest(self, path: str | Path) -> str:
        """Content digest of ``path`` (raises FileNotFoundError when it is gone)."""
        return self.digest_abs(path if isinstance(path, str) and os.path.isabs(path) else os.path.abspath(path))

    def digest_abs(self, key: str) -> str:
        """:meth:`digest` of an absolute path given as a string (the no-op path's hot call)."""
        st = os.stat(key)
        e = self.entries.get(key)
        if e is not None and e[0] == st.st_size and e[1] == st.st_mtime_ns and e[2] == st.st_ino:
            return e[3]
        d = digest_file(key)
        self.hashed += 1
        if time.time_ns() - st.st_mtime_ns > RACY_NS:
            self.entries[key] = [st.st_size, st.st_mtime_ns, st.st_ino, d]
            self.dirty = True
        elif key in self.entries:
            del self.entries[key]
            self.dirty = True
        return d

    def stat_matches(self, path: str | Path, size: int, mtime_ns: int) -> bool:
        try:
            st = os.stat(path)
        except OSError:
            return False
        return st.st_size == size and st.st_mtime_ns == mtime_ns

    def save(self) -> None:
        if self.path is None or not self.dirty:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            import tempfile  # only when saving: it imports shutil, bz2 and lzma

            fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".stat-cache.")
        except OSError:  # not saved: the next build re-reads the files, nothing worse
            return
        try:
            with os.fdopen(fd, "w") as f:
                json.dump({"version": VERSION, "entries": self.entries}, f, separators=(",", ":"))
            os.replace(tmp, self.path)
        except OSError:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        self.dirty = False
