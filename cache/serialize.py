"""A deterministic container for step outputs: a JSON header and raw numpy arrays.

    b"APK1" | u32 header length | header JSON (canonical) | arrays, each 16-byte aligned

The header holds ``meta`` (any JSON) and, per array, its name, dtype, shape, offset and size.
Arrays with the same bytes are stored once, their entries sharing the offset (a model placing
one mesh 98 times, MetalRoughSpheresNoTextures: its LOD step's pack 64.7 -> 40.8 MB and its
mesh step's 33.4 -> 21.0 MB, the placements' index buffers being equal); a reader needs
nothing for it, each entry reads its own bytes. Same input, same bytes (unlike npz, which
stamps times), so step outputs can be keyed by their digest and a rebuild that produces the
same result stops invalidating what follows. No pickle: nothing read from the cache is ever
executed.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import xxhash

MAGIC = b"APK1"
_ALIGN = 16


#: arrays smaller than this are always stored (looking for an equal one would cost more)
SHARE_MIN_BYTES = 256


def pack(meta: dict, arrays: dict[str, np.ndarray]) -> bytes:
    """The pack of ``meta`` and ``arrays`` (module docstring), as one bytes object."""
    return b"".join(pack_chunks(meta, arrays))


def pack_chunks(meta: dict, arrays: dict[str, np.ndarray]) -> list:
    """:func:`pack` as a list of bytes-like pieces whose concatenation is the pack: the arrays'
    own buffers, not copies (``Store.put_blob`` hashes and writes the pieces in turn; two
    copies of every step output fewer). The arrays must not change while the list is used."""
    entries = []
    chunks: list = []
    offset = 0
    stored: dict[bytes, list[tuple[memoryview, int]]] = {}  # digest -> (bytes, offset) of arrays stored
    for name in sorted(arrays):
        a = np.asarray(arrays[name], order="C")  # not ascontiguousarray: it makes 0-d arrays 1-d
        if a.dtype.hasobject:
            raise TypeError(f"array {name!r} has object dtype")
        if a.dtype.fields is not None or a.dtype.subdtype is not None:  # dtype.str would lose the fields
            raise TypeError(f"array {name!r} has a structured dtype")
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        raw = memoryview(np.ascontiguousarray(a).reshape(-1).view(np.uint8))
        entry = {"name": name, "dtype": a.dtype.str, "shape": list(a.shape), "size": a.nbytes}
        if a.nbytes >= SHARE_MIN_BYTES:
            same = stored.setdefault(xxhash.xxh3_128_digest(raw), [])
            at = next((off for other, off in same if other == raw), None)
            if at is not None:  # the same bytes are stored already: this entry reads them there
                entries.append({**entry, "offset": at})
                continue
        pad = -offset % _ALIGN
        if pad:
            chunks.append(b"\0" * pad)
        offset += pad
        if a.nbytes >= SHARE_MIN_BYTES:
            same.append((raw, offset))
        entries.append({**entry, "offset": offset})
        if a.nbytes:
            chunks.append(raw)
        offset += a.nbytes
    header = json.dumps({"meta": meta, "arrays": entries}, sort_keys=True, separators=(",", ":"),
                        allow_nan=False).encode()
    return [MAGIC + struct.pack("<I", len(header)) + header, *chunks]


def unpack(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """(meta, arrays) of a pack; ValueError for anything that is not a well-formed pack."""
    if not data.startswith(MAGIC) or len(data) < 8:
        raise ValueError("not an assetpipe pack")
    (hlen,) = struct.unpack_from("<I", data, 4)
    base = 8 + hlen
    if base > len(data):
        raise ValueError("assetpipe pack: header runs past the end")
    try:
        header = json.loads(data[8:base])
        arrays = {}
        for e in header["arrays"]:
            dtype = np.dtype(e["dtype"])
            shape = tuple(int(d) for d in e["shape"])
            count = int(np.prod(shape, dtype=np.int64))
            if dtype.hasobject or min(shape, default=0) < 0 or e["offset"] < 0 \
                    or e["size"] != count * dtype.itemsize or base + e["offset"] + e["size"] > len(data):
                raise ValueError(f"bad array entry {e!r}")
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=base + e["offset"])
            arrays[e["name"]] = arr.reshape(shape)
        return header["meta"], arrays
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"assetpipe pack: malformed header ({exc!r})") from None
