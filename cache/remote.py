"""A remote cache tier behind the local store: any fsspec URL (``s3://bucket/prefix``,
``gs://...``, ``file:///shared/cache``), shared by every machine that builds.

:class:`TieredStore` has the interface of :class:`assetpipe.cache.store.Store` and wraps one:

* reads go to the local tier first; a step record missing there is fetched from the remote
  tier together with every blob it names, each blob verified against its digest (and the
  record against its checksum) before it is copied into the local tier. A corrupt or
  truncated remote entry is reported (``Store.dropped``, counted in the build's summary),
  deleted from the remote tier, and treated as missing, so the step is rebuilt and
  re-uploaded;
* writes go to the local tier; ``put_record`` then uploads the record's blobs (those the
  remote tier lacks or holds with the wrong size) and, last, the record itself, so a reader
  that finds a record finds its blobs;
* uploads are atomic: on object stores (S3, GCS, Azure, memory) one PUT of the whole object
  is (an object appears complete or not at all, multipart uploads included: the object exists
  only after CompleteMultipartUpload); on anything else (a shared filesystem, SFTP) the data
  goes to ``tmp/<random>`` and is moved into place. Two machines writing one entry at once
  write the same bytes (blobs are named by content; step records are deterministic), so the
  last writer wins with what the first wrote;
* the remote tier failing (unreachable, no permission) is said once (the ``assetpipe.cache``
  logger, and :attr:`TieredStore.notice`); the build goes on with the local tier alone.

Layout under the URL is the local store's: ``objects/ab/<30 hex>``, ``actions/ab/<30 hex>``.
S3 settings come from the standard places (AWS environment variables and config files, via
botocore); ``AWS_ENDPOINT_URL_S3`` or ``AWS_ENDPOINT_URL`` selects an S3-compatible server
(MinIO, moto, Ceph).

Needs the ``farm`` extra (fsspec, s3fs for S3); imported only when a URL is given.
"""

from __future__ import annotations

import json
import logging
import os
import uuid
from pathlib import Path

from assetpipe.core.errors import CacheError
from assetpipe.core.hashing import canonical_json, digest_bytes
from assetpipe.cache.store import Store, _split, default_cache_dir, is_url, unwrap_record  # is_url re-exported

log = logging.getLogger("assetpipe.cache")

# protocols whose single PUT is atomic (no reader sees a partial object)
ATOMIC_PUT = {"s3", "s3a", "gs", "gcs", "az", "abfs", "abfss", "adl", "memory"}


def storage_options(protocol: str) -> dict:
    """fsspec options for ``protocol``: for S3, the endpoint from the AWS variables (older
    botocore releases ignore ``AWS_ENDPOINT_URL``), short connect timeouts and few retries, so
    an unreachable store is noticed in seconds, and no listing cache (another machine writes)."""
    if protocol not in ("s3", "s3a"):
        return {}
    opts: dict = {"use_listings_cache": False, "skip_instance_cache": True,
                  "config_kwargs": {"connect_timeout": 3, "read_timeout": 60,
                                    "retries": {"max_attempts": 2, "mode": "standard"}}}
    endpoint = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL")
    if endpoint:
        opts["endpoint_url"] = endpoint
    return opts


def open_store(cache: str | os.PathLike | None, local: str | os.PathLike | None = None):
    """The build's store for ``--cache``: a folder (or None: the default folder) gives a
    :class:`Store`; a URL gives a :class:`TieredStore` whose local tier is ``local`` (default:
    ``$ASSETPIPE_CACHE``, else the XDG cache folder)."""
    if not is_url(cache):
        return Store(Path(cache) if cache else default_cache_dir())
    return TieredStore(Store(Path(local) if local else default_cache_dir()), str(cache))


class TieredStore:
    """A local :class:`Store` in front of a remote fsspec tier (see the module's docstring)."""

    def __init__(self, local: Store, url: str, options: dict | None = None):
        self.local = local
        self.url = url.rstrip("/")
        self._options = options
        self._fs = None
        self._base = ""
        self.notice: str | None = None  # set once, when the remote tier failed
        self.moved = {"down": 0, "up": 0, "gets": 0, "puts": 0, "records_fetched": 0}
        self._remote_ok: set[str] = set()  # blob digests known to be intact on the remote tier

    # -- everything the local store does (stats, gc, paths) stays the local store's -------
    def __getattr__(self, name):
        return getattr(self.local, name)

    @property
    def root(self) -> Path:
        return self.local.root

    @property
    def dropped(self) -> list[str]:
        return self.local.dropped

    @property
    def remote_up(self) -> bool:
        return self.notice is None and self._connect() is not None

    # -- the remote tier ----------------------------------------------------------------
    def _connect(self):
        if self._fs is None and self.notice is None:
            try:
                import fsspec
            except ImportError:
                self._down("fsspec is not installed (pip install 'assetpipe[farm]')")
                return None
            protocol = self.url.split("://", 1)[0]
            opts = storage_options(protocol) if self._options is None else self._options
            try:
                self._fs, self._base = fsspec.core.url_to_fs(self.url, **opts)
            except (ImportError, ValueError) as exc:
                self._down(str(exc))
        return self._fs

    def _down(self, why: str) -> None:
        if self.notice is None:
            self.notice = (f"remote cache {self.url} unreachable ({why.splitlines()[0] if why else 'no reason given'}); "
                           "building with the local cache only")
            log.warning("assetpipe: %s", self.notice)
        self._fs = None

    def _key(self, kind: str, digest: str) -> str:
        self._connect()  # sets the base path
        a, b = _split(digest)
        return f"{self._base}/{kind}/{a}/{b}"

    def _call(self, fn, *args):
        """fn(*args) on the remote tier; None when the entry is absent; the tier is switched
        off (and that said once) on any other failure."""
        if self._connect() is None:
            return None
        try:
            return fn(*args)
        except FileNotFoundError:
            return None
        except Exception as exc:  # noqa: BLE001 - any failure of the remote tier: build locally
            if _is_not_found(exc):
                return None
            self._down(f"{type(exc).__name__}: {exc}")
            return None

    def _get_many(self, paths: list[str]) -> dict[str, bytes | None]:
        """path -> bytes (None: absent) for every path, fetched concurrently where the
        filesystem can (fsspec's async ``cat``); {} when the tier is down."""
        if not paths:
            return {}
        got = self._call(self._fs_cat, paths)
        if got is None:
            return {}
        out: dict[str, bytes | None] = {}
        for p in paths:
            v = got.get(p)
            if isinstance(v, (bytes, bytearray)):
                out[p] = bytes(v)
                self.moved["down"] += len(v)
                self.moved["gets"] += 1
            elif v is None or isinstance(v, FileNotFoundError) or _is_not_found(v):
                out[p] = None
            else:  # a failure that is not "absent": the tier is down
                self._down(f"{type(v).__name__}: {v}")
                return {}
        return out

    def _fs_cat(self, paths: list[str]) -> dict:
        """path -> bytes or the exception, one GET per path, concurrent on async filesystems
        (fsspec's own ``cat(list)`` measured 3.5x slower than ``cat_file`` on a 10 MB object)."""
        fs = self._fs
        if getattr(fs, "async_impl", False):
            import asyncio

            from fsspec.asyn import sync

            async def fetch_all():
                return await asyncio.gather(*[fs._cat_file(p) for p in paths], return_exceptions=True)

            return dict(zip(paths, sync(fs.loop, fetch_all)))
        out = {}
        for p in paths:
            try:
                out[p] = fs.cat_file(p)
            except Exception as exc:  # noqa: BLE001 - sorted out by the caller
                out[p] = exc
        return out

    def _put_many(self, items: dict[str, bytes]) -> bool:
        """Upload every path -> bytes (concurrently on object stores); False when the tier is down."""
        if not items:
            return True
        return self._call(self._fs_put, items) is not None

    def _fs_put(self, items: dict[str, bytes]) -> bool:
        fs = self._fs
        protocol = fs.protocol if isinstance(fs.protocol, str) else fs.protocol[0]
        if protocol in ATOMIC_PUT:  # one PUT per object: whole or absent
            fs.pipe(items)
        else:  # a filesystem: write aside, then move into place (a rename where it can be)
            fs.makedirs(f"{self._base}/tmp", exist_ok=True)
            for path, data in items.items():
                tmp = f"{self._base}/tmp/{uuid.uuid4().hex}"
                fs.makedirs(path.rsplit("/", 1)[0], exist_ok=True)
                fs.pipe_file(tmp, data)
                try:
                    fs.mv(tmp, path)
                except Exception:
                    try:
                        fs.rm_file(tmp)
                    except Exception:  # noqa: BLE001
                        pass
                    raise
        for data in items.values():
            self.moved["up"] += len(data)
            self.moved["puts"] += 1
        return True

    def _remove(self, path: str) -> None:
        self._call(lambda p: self._fs.rm_file(p), path)

    def _verified(self, digest: str, path: str, data: bytes | None) -> bytes | None:
        """``data`` if it matches ``digest``; a corrupt remote blob is reported and deleted."""
        if data is None:
            return None
        if digest_bytes(data) != digest:
            self.local.dropped.append(f"remote {self.url}/objects/{digest}: content does not match its digest "
                                      f"({len(data)} bytes); rebuilt")
            self._remove(path)
            self._remote_ok.discard(digest)
            return None
        self._remote_ok.add(digest)
        return data

    # -- blobs --------------------------------------------------------------------------
    def put_blob(self, data: bytes) -> str:
        return self.local.put_blob(data)

    def get_blob(self, digest: str) -> bytes | None:
        data = self.local.get_blob(digest)
        if data is None and self.notice is None:
            path = self._key("objects", digest)
            data = self._verified(digest, path, self._get_many([path]).get(path))
            if data is not None:
                self.local.put_blob(data)
        return data

    def has_blob(self, digest: str) -> bool:
        return self.local.has_blob(digest)

    def blob_path(self, digest: str) -> Path:
        return self.local.blob_path(digest)

    # -- step records -------------------------------------------------------------------
    def get_record(self, key: str) -> dict | None:
        """The local record, else the remote one with all its blobs (fetched together, each
        verified, copied into the local tier); None if absent or anything is corrupt."""
        rec = self.local.get_record(key)
        if rec is not None or self.notice is not None:
            return rec
        path = self._key("actions", key)
        record = self._parse_record(key, path, self._get_many([path]).get(path))
        if record is None:
            return None
        missing = {self._key("objects", d): d for d in dict.fromkeys(record.get("blobs", {}).values())
                   if not self.local.has_blob(d) or self.local.get_blob(d) is None}
        got = self._get_many(list(missing))
        for p, d in missing.items():
            data = self._verified(d, p, got.get(p))
            if data is None:  # absent or corrupt (reported): the step is rebuilt and re-uploaded
                return None
            self.local.put_blob(data)
        self.moved["records_fetched"] += 1
        self.local.put_record(key, record)
        return record

    def _parse_record(self, key: str, path: str, raw: bytes | None) -> dict | None:
        """The record in ``raw`` if its checksum holds; a corrupt one is reported and deleted."""
        if raw is None:
            return None
        record = unwrap_record(raw)
        if record is None:
            self.local.dropped.append(f"remote {self.url}/actions/{key}: record is corrupt; rebuilt")
            self._remove(path)
            return None
        return record

    def prefetch(self, keys: list[str], batch: int = 64) -> None:
        """Copy the records under ``keys`` that the local tier lacks, and their blobs, from the
        remote tier in concurrent batches (the graph calls this once per phase; one GET at a
        time cost a round trip per record and per blob). What fails here is left to
        :meth:`get_record`, which reports it."""
        if self.notice is not None or self._connect() is None:
            return
        todo = {self._key("actions", k): k for k in dict.fromkeys(keys)
                if not self.local._path("actions", k).exists()}
        paths = list(todo)
        records: dict[str, dict] = {}
        for i in range(0, len(paths), batch):
            got = self._get_many(paths[i:i + batch])
            for p in paths[i:i + batch]:
                rec = self._parse_record(todo[p], p, got.get(p))
                if rec is not None:
                    records[todo[p]] = rec
        need = {self._key("objects", d): d for rec in records.values() for d in rec.get("blobs", {}).values()
                if not self.local.has_blob(d)}
        bad: set[str] = set()
        blob_paths = list(need)
        for i in range(0, len(blob_paths), batch):
            got = self._get_many(blob_paths[i:i + batch])
            for p in blob_paths[i:i + batch]:
                data = self._verified(need[p], p, got.get(p))
                if data is None:
                    bad.add(need[p])
                else:
                    self.local.put_blob(data)
        for key, rec in records.items():
            if not bad.intersection(rec.get("blobs", {}).values()):
                self.moved["records_fetched"] += 1
                self.local.put_record(key, rec)

    def put_record(self, key: str, record: dict) -> None:
        """Into the local tier; then its blobs (those not known to be on the remote tier:
        a PUT of a few KB costs what a HEAD does) and, once they are there, the record."""
        self.local.put_record(key, record)
        if self._connect() is None:
            return
        blobs = {}
        for d in dict.fromkeys(record.get("blobs", {}).values()):
            if d in self._remote_ok:
                continue
            data = self.local.get_blob(d)
            if data is None:
                raise CacheError(f"blob {d} of step record {key} vanished from the cache folder {self.local.root}")
            blobs[self._key("objects", d)] = data
        if not self._put_many(blobs):
            return
        self._remote_ok.update(record.get("blobs", {}).values())
        body = canonical_json(record)
        self._put_many({self._key("actions", key): canonical_json({"check": digest_bytes(body), "record": record})})


def _is_not_found(exc: BaseException) -> bool:
    """Whether a remote tier's exception says "no such entry" (a cache miss), read from its
    structure, never its text: a connection error's message holds the endpoint URL, and a port
    such as 40412 once made an unreachable store pass for an empty one (no notice, every call
    waiting for its connect timeout). botocore: ``response`` with an error code or HTTP status;
    aiohttp/requests-style errors: ``status``/``status_code``."""
    if isinstance(exc, FileNotFoundError):
        return True
    response = getattr(exc, "response", None)
    if isinstance(response, dict):
        code = str((response.get("Error") or {}).get("Code", ""))
        status = (response.get("ResponseMetadata") or {}).get("HTTPStatusCode")
        return code in ("NoSuchKey", "404", "NotFound") or status == 404
    return 404 in (getattr(exc, "status", None), getattr(exc, "status_code", None))
