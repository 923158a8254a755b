"""Content digests: xxh3-128, written as ``"xxh3:<32 hex>"``.

xxh3-128 was measured at 28 GB/s in memory on this kind of machine, against 1.8 GB/s for
sha256 (../shared/NOTES-measurements.md); it is not a cryptographic hash, which a build cache
does not need (the store verifies content on read, it does not defend against an attacker).

This module imports only ``xxhash`` and the standard library: the no-op build path uses it
and must not pay for numpy.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import xxhash

PREFIX = "xxh3:"
_CHUNK = 1 << 20


def digest_bytes(data: bytes | bytearray | memoryview) -> str:
    return PREFIX + xxhash.xxh3_128_hexdigest(data)


def digest_chunks(chunks) -> str:
    """:func:`digest_bytes` of the concatenation of ``chunks`` (bytes-like pieces), without
    making it."""
    h = xxhash.xxh3_128()
    for c in chunks:
        h.update(c)
    return PREFIX + h.hexdigest()


def digest_file(path: str | Path) -> str:
    """Digest of a file's content, read in pieces of at most 1 MiB into one buffer (constant
    memory, no copy per piece)."""
    h = xxhash.xxh3_128()
    with open(path, "rb", buffering=0) as f:
        buf = bytearray(max(1, min(_CHUNK, os.fstat(f.fileno()).st_size)))
        view = memoryview(buf)
        while n := f.readinto(buf):
            h.update(view[:n])
    return PREFIX + h.hexdigest()


def canonical_json(value) -> bytes:
    """The canonical form used in keys: sorted keys, no spaces, floats by repr (round-trip)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False).encode("utf-8")


def digest_json(value) -> str:
    return digest_bytes(canonical_json(value))
