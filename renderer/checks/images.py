"""Decoding images for the checks once per model: the level-0 file of a texture is usually the
source image unchanged, so the ``textures`` and ``roles`` checks share one decode (keyed by a
digest of the bytes). OpenCV decodes straight to an array (no Pillow image + convert copy); Pillow is the
fallback for what OpenCV does not read (and for palette images with transparency)."""

from __future__ import annotations

import hashlib
import io
import threading
from typing import Any

import numpy as np


def decode_rgba(data: bytes, cache: dict[str, Any] | None = None) -> np.ndarray:
    """(H, W, 4) uint8 RGBA of PNG/JPEG/... ``data`` (16-bit images rounded to 8 bits).

    With ``cache``, each image is decoded once even when two threads ask for it at once (the
    source model's thread and the texture checks: a lock per image, kept in the cache); other
    images decode side by side."""
    key = "img:" + hashlib.blake2b(data, digest_size=16).hexdigest()
    if cache is None:
        return _decode(data)
    if key in cache:
        return cache[key]
    with cache.setdefault("lock:" + key, threading.Lock()):  # setdefault: one lock, atomically
        if key not in cache:
            cache[key] = _decode(data)
    return cache[key]


def _decode(data: bytes) -> np.ndarray:
    out = None
    if data[:8] != b"\x89PNG\r\n\x1a\n" or b"PLTE" not in data[:4096]:  # palettes: Pillow handles tRNS right
        import cv2  # noqa: PLC0415

        arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if arr is not None:
            if arr.dtype == np.uint16:
                arr = ((arr.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
            if arr.dtype == np.uint8:
                if arr.ndim == 2:
                    out = cv2.cvtColor(arr, cv2.COLOR_GRAY2RGBA)
                elif arr.shape[2] == 3:
                    out = cv2.cvtColor(arr, cv2.COLOR_BGR2RGBA)
                elif arr.shape[2] == 4:
                    out = cv2.cvtColor(arr, cv2.COLOR_BGRA2RGBA)
    if out is None:
        from PIL import Image  # noqa: PLC0415

        with Image.open(io.BytesIO(data)) as im:
            out = np.asarray(im.convert("RGBA"))
    return out
