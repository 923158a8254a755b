"""Decoding encoded images (PNG, JPEG, TGA, BMP, and GIF/WebP) into RGBA pixel arrays.

Pure functions: bytes in, numpy arrays out, no file I/O.

Output convention
-----------------
:func:`decode_image` returns a C-contiguous array of shape ``(H, W, 4)``, channels R, G, B, A,
row 0 the top row of the image (glTF / Vulkan convention):

* ``uint8`` for every 8-bit-or-less source (palette with or without transparency, grey,
  grey+alpha, RGB, RGBA, CMYK JPEG, 16-bit-per-pixel TGA/BMP, ...);
* ``uint16`` (0..65535) for PNGs stored with 16 bits per channel (grey, grey+alpha, RGB,
  RGBA), which are decoded with OpenCV because Pillow truncates 16-bit colour PNGs to 8 bits.

Missing alpha is filled with the maximum value (255 or 65535). Colour-key transparency
(``tRNS`` on grey / RGB PNGs, palette ``tRNS``) becomes alpha for 8-bit sources; a colour key
on a 16-bit PNG is ignored (OpenCV does not apply it). Embedded ICC profiles and gAMA chunks
are ignored: glTF defines texture colour spaces by role, not by image metadata.

EXIF orientation is **ignored** (glTF 2.0: "the image's orientation... must be ignored";
texture coordinates address the stored pixel rows).
"""

from __future__ import annotations

import io
import struct
import warnings

import cv2
import numpy as np
from PIL import Image

from assetpipe.core.errors import InvalidTextureError
from assetpipe.pipelines.model import ImageSource

# 16384 x 16384 (Vulkan's common maxImageDimension2D, squared): 1 GiB as RGBA8 already.
DEFAULT_MAX_PIXELS = 16384 * 16384

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# Formats Pillow may identify that we accept (glTF core needs PNG and JPEG; OBJ/MTL files in
# the wild also use TGA and BMP; GIF/WebP are sniffed by pipelines.image_source).
_ACCEPTED_FORMATS = frozenset({"PNG", "JPEG", "MPO", "TGA", "BMP", "DIB", "GIF", "WEBP"})
# (names of Pillow's openers: a JPEG with multi-picture data opens through "JPEG" and reports
# "MPO"; "MPO" itself is no opener in Pillow 13, and naming it made a JPEG that fails to open a
# KeyError instead of "cannot identify image file")
_PIL_FORMAT_HINT = {
    "image/png": ["PNG"], "image/jpeg": ["JPEG"], "image/bmp": ["BMP", "DIB"],
    "image/x-tga": ["TGA"], "image/tga": ["TGA"], "image/gif": ["GIF"], "image/webp": ["WEBP"],
}


def _where(image: ImageSource) -> str:
    return image.origin or image.name


def _png_ihdr(data: bytes) -> tuple[int, int, int, int] | None:
    """``(width, height, bit_depth, colour_type)`` from a PNG's IHDR, or None if not a PNG."""
    if not data.startswith(_PNG_MAGIC) or len(data) < 33 or data[12:16] != b"IHDR":
        return None
    width, height, depth, colour_type = struct.unpack(">IIBB", data[16:26])
    return width, height, depth, colour_type


def _check_size(image: ImageSource, width: int, height: int, max_pixels: int, bytes_per_channel: int = 1) -> None:
    """The one limit on decoded images, checked from the header before any pixel is decoded:
    the RGBA pixels must fit in ``max_pixels`` RGBA8 texels (4 bytes each), so a 16-bit image
    (8 bytes per texel) may have half as many pixels. Pillow's own bomb limit never applies
    (it would refuse a real 16384x16384 PNG that ours accepts)."""
    if width <= 0 or height <= 0:
        raise InvalidTextureError(_where(image), f"image {image.name!r} has an empty size {width}x{height}")
    decoded = width * height * 4 * bytes_per_channel
    if decoded > max_pixels * 4:
        depth = f" {8 * bytes_per_channel}-bit" if bytes_per_channel > 1 else ""
        raise InvalidTextureError(
            _where(image),
            f"image {image.name!r} is {width}x{height}{depth} = {width * height} pixels, {_mib(decoded)} decoded as RGBA: "
            f"over the limit of {max_pixels} RGBA8 texels ({_mib(max_pixels * 4)}; checked before decoding)")


def _mib(n: int) -> str:
    return f"{n / (1 << 20):.1f} MiB" if n >= 1 << 20 else f"{n} bytes"


_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # samples per pixel by colour type
_PNG_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}


def _check_png_stream(image: ImageSource) -> None:
    """Check a PNG's chunks (CRCs) and pixel stream (inflates to exactly the size its header
    implies) before a decoder sees it. A header claiming 16384^2 pixels over a few bytes of
    data is refused without allocating the image (Pillow allocates first), and libpng never
    prints its complaints about a broken file to stderr beside our one-line error. Inflates in
    1 MiB pieces, so the check keeps no more than that."""
    import zlib

    data = image.data
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    interlace = data[28]
    if depth not in _PNG_DEPTHS.get(colour, ()) or interlace not in (0, 1) or data[26] != 0 or data[27] != 0:
        raise InvalidTextureError(_where(image), f"image {image.name!r} has an invalid PNG header "
                                                 f"(bit depth {depth}, colour type {colour})")
    pos, inflater, inflated = 8, zlib.decompressobj(), 0
    try:
        while pos + 12 <= len(data):
            length, kind = struct.unpack(">I4s", data[pos:pos + 8])
            body = data[pos + 8:pos + 8 + length]
            if len(body) != length or pos + 12 + length > len(data):
                break
            crc = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])[0]
            if zlib.crc32(kind + body) != crc:
                raise InvalidTextureError(_where(image), f"image {image.name!r} has a corrupt {kind!r} chunk (CRC)")
            if kind == b"IDAT":
                chunk = inflater.decompress(body, 1 << 20)
                while True:
                    inflated += len(chunk)
                    if not inflater.unconsumed_tail:
                        break
                    chunk = inflater.decompress(inflater.unconsumed_tail, 1 << 20)
            elif kind == b"IEND":
                break
            pos += 12 + length
    except zlib.error as exc:
        raise InvalidTextureError(_where(image), f"image {image.name!r} is a corrupt PNG ({exc})") from None
    bits = depth * _PNG_CHANNELS[colour]  # per pixel
    if interlace:  # Adam7: seven passes, each of its own rows and columns
        passes = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
        expected = 0
        for x0, y0, dx, dy in passes:
            w, h = (width - x0 + dx - 1) // dx, (height - y0 + dy - 1) // dy
            if w > 0 and h > 0:
                expected += h * (1 + (w * bits + 7) // 8)
    else:
        expected = height * (1 + (width * bits + 7) // 8)
    # Only missing pixel data is refused: a stream lacking its zlib checksum or a file lacking
    # IEND after complete pixel data still decodes (Pillow and libpng accept them).
    if inflated < expected:
        raise InvalidTextureError(_where(image), f"image {image.name!r} is a corrupt or truncated PNG "
                                                 f"(its pixel data holds {inflated} of {expected} bytes)")


def _decode_png16(image: ImageSource, max_pixels: int) -> np.ndarray:
    """A 16-bit PNG via OpenCV (IMREAD_UNCHANGED keeps 16 bits and ignores EXIF)."""
    buf = np.frombuffer(image.data, dtype=np.uint8)
    try:
        arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:  # pragma: no cover - OpenCV raises rarely, returns None mostly
        raise InvalidTextureError(_where(image), f"image {image.name!r} cannot be decoded: {exc}") from None
    if arr is None:
        raise InvalidTextureError(_where(image), f"image {image.name!r} is a corrupt or truncated 16-bit PNG")
    if arr.dtype != np.uint16:  # OpenCV chose 8 bits after all: widen exactly
        arr = arr.astype(np.uint16) * 257
    h, w = arr.shape[:2]
    _check_size(image, w, h, max_pixels, 2)
    out = np.empty((h, w, 4), dtype=np.uint16)
    if arr.ndim == 2:
        out[..., :3] = arr[..., None]
        out[..., 3] = 65535
    elif arr.shape[2] == 2:  # grey + alpha (some OpenCV builds)
        out[..., :3] = arr[..., :1]
        out[..., 3] = arr[..., 1]
    elif arr.shape[2] == 3:
        out[..., :3] = arr[..., ::-1]
        out[..., 3] = 65535
    elif arr.shape[2] == 4:
        out[..., :3] = arr[..., 2::-1]
        out[..., 3] = arr[..., 3]
    else:  # pragma: no cover
        raise InvalidTextureError(_where(image), f"image {image.name!r} has {arr.shape[2]} channels")
    return out


def decode_image(image: ImageSource, max_pixels: int = DEFAULT_MAX_PIXELS) -> np.ndarray:
    """Decode ``image.data`` into RGBA pixels.

    Returns ``(H, W, 4)`` ``uint8``, or ``(H, W, 4)`` ``uint16`` for 16-bit-per-channel PNGs
    (see the module docstring). EXIF orientation is ignored.

    Raises :class:`InvalidTextureError` (naming ``image.origin``) when the bytes are not a
    decodable image of an accepted format, are truncated, or decode to more than
    ``max_pixels`` RGBA8 texels' worth of memory (4 bytes each; a 16-bit PNG counts 8 bytes a
    texel). The size is checked from the header, before the pixels are decoded: a
    decompression bomb is refused without allocating its pixels, on the OpenCV (16-bit PNG)
    path too, and Pillow's own bomb limit never refuses an image ours accepts.
    """
    data = image.data
    ihdr = _png_ihdr(data)
    if ihdr is not None:
        _check_size(image, ihdr[0], ihdr[1], max_pixels, 2 if ihdr[2] == 16 else 1)
        _check_png_stream(image)
        if ihdr[2] == 16:
            return _decode_png16(image, max_pixels)
    formats = _PIL_FORMAT_HINT.get(image.mime)
    try:
        with warnings.catch_warnings():
            # Our own max_pixels bound replaces Pillow's global bomb check.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            # and Pillow's complaints about metadata we do not read (a corrupt EXIF block, a TIFF
            # tag longer than the file) would be stray lines in the build's output
            warnings.filterwarnings("ignore", module=r"PIL\.")
            # ...and Pillow's bomb *error* (at twice its limit) must not fire below ours
            saved = Image.MAX_IMAGE_PIXELS
            Image.MAX_IMAGE_PIXELS = max(saved or 0, max_pixels)
            try:
                im = Image.open(io.BytesIO(data), formats=formats)
            finally:
                Image.MAX_IMAGE_PIXELS = saved
            if im.format not in _ACCEPTED_FORMATS:
                raise InvalidTextureError(_where(image), f"image {image.name!r} is a {im.format} image, not a supported format")
            _check_size(image, im.width, im.height, max_pixels)
            im.load()
            rgba = _to_rgba(im)
    except InvalidTextureError:
        raise
    except Image.DecompressionBombError as exc:
        raise InvalidTextureError(_where(image), f"image {image.name!r} is too large: {exc}") from None
    except (OSError, ValueError, SyntaxError, EOFError, struct.error, IndexError, TypeError,
            MemoryError, Image.UnidentifiedImageError) as exc:
        problem = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InvalidTextureError(_where(image), f"image {image.name!r} cannot be decoded: {problem}") from None
    return rgba


# Rows converted at a time: the RGBA copy is made band by band into the output array, so
# decoding holds Pillow's image and our array, never a whole-image RGBA copy and its bytes too
# (a 12000x12000 RGB PNG peaked at 2.2 GiB converted whole, 1.2 GiB in bands; see
# tests/test_texture_process.py's peak-memory test).
_BAND_BYTES = 4 << 20


#: Pillow modes OpenCV widens to RGBA exactly as Pillow's ``convert("RGBA")`` does (no colour key)
_WIDEN = {"RGB": cv2.COLOR_RGB2RGBA, "L": cv2.COLOR_GRAY2RGBA}


def _to_rgba(im: Image.Image) -> np.ndarray:
    """Any Pillow mode to ``(H, W, 4)`` uint8 RGBA, honouring palette / colour-key transparency."""
    mode = im.mode
    if mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        # 16-bit grey from a non-PNG container (PNGs take the OpenCV path): keep 8 bits.
        arr = np.asarray(im, dtype=np.float64)
        scale = 255.0 / 65535.0 if mode.startswith("I") else 255.0
        grey = np.clip(np.rint(arr * scale), 0, 255).astype(np.uint8)
        out = np.empty(grey.shape + (4,), dtype=np.uint8)
        out[..., :3] = grey[..., None]
        out[..., 3] = 255
        return out
    if mode == "RGBA":
        convert = None
    elif mode in ("RGBa", "La", "P", "PA", "L", "LA", "RGB", "1"):
        # premultiplied modes are un-premultiplied; Pillow applies palette tRNS and grey / RGB
        # colour keys (info["transparency"], kept by crop)
        convert = ("RGBA",)
    else:  # CMYK, YCbCr, LAB, HSV, ...
        convert = ("RGB", "RGBA")
    width, height = im.size
    out = np.empty((height, width, 4), dtype=np.uint8)
    rows = max(1, _BAND_BYTES // (4 * max(width, 1)))
    # RGB or grey without a colour key: OpenCV widens each band straight into the output (alpha
    # 255, what Pillow's convert gives, in a third of its time: 4 MP RGB 18.6 -> 6.9 ms)
    widen = _WIDEN.get(mode) if "transparency" not in im.info else None
    for y0 in range(0, height, rows):  # a loop over bands of rows, not texels
        y1 = min(height, y0 + rows)
        band = im.crop((0, y0, width, y1)) if (y0, y1) != (0, height) else im
        if widen is not None:
            cv2.cvtColor(np.asarray(band, dtype=np.uint8), widen, dst=out[y0:y1])
            continue
        for m in convert or ():
            band = band.convert(m)
        arr = np.asarray(band, dtype=np.uint8)
        if arr.shape != (y1 - y0, width, 4):  # pragma: no cover - defensive
            raise ValueError(f"unexpected decoded shape {arr.shape}")
        out[y0:y1] = arr
    return out


def image_size(image: ImageSource) -> tuple[int, int] | None:
    """``(width, height)`` read from the image's header, without decoding a pixel; ``None`` when
    the header cannot be read (:func:`decode_image` then says what is wrong)."""
    ihdr = _png_ihdr(image.data)
    if ihdr is not None:
        return ihdr[0], ihdr[1]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            saved = Image.MAX_IMAGE_PIXELS
            Image.MAX_IMAGE_PIXELS = None  # a header read allocates nothing; our limits apply later
            try:
                with Image.open(io.BytesIO(image.data), formats=_PIL_FORMAT_HINT.get(image.mime)) as im:
                    return int(im.width), int(im.height)
            finally:
                Image.MAX_IMAGE_PIXELS = saved
    except (OSError, ValueError, SyntaxError, EOFError, struct.error, IndexError, TypeError,
            Image.UnidentifiedImageError):
        return None


def has_alpha_below_255(rgba: np.ndarray) -> bool:
    """True if any texel's alpha is below the maximum (255 for uint8, 65535 for uint16).

    ``rgba``: ``(H, W, 4)`` uint8 or uint16.
    """
    top = 65535 if rgba.dtype == np.uint16 else 255
    alpha = rgba[..., 3]
    if alpha.size == 0:
        return False
    return bool(alpha.min() < top)
