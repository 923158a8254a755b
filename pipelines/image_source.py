"""Reading the encoded images a model references, safely.

Only this module and the importers touch source files. Paths are confined to the model's
folder (a URI that resolves outside it is refused), sizes are bounded, and the MIME type is
sniffed from the bytes (a file named .png holding a JPEG is decoded as the JPEG it is).
"""

from __future__ import annotations

import os
from pathlib import Path

from assetpipe.core.errors import AssetError, InvalidTextureError, MissingFileError
from assetpipe.core.hashing import digest_bytes
from assetpipe.pipelines.model import ImageSource

# A 16384^2 RGBA PNG can be far smaller than this; anything larger is refused, not read.
MAX_IMAGE_FILE_BYTES = 256 * 1024 * 1024

_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", "image/png"),
    (b"\xff\xd8\xff", "image/jpeg"),
    (b"BM", "image/bmp"),
    (b"GIF8", "image/gif"),
    (b"RIFF", "image/webp"),  # confirmed below
    (b"\xabKTX 20\xbb\r\n\x1a\n", "image/ktx2"),
)


def sniff_mime(data: bytes) -> str | None:
    """The image type from its first bytes, or None if unknown (TGA has no magic: by caller)."""
    for magic, mime in _MAGIC:
        if data.startswith(magic):
            if mime == "image/webp" and data[8:12] != b"WEBP":
                continue
            return mime
    return None


def resolve_inside(base_dir: Path, relative: str, referrer: Path) -> Path:
    """Resolve ``relative`` against ``base_dir`` and refuse anything outside ``base_dir``."""
    base = base_dir.resolve()
    target = (base / relative).resolve()
    if target != base and base not in target.parents:
        raise AssetError(referrer, f"refuses {relative!r}: it resolves outside the model's folder {base}")
    return target


def read_image_file(path: Path, referrer: Path, name: str | None = None) -> ImageSource:
    """Read an image file into an :class:`ImageSource`; errors name ``referrer`` and the file."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise MissingFileError(referrer, f"image {path.name!r} not found (looked for {path})") from None
    if size > MAX_IMAGE_FILE_BYTES:
        raise InvalidTextureError(referrer, f"image {path.name!r} is {size} bytes, over the {MAX_IMAGE_FILE_BYTES} limit")
    data = path.read_bytes()
    image = image_from_bytes(data, name or path.name, str(path), referrer, hint=path.suffix)
    return ImageSource(image.name, image.data, image.mime, image.origin, image.digest, path=path)


def image_from_bytes(data: bytes, name: str, origin: str, referrer: Path, hint: str = "",
                     declared_mime: str | None = None) -> ImageSource:
    if len(data) > MAX_IMAGE_FILE_BYTES:
        raise InvalidTextureError(referrer, f"image {name!r} is {len(data)} bytes, over the {MAX_IMAGE_FILE_BYTES} limit")
    mime = sniff_mime(data)
    if mime is None:
        if hint.lower() == ".tga" or declared_mime == "image/x-tga":
            mime = "image/x-tga"
        elif data.startswith(b"version https://git-lfs"):
            raise InvalidTextureError(referrer, f"image {name!r} is a Git LFS pointer, not an image (run git lfs pull)")
        else:
            raise InvalidTextureError(referrer, f"image {name!r} is not a PNG, JPEG, BMP, GIF, WebP or TGA file")
    return ImageSource(name=name, data=data, mime=mime, origin=origin, digest=digest_bytes(data))


def model_relative(path: Path, base: Path) -> str:
    try:
        return os.path.relpath(path, base)
    except ValueError:
        return str(path)
