"""The content-addressed store: blobs named by their digest, and step records by key.

Layout under the cache root::

    objects/ab/<30 hex>     a blob; its name is the xxh3-128 of its content
    actions/ab/<30 hex>     a step record (JSON) under the step's cache key
    tmp/                    files being written (renamed into place when complete)

Every write goes to ``tmp/`` and is renamed into place (atomic on POSIX), so a reader or a
killed build never sees half a file, and two builds writing the same entry at once both
succeed with the same content. Every read is verified: a blob whose content no longer
matches its name, or a record that does not parse or lacks its checksum, is deleted and
reported as missing, so the caller rebuilds it; a corrupted cache is never served.

Imports only the standard library and xxhash (the no-op build path uses it).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from assetpipe.core.errors import CacheError
from assetpipe.core.hashing import PREFIX, canonical_json, digest_bytes

ENV_VAR = "ASSETPIPE_CACHE"
# folders this process has made sure exist (a Store is made per task: this saves a mkdir a write)
_KNOWN_DIRS: set[Path] = set()


def default_cache_dir() -> Path:
    """``$ASSETPIPE_CACHE``, else ``$XDG_CACHE_HOME/assetpipe``, else ``~/.cache/assetpipe``."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    # the XDG base directory spec: a relative path is invalid and ignored
    return (Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache") / "assetpipe"


def _split(digest: str) -> tuple[str, str]:
    hexpart = digest[len(PREFIX):] if digest.startswith(PREFIX) else digest
    if len(hexpart) < 8 or any(c not in "0123456789abcdef" for c in hexpart):
        raise ValueError(f"not a digest: {digest!r}")
    return hexpart[:2], hexpart[2:]


class Store:
    def __init__(self, root: Path):
        self.root = Path(root)
        self.dropped: list[str] = []  # entries found corrupt and deleted during this run
        self._dirs = _KNOWN_DIRS
        if self.root in _KNOWN_DIRS:
            return
        try:
            for sub in ("objects", "actions", "tmp"):
                (self.root / sub).mkdir(parents=True, exist_ok=True)
            _KNOWN_DIRS.add(self.root)
        except OSError as exc:
            raise CacheError(f"cannot use the cache folder {self.root}: {exc.strerror}") from None

    # -- low level ----------------------------------------------------------------------
    def _path(self, kind: str, digest: str) -> Path:
        a, b = _split(digest)
        return self.root / kind / a / b

    def _read(self, path: Path) -> bytes | None:
        """The file's bytes, or None when absent; any other failure makes the cache unusable."""
        try:
            return path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise CacheError(f"cannot read from the cache folder {self.root}: {exc.strerror}") from None

    def _write(self, path: Path, data: bytes) -> None:
        for attempt in (0, 1):
            tmp = None
            try:
                if attempt or path.parent not in _KNOWN_DIRS:  # one mkdir per shard and process
                    (self.root / "tmp").mkdir(parents=True, exist_ok=True)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    _KNOWN_DIRS.add(path.parent)
                fd, tmp = tempfile.mkstemp(dir=self.root / "tmp")
                with os.fdopen(fd, "wb") as f:
                    f.write(data)
                os.replace(tmp, path)
                return
            except OSError as exc:
                if tmp is not None:
                    try:
                        os.unlink(tmp)
                    except OSError:
                        pass
                if isinstance(exc, FileNotFoundError) and not attempt:
                    _KNOWN_DIRS.discard(path.parent)  # a folder vanished under us: make it again
                    continue
                raise CacheError(f"cannot write to the cache folder {self.root}: {exc.strerror}") from None

    def _drop(self, path: Path, why: str) -> None:
        self.dropped.append(f"{path.relative_to(self.root)}: {why}")
        try:
            path.unlink()
        except OSError:
            pass

    # -- blobs --------------------------------------------------------------------------
    def put_blob(self, data: bytes) -> str:
        digest = digest_bytes(data)
        path = self._path("objects", digest)
        if self.get_blob(digest) is None:  # absent, or present but corrupt (dropped): write it
            self._write(path, data)
        return digest

    def get_blob(self, digest: str) -> bytes | None:
        """The blob's bytes, verified; None if absent or corrupt (a corrupt one is deleted)."""
        path = self._path("objects", digest)
        data = self._read(path)
        if data is None:
            return None
        if digest_bytes(data) != digest:
            self._drop(path, "content does not match its digest")
            return None
        return data

    def has_blob(self, digest: str) -> bool:
        return self._path("objects", digest).exists()

    def blob_path(self, digest: str) -> Path:
        return self._path("objects", digest)

    # -- step records -------------------------------------------------------------------
    def put_record(self, key: str, record: dict) -> None:
        body = canonical_json(record)
        self._write(self._path("actions", key), canonical_json({"check": digest_bytes(body), "record": record}))

    def get_record(self, key: str) -> dict | None:
        """The record under ``key``, verified, with every blob it names present and intact."""
        path = self._path("actions", key)
        raw = self._read(path)
        if raw is None:
            return None
        try:
            wrapper = json.loads(raw)
            record = wrapper["record"]
            ok = isinstance(record, dict) and wrapper["check"] == digest_bytes(canonical_json(record))
        except (ValueError, KeyError, TypeError):
            ok = False
        if not ok:
            self._drop(path, "record is corrupt")
            return None
        for d in record.get("blobs", {}).values():
            if self.get_blob(d) is None:  # absent, or corrupt (then dropped too)
                self._drop(path, f"blob {d} is missing or corrupt")
                return None
        return record
