"""The content-addressed store: blobs named by their digest, and step records by key.

Layout under the cache root::

    objects/ab/<30 hex>     a blob; its name is the xxh3-128 of its content
    actions/ab/<30 hex>     a step record (JSON) under the step's cache key
    tmp/                    files being written (renamed into place when complete)
    builds/<pid>-<n>        one per running build, locked while it runs (the collector keeps
                            everything used since the oldest running build started)
    outputs/<digest>        the output folders built with this cache (their blobs are kept)
    last-build.json         the last build's step lookups and hits (``assetpipe cache stats``)

Blobs are read-only (0444). An output is put in place (``export_blob``) as a reflink of its
blob where the file system can (btrfs, XFS: copy-on-write, so no second copy on disk and an
edit of the output never reaches the blob), else as a copy. Hard links would also save the
copy on ext4, but an output sharing its blob's inode can be edited *in place* (``open(p, "w")``,
``echo >``, an editor that keeps hard links; file modes do not stop root) and that edit would
change the cached blob: so they are used only when asked for (``ASSETPIPE_OUTPUT_LINKS=hardlink``,
and then only for a blob no other output folder links yet). Either way the cache never *serves*
a changed blob: every blob is verified against its digest whenever it is read.

Imports only the standard library and xxhash (the no-op build path uses it).
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import time
from pathlib import Path

from assetpipe.core.errors import CacheError
from assetpipe.core.hashing import PREFIX, canonical_json, digest_bytes, digest_chunks, digest_file
from assetpipe.core.writer import write_all

ENV_VAR = "ASSETPIPE_CACHE"
BLOB_MODE = 0o444  # blobs are never written in place: read-only, for every output linked to them
LAST_BUILD = "last-build.json"
LINKS_ENV = "ASSETPIPE_OUTPUT_LINKS"  # "hardlink": outputs share their blob's inode (see above)
_REFLINK_OK = True  # turned off for this process at the first file system that refuses FICLONE
# folders this process has made sure exist (a Store is made per task: this saves a mkdir a write)
_KNOWN_DIRS: set[Path] = set()


def is_url(cache) -> bool:
    """Whether ``--cache`` names a remote tier (an fsspec URL) rather than a folder: here, so
    that a build with a local cache does not import :mod:`assetpipe.cache.remote`."""
    return cache is not None and "://" in str(cache)


def default_cache_dir() -> Path:
    """``$ASSETPIPE_CACHE``, else ``$XDG_CACHE_HOME/assetpipe``, else ``~/.cache/assetpipe``."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    # the XDG base directory spec: a relative path is invalid and ignored
    return (Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache") / "assetpipe"


class _BuildSession:
    """A running build's registration: its file in ``builds/``, locked until closed. Closed by
    :meth:`Store.end_build`, or when the build's frame is dropped (a build that raised), so a
    long-lived process (watch, the API) never leaves a registration that looks like a running build."""

    def __init__(self, fd: int, path: Path):
        self.fd, self.path = fd, path

    def __getitem__(self, i: int):  # (fd, path), as a tuple
        return (self.fd, self.path)[i]

    def close(self) -> None:
        if self.fd is None:
            return
        try:
            os.unlink(self.path)
        except OSError:
            pass
        os.close(self.fd)
        self.fd = None

    __del__ = close


def _reflink(src: Path, dst: Path) -> bool:
    """Clone ``src`` to ``dst`` (FICLONE: copy-on-write, no data copied); False where unsupported."""
    global _REFLINK_OK
    if not _REFLINK_OK:
        return False
    try:
        import fcntl

        with open(src, "rb") as s, open(dst, "wb") as d:
            fcntl.ioctl(d.fileno(), 0x40049409, s.fileno())  # FICLONE
        os.chmod(dst, 0o644)
        return True
    except (OSError, ImportError) as exc:
        try:
            os.unlink(dst)
        except OSError:
            pass
        if getattr(exc, "errno", None) in (errno.EOPNOTSUPP, errno.EXDEV, errno.EINVAL, errno.ENOTTY):
            _REFLINK_OK = False if getattr(exc, "errno", None) != errno.EXDEV else _REFLINK_OK
        return False


def _hardlink(src: Path, dst: Path) -> bool:
    """Hard-link ``src`` (a blob no other output folder links yet) to ``dst``; False otherwise."""
    try:
        st = os.stat(src)
        if st.st_nlink != 1:
            return False
        if st.st_mode & 0o777 != BLOB_MODE:
            os.chmod(src, BLOB_MODE)
        os.link(src, dst)
        return True
    except OSError:
        return False


def unwrap_record(raw: bytes) -> dict | None:
    """The record stored in ``raw`` (``{"record": ..., "check": digest}``), or None when it does
    not parse or its checksum does not hold. Shared by the local store and the remote tier."""
    try:
        wrapper = json.loads(raw)
        record = wrapper["record"]
        ok = isinstance(record, dict) and wrapper["check"] == digest_bytes(canonical_json(record))
    except (ValueError, KeyError, TypeError):
        return None
    return record if ok else None


def _split(digest: str) -> tuple[str, str]:
    hexpart = digest[len(PREFIX):] if digest.startswith(PREFIX) else digest
    if len(hexpart) < 8 or any(c not in "0123456789abcdef" for c in hexpart):
        raise ValueError(f"not a digest: {digest!r}")
    return hexpart[:2], hexpart[2:]


_SMALL_NAMES = itertools.count()  # Store._write_small's temporary files


class Store:
    def __init__(self, root: Path):
        self.root = Path(root)
        self.dropped: list[str] = []  # entries found corrupt and deleted during this run
        self.hits = 0  # step lookups answered from the cache during this run
        self.misses = 0  # ... and not (the step runs)
        self.writes = 0  # blobs and records written during this run
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

    def _write(self, path: Path, data, mode: int | None = None) -> None:
        """Write ``data`` (bytes-like, or a list or tuple of bytes-like pieces) at ``path``,
        atomically (through ``tmp/``)."""
        self.writes += 1
        for attempt in (0, 1):
            tmp = None
            try:
                if attempt or path.parent not in _KNOWN_DIRS:  # one mkdir per shard and process
                    (self.root / "tmp").mkdir(parents=True, exist_ok=True)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    _KNOWN_DIRS.add(path.parent)
                import tempfile  # here: it imports shutil, bz2 and lzma (5 ms of a no-op build)

                fd, tmp = tempfile.mkstemp(dir=self.root / "tmp")
                with os.fdopen(fd, "wb") as f:
                    for piece in (data if isinstance(data, (list, tuple)) else (data,)):
                        write_all(f, piece)
                if mode is not None:
                    os.chmod(tmp, mode)
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
    def put_blob(self, data) -> str:
        """Store a blob; its digest. ``data``: bytes-like, or a list or tuple of bytes-like
        pieces of it (:func:`assetpipe.cache.serialize.pack_chunks`: the pieces are hashed and
        written in turn, never joined into one copy)."""
        chunked = isinstance(data, (list, tuple))
        digest = digest_chunks(data) if chunked else digest_bytes(data)
        path = self._path("objects", digest)
        if not self.blob_intact(digest):  # absent, or present but corrupt (dropped): write it
            self._write(path, data, BLOB_MODE)
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

    def blob_intact(self, digest: str) -> bool:
        """Whether blob ``digest`` is present with content matching its name (a corrupt one is
        deleted): :meth:`get_blob`'s check, hashed in 1 MiB pieces instead of read whole (for a
        caller that does not need the bytes: an export, a record's blobs)."""
        path = self._path("objects", digest)
        try:
            ok = digest_file(path) == digest
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise CacheError(f"cannot read from the cache folder {self.root}: {exc.strerror}") from None
        if not ok:
            self._drop(path, "content does not match its digest")
        return ok

    def blob_path(self, digest: str) -> Path:
        return self._path("objects", digest)

    def export_blob(self, digest: str, dest: Path, tmp_dir: Path) -> str:
        """Put blob ``digest`` at ``dest`` atomically (through ``tmp_dir``, on dest's file system),
        verified; returns how: "reflink", "hardlink" or "copy" (module docstring). Raises
        FileNotFoundError when the blob is missing or corrupt (then dropped)."""
        path = self._path("objects", digest)
        if not self.blob_intact(digest):
            raise FileNotFoundError(f"blob {digest} for {dest} vanished from the cache")
        tmp = Path(tmp_dir) / f".{Path(dest).name}.{os.getpid()}.{time.monotonic_ns()}.tmp"
        how = "copy"
        try:
            if os.environ.get(LINKS_ENV) == "hardlink" and _hardlink(path, tmp):
                how = "hardlink"
            elif _reflink(path, tmp):
                how = "reflink"
            else:
                import shutil  # only when a blob is exported (it imports bz2 and lzma)

                shutil.copyfile(path, tmp)
                os.chmod(tmp, 0o644)
            os.replace(tmp, dest)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        return how

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
        record = unwrap_record(raw)
        if record is None:
            self._drop(path, "record is corrupt")
            return None
        for d in record.get("blobs", {}).values():
            if not self.blob_intact(d):  # absent, or corrupt (then dropped too)
                self._drop(path, f"blob {d} is missing or corrupt")
                return None
        try:  # its last use, for the collector (least recently used goes first)
            os.utime(path)
        except OSError:
            pass
        return record

    # -- build sessions (for the collector and ``cache stats``) ------------------------------
    def begin_build(self, out_dir: Path | None = None):
        """Register a running build: a file in ``builds/`` locked until :meth:`end_build` (or the
        process's end), so a collection meanwhile keeps everything this build may still use;
        and the output folder, whose current outputs' blobs a collection keeps."""
        import fcntl

        d = self.root / "builds"
        try:
            d.mkdir(exist_ok=True)
            path = d / f"{os.getpid()}-{time.monotonic_ns()}"
            fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX)
            os.utime(path)  # its mtime: when this build started
        except OSError:
            return None  # not registered: a collection meanwhile keeps what is younger than 10 minutes
        if out_dir is not None:
            from assetpipe.core.hashing import digest_bytes

            target = os.path.abspath(out_dir)
            reg = self.root / "outputs" / digest_bytes(target.encode()).split(":", 1)[1][:32]
            try:
                if not reg.exists():
                    reg.parent.mkdir(exist_ok=True)
                    self._write_small(reg, target.encode())
            except OSError:
                pass
        return _BuildSession(fd, path)

    def _write_small(self, path: Path, data: bytes) -> None:
        # a name of this process's own, not tempfile's: a no-op build writes this file, and
        # tempfile imports shutil, bz2 and lzma (5 ms of its 100)
        while True:
            tmp = path.parent / f".tmp-{os.getpid()}-{next(_SMALL_NAMES)}"
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
                break
            except FileExistsError:  # left by a killed process that had this pid
                continue
        with os.fdopen(fd, "wb") as f:
            write_all(f, data)
        os.replace(tmp, path)

    def end_build(self, session, out_dir: Path | None = None, seconds: float = 0.0) -> None:
        """Record this build's step lookups (``cache stats``: the hit rate of the last build),
        unregister it, and collect when the cache exceeds its size limit (only after a build
        that wrote to it, so a no-op build never walks the cache)."""
        body = {"time": time.time(), "out": str(os.path.abspath(out_dir)) if out_dir else None,
                "lookups": self.hits + self.misses, "hits": self.hits, "writes": self.writes,
                "seconds": round(seconds, 3)}
        try:
            self._write_small(self.root / LAST_BUILD, json.dumps(body).encode())
        except OSError:
            pass
        if session is not None:
            session.close()
        if self.writes:
            from assetpipe.cache.maintenance import auto_collect

            auto_collect(self.root)
