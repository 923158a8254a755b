"""A deterministic container for step outputs: a JSON header and raw numpy arrays.

    b"APK1" | u32 header length | header JSON (canonical) | arrays, each 16-byte aligned

The header holds ``meta`` (any JSON) and, per array, its name, dtype, shape, offset and size.
Same input, same bytes (unlike npz, which stamps times), so step outputs can be keyed by
their digest and a rebuild that produces the same result stops invalidating what follows.
No pickle: nothing read from the cache is ever executed.
"""

from __future__ import annotations

import json
import struct

import numpy as np

MAGIC = b"APK1"
_ALIGN = 16


def pack(meta: dict, arrays: dict[str, np.ndarray]) -> bytes:
    entries = []
    chunks = []
    offset = 0
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        if a.dtype.hasobject:
            raise TypeError(f"array {name!r} has object dtype")
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        pad = -offset % _ALIGN
        chunks.append(b"\0" * pad)
        offset += pad
        entries.append({"name": name, "dtype": a.dtype.str, "shape": list(a.shape), "offset": offset,
                        "size": a.nbytes})
        chunks.append(a.tobytes())
        offset += a.nbytes
    header = json.dumps({"meta": meta, "arrays": entries}, sort_keys=True, separators=(",", ":"),
                        allow_nan=False).encode()
    return MAGIC + struct.pack("<I", len(header)) + header + b"".join(chunks)


def unpack(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    if not data.startswith(MAGIC) or len(data) < 8:
        raise ValueError("not an assetpipe pack")
    (hlen,) = struct.unpack_from("<I", data, 4)
    header = json.loads(data[8:8 + hlen])
    base = 8 + hlen
    arrays = {}
    for e in header["arrays"]:
        start = base + e["offset"]
        arr = np.frombuffer(data, dtype=np.dtype(e["dtype"]), count=int(np.prod(e["shape"], dtype=np.int64)),
                            offset=start)
        arrays[e["name"]] = arr.reshape(e["shape"])
    return header["meta"], arrays
